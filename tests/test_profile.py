"""The cost split of benchmarks.profile (no timing limits: only its bookkeeping)."""
import json
import math
import sys
from pathlib import Path

import pytest

# benchmarks/ is not installed: it is imported from the repository's root
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.profile import main, profile_run  # noqa: E402


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_fractions_partition_the_run(scheme):
    row = profile_run("dumbbell", scheme, 3.0, repeats=1, t_end=0.2)
    f = row["fractions"]
    assert math.isclose(sum(f.values()), 1.0)
    assert all(0.0 <= v <= 1.0 for v in f.values())
    # the model and the linear solves are both entered in every Newton iteration
    assert f["model"] > 0.02 and f["linear_algebra"] > 0.01
    assert row["newton_iterations"] >= row["steps"] > 0
    assert row["ms_per_iteration"] > 0 and row["status"] == "SUCCESS"


def test_a_costlier_model_takes_a_larger_share():
    # the toss rule's beam kernels cost far more per call than the dumbbell's
    # scalar arithmetic, with linear algebra of the same small size
    light = profile_run("dumbbell", "newmark", 3.0, repeats=1, t_end=0.2)["fractions"]
    heavy = profile_run("toss_rule", "newmark", 3.0, repeats=1, t_end=0.01)["fractions"]
    assert heavy["model"] > light["model"] + 0.15


def test_command_line_writes_json(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["--problems", "dumbbell", "--schemes", "hfdi", "--repeats", "1",
                 "--t-end", "0.1", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["problem"], r["scheme"]) for r in rows] == [("dumbbell", "hfdi")]
    assert "ms/it" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--problems", "nope"])


def test_paths_compare_the_same_runs(tmp_path, capsys):
    pytest.importorskip("numba")
    out = tmp_path / "paths.json"
    assert main(["--paths", "--rtol", "1e-5", "--problems", "articulated", "--schemes",
                 "bathe,hfdi", "--repeats", "1", "--t-end", "0.02", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["scheme"], r["rtol"], r["target"]) for r in rows] == [("bathe", 1e-5, None),
                                                                     ("hfdi", 1e-5, None)]
    for row in rows:
        # both paths take the same steps and corrections; the timing itself is not asserted
        assert row["same_counts"] and row["newton_iterations"] >= row["steps"] > 0
        assert row["python_us"] > 0 and row["compiled_us"] > 0
        assert math.isclose(row["speedup"], row["python_us"] / row["compiled_us"])
        assert row["floor_us"] > 0 and row["floor_iterations_per_step"] >= 1
    assert "floor µs/it" in capsys.readouterr().out


def _floor_case(problem, t_end, step):
    import numpy as np

    import hfdi
    from benchmarks.floor import floor_run
    pytest.importorskip("numba")
    make = getattr(hfdi.models, problem)

    def check(scheme):
        # HFDI's floor takes the load rate as a difference quotient
        library = hfdi.HFDI(load_rate="difference") if scheme == "hfdi" else scheme
        ref = hfdi.integrate(make(), library, t_end, step=step, tol=1e-12, compiled=False)
        u, v, iterations = floor_run(make(), scheme, step, t_end, 1e-12)
        assert iterations >= ref.stats.steps
        for got, want in ((u, ref.u[-1]), (v, ref.v[-1])):
            assert np.abs(got - want).max() <= 1e-9 * np.abs(want).max()
    return check


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_the_floor_loop_takes_the_librarys_steps(scheme):
    """The minimal loop whose cost is the floor (benchmarks/floor.py) computes
    the same steps as the library: the same end state, to the Newton tolerance,
    at the same fixed step."""
    _floor_case("dumbbell", 0.2, 1e-3)(scheme)


@pytest.mark.slow
@pytest.mark.parametrize("problem, t_end, step", [("tetrahedra", 1.0, 0.01),
                                                   ("articulated", 0.2, 1e-3),
                                                   ("toss_rule", 0.002, 1e-5)])
@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_the_floor_loop_takes_the_librarys_steps_on_every_model(problem, t_end, step, scheme):
    _floor_case(problem, t_end, step)(scheme)
