"""The cost split of benchmarks.profile (no timing limits: only its bookkeeping)."""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

# benchmarks/ is not installed: it is imported from the repository's root
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.floor import correction_costs, floor_us, unit_costs  # noqa: E402
from benchmarks.profile import main, profile_run  # noqa: E402

import hfdi  # noqa: E402


@pytest.mark.parametrize("scheme", list(hfdi.SCHEMES))
def test_fractions_partition_the_run(scheme):
    row = profile_run("dumbbell", scheme, 3.0, repeats=1, t_end=0.2)
    f = row["fractions"]
    assert math.isclose(sum(f.values()), 1.0)
    assert all(0.0 <= v <= 1.0 for v in f.values())
    # the model and the linear solves are both entered in every Newton iteration
    assert f["model"] > 0.02 and f["linear_algebra"] > 0.01
    assert row["newton_iterations"] >= row["steps"] > 0
    assert row["ms_per_iteration"] > 0 and row["status"] == "SUCCESS"


@pytest.mark.slow
def test_a_costlier_model_takes_a_larger_share():
    # the toss rule's beam kernels cost far more per call than the dumbbell's
    # scalar arithmetic, with linear algebra of the same small size (measured
    # 0.45 and 0.16); each run once before, so that no first call's
    # compilation (a fresh cache) counts as the model's time (0.33 then). A
    # ratio, not a difference: other work on the machine dilutes both shares
    # alike (0.22 and 0.11 measured with the cores busy)
    shares = {}
    for problem, t_end in (("dumbbell", 0.2), ("toss_rule", 0.01)):
        profile_run(problem, "newmark", 3.0, repeats=1, t_end=t_end)
        shares[problem] = profile_run(problem, "newmark", 3.0, repeats=1,
                                      t_end=t_end)["fractions"]["model"]
    assert shares["toss_rule"] > 1.5 * shares["dumbbell"], shares


def test_command_line_writes_json(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["--problems", "dumbbell", "--schemes", "hfdi", "--repeats", "1",
                 "--t-end", "0.1", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["problem"], r["scheme"]) for r in rows] == [("dumbbell", "hfdi")]
    assert "ms/it" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--problems", "nope"])


@pytest.mark.slow
def test_paths_compare_the_same_runs(tmp_path, capsys):
    pytest.importorskip("numba")
    out = tmp_path / "paths.json"
    assert main(["--paths", "--rtol", "1e-5", "--problems", "articulated", "--schemes",
                 "bathe,hfdi,generalized_alpha", "--repeats", "1", "--t-end", "0.02",
                 "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["scheme"], r["rtol"], r["target"]) for r in rows] == [
        ("bathe", 1e-5, None), ("hfdi", 1e-5, None), ("generalized_alpha", 1e-5, None)]
    for row in rows:
        # both paths take the same steps and corrections; the timing itself is not asserted
        assert row["same_counts"] and row["newton_iterations"] >= row["steps"] > 0
        assert row["python_us"] > 0 and row["compiled_us"] > 0
        assert math.isclose(row["speedup"], row["python_us"] / row["compiled_us"])
        # the floor is the unit costs of one correction, measured on the library's code
        costs = row["unit_costs_us"]
        assert set(costs) == {"force", "stiffness", "stiffness_derivative",
                              "potential_energy", "solve", "product"}
        assert all(value > 0 for value in costs.values())
        assert math.isclose(row["floor_us"], sum(costs[k] for k in
                                                 correction_costs(row["scheme"])))
        assert math.isclose(row["floor_iterations_per_step"],
                            row["compiled_newton_iterations"] / row["compiled_steps"])
    assert "floor µs/it" in capsys.readouterr().out


def test_the_floor_of_a_correction_is_its_kernels_and_its_solve():
    """Every scheme's correction evaluates f and K and solves once; HFDI's
    stage also evaluates T(u)[v_D] and forms S B⁻¹ S (Eq. 21)."""
    costs = {"force": 1.0, "stiffness": 10.0, "stiffness_derivative": 100.0,
             "potential_energy": 1000.0, "solve": 1e4, "product": 1e5}
    assert floor_us(None, "newmark", costs) == 10011.0
    assert floor_us(None, "bathe", costs) == 10011.0
    assert floor_us(None, "generalized_alpha", costs) == 10011.0
    assert floor_us(None, "hfdi", costs) == 110111.0
    assert floor_us(None, hfdi.HFDI(load_rate="difference"), costs) == 110111.0
    with pytest.raises(ValueError, match="costs lacks stiffness_derivative, product"):
        floor_us(None, "hfdi", {"force": 1.0, "stiffness": 1.0, "solve": 1.0})
    with pytest.raises(ValueError, match="scheme must be one of"):
        correction_costs("euler")


def test_unit_costs_refuse_bad_input_naming_it():
    model = hfdi.models.dumbbell()
    with pytest.raises(ValueError, match="repeats must be an integer >= 1"):
        unit_costs(model, model.initial_displacement, repeats=0)
    with pytest.raises(ValueError, match="calls must be an integer >= 1"):
        unit_costs(model, model.initial_displacement, calls=1.5)
    with pytest.raises(ValueError, match="u must be a finite vector of the model's 4 entries"):
        unit_costs(model, [0.0, 1.0])
    plain = hfdi.System([1.0], lambda u: u, lambda u: np.eye(1), lambda u, w: np.zeros((1, 1)))
    with pytest.raises(ValueError, match="has no compiled kernels"):
        unit_costs(plain, [0.0])


@pytest.mark.slow
def test_unit_costs_time_the_models_kernels_and_the_librarys_solve():
    """The loops call the model's compiled kernels and hfdi.linsolve.dense.solve
    (no timing asserted: every cost measured, positive and finite); the
    floor from them is their sum for the scheme."""
    pytest.importorskip("numba")
    model = hfdi.models.toss_rule()
    costs = unit_costs(model, model.initial_displacement, repeats=1, calls=10)
    assert set(costs) == {"force", "stiffness", "stiffness_derivative", "potential_energy",
                          "solve", "product"}
    assert all(math.isfinite(v) and v > 0 for v in costs.values())
    assert floor_us(model, "generalized_alpha", costs) == pytest.approx(
        costs["force"] + costs["stiffness"] + costs["solve"])
