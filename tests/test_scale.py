"""The scale measurement (benchmarks.scale) and the band IDA path without a dense matrix.

No wall-clock asserts: the timings depend on the machine; only their presence,
finiteness and the files are checked.
"""
import json
import math
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import hfdi
from validation import reference
from validation.reference import _FirstOrderForm, ida_dense_reference, ida_march

# benchmarks/ is not installed: it is imported from the repository's root
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import scale  # noqa: E402

# every test here runs the scale measurement's IDA runs: not in the quick loop
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tiny_scale(tmp_path_factory):
    out = tmp_path_factory.mktemp("scale")
    return out, scale.run_scale(out, sizes=(2, 4, 8), steps=2, timeout=120)


def test_scale_json_and_png(tiny_scale):
    out, result = tiny_scale
    data = json.loads((out / "scale.json").read_text())
    assert [r["n_elements"] for r in data["records"]] == [2, 4, 8]
    for rec in data["records"]:
        assert "error" not in rec
        assert rec["n_dof"] == 3 * (rec["n_elements"] + 1)
        assert rec["newton_iterations_timed"] >= 1 and rec["steps_timed"] >= 1
        for key in ("time_per_iteration_s", "time_per_step_s", "model_build_s",
                    "first_step_s", "peak_rss_MB", "rss_baseline_MB"):
            assert math.isfinite(rec[key]) and rec[key] > 0, key
        assert rec["peak_memory_MB"] >= 0
        # the measuring process runs single-threaded BLAS
        assert rec["threads"]["OPENBLAS_NUM_THREADS"] == "1"
    fit = data["fits"]["time_per_iteration_s"]["all"]
    assert math.isfinite(fit["exponent"]) and fit["sizes"] == [2, 4, 8]
    # no size reaches the asymptotic range: reported as missing, not invented
    assert data["fits"]["time_per_iteration_s"]["asymptotic"]["exponent"] is None
    for key in ("platform", "cpu", "cpu_count", "numpy", "scipy", "blas_threads"):
        assert key in data["machine"]
    png = (out / "scale.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_scale_measures_both_paths(tmp_path):
    """--paths: each size on the default path (45 elements, 138 DOFs: the
    compiled sparse model) and then on the Python path, the same run."""
    pytest.importorskip("numba")
    result = scale.run_scale(tmp_path, sizes=(45,), steps=2, timeout=300, python_path=True)
    rec = result["records"][0]
    assert "error" not in rec and "python_path_error" not in rec
    assert rec["compiled_model"] and not rec["compiled_attempt"]
    assert math.isfinite(rec["time_per_iteration_python_s"]) and rec["peak_memory_python_MB"] >= 0
    assert rec["steps_python"] == rec["steps_timed"]
    assert "Python ms/it" in scale.format_table(result)
    off = scale.measure_size(45, steps=1, timeout=300, compiled="off")
    assert not off["compiled_model"] and off["compiled"] == "off"
    with pytest.raises(ValueError, match="compiled must be one of auto, off"):
        scale.measure_size(45, compiled="yes")


def test_scale_measures_generalized_alpha():
    """--scheme takes every scheme of hfdi.SCHEMES; the warm-up before the
    baseline loads the compiled code, so the size's own steps are timed."""
    rec = scale.measure_size(2, scheme="generalized_alpha", steps=2, timeout=300)
    assert rec["scheme"] == "generalized_alpha" and rec["status"] in ("RUNNING", "SUCCESS")
    # two accepted steps timed (attempts counted: a rejected one among them)
    assert rec["ok"] and rec["steps_timed"] >= 2 and rec["newton_iterations_timed"] >= 2
    assert rec["compiled_attempt"]                    # 9 DOFs: the compiled loop
    with pytest.raises(SystemExit):
        scale.build_parser().parse_args(["--out", "x", "--scheme", "euler"])


@pytest.mark.parametrize("scheme", ["hfdi", "generalized_alpha"])
def test_full_run_keeps_every_accepted_step(scheme):
    """The full run's steps, observed through Integrator.advance(rows=...),
    are those of hfdi.integrate on the same model: times and displacements."""
    model = hfdi.models.toss_rule(6)
    record, u_end, (ts, us) = scale._scheme_run(model, scheme, 3.0, True, 0.002)
    ref = hfdi.integrate(hfdi.models.toss_rule(6), scheme, 0.002, target_iterations=3.0)
    assert record["success"] and record["steps"] == ref.stats.steps
    assert record["accepted"] == ref.stats.accepted == len(ts) - 1
    np.testing.assert_array_equal(ts, ref.t)
    np.testing.assert_array_equal(np.array(us), ref.u)
    np.testing.assert_array_equal(u_end, ref.u[-1])
    # without keeping them, the same run
    again, u_again, (t_none, u_none) = scale._scheme_run(model, scheme, 3.0, False, 0.002)
    assert u_none is None and again["steps"] == record["steps"]
    np.testing.assert_array_equal(u_again, u_end)


def test_fit_exponent_recovers_a_power_law():
    n = np.array([10, 100, 1000, 10000])
    fit = scale.fit_exponent(n, 3e-4 * n ** 1.05)
    assert fit["exponent"] == pytest.approx(1.05, abs=1e-12)
    assert scale.fit_exponent([5], [1.0])["exponent"] is None
    # non-positive values (a memory growth below the RSS resolution) are left out
    assert scale.fit_exponent([1, 10, 100], [0.0, 1.0, 10.0])["sizes"] == [10, 100]


def test_failed_size_is_one_line():
    with pytest.raises(ValueError):
        scale.measure_size(0)
    with pytest.raises(scale.ScaleError, match="no result within"):
        scale.measure_size(2, steps=1, timeout=0.01)


def test_cli_bad_arguments_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        scale.main(["--out", "x", "--sizes", "a,b"])
    assert exc.value.code == 2
    assert "error" in capsys.readouterr().err


def test_internal_band_jacobian_matches_the_dense_solution():
    model = hfdi.models.toss_rule(10)
    t_end = 0.004
    band = ida_march(model, t_end, rtol=1e-8, linsolver="band", band_jacobian="internal")
    dense = ida_dense_reference(model, t_end, rtol=1e-8, linsolver="dense")
    assert band.stats["jacobian"] == "internal" and band.stats["steps"] > 0
    assert (band.stats["lband"], band.stats["uband"]) == (11, 9)
    u_ref = dense.u[-1]
    assert np.linalg.norm(band.u[0] - u_ref) <= 1e-6 * np.linalg.norm(u_ref)


def test_march_lands_on_requested_times():
    model = hfdi.models.toss_rule(3)
    seen = []
    ref = ida_march(model, 0.002, t_eval=[0.0, 0.0005, 0.001], rtol=1e-6,
                    callback=lambda t, u, v: seen.append((t, u.shape, v.shape)))
    assert [s[0] for s in seen] == [0.0, 0.0005, 0.001]
    assert seen[0][1] == (model.n_dof,) and ref.t[0] == 0.002


def test_march_wall_limit_stops_early():
    model = hfdi.models.toss_rule(3)
    ref = ida_march(model, 0.1, rtol=1e-8, wall_limit=0.2)
    assert ref.stats["stopped"] == "wall_limit" and ref.t[0] < 0.1


def test_band_path_allocates_no_dense_matrix():
    # 3000 elements: 18 006 unknowns, a dense iteration matrix would be 2.6 GB
    model = hfdi.models.toss_rule(3000)
    n_eq = 2 * model.n_dof
    tracemalloc.start()
    try:
        form = _FirstOrderForm(model, "band")
        assert form.jacobian_kind == "internal" and form.jacobian is None
        ref = ida_march(model, 2e-7, rtol=1e-6, linsolver="band")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert ref.stats["linsolver"] == "band" and ref.stats["jacobian"] == "internal"
    assert peak < 0.01 * n_eq ** 2 * 8


def test_small_band_keeps_the_analytic_jacobian():
    form = _FirstOrderForm(hfdi.models.toss_rule(10), "band")
    assert form.jacobian_kind == "analytic" and form.jacobian is not None
    assert 2 * form.n <= reference.BAND_LIMIT
    with pytest.raises(ValueError, match="band_jacobian"):
        _FirstOrderForm(hfdi.models.toss_rule(2), "band", "dq")
