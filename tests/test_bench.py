"""``python -m benchmarks precision``: work–precision of our schemes against IDA, Radau and BDF."""
import json
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

# benchmarks/ is not installed: it is imported from the repository's root
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.__main__ import main as benchmarks_main  # noqa: E402
from benchmarks.precision import (_mark_inaccurate, bench_problem, goal,  # noqa: E402
                                  interpolate_wall, pareto_front, speedups)
from benchmarks.ida_compiled import available as ida_c_available  # noqa: E402

# every test here runs the benchmark commands end to end: not in the quick loop
pytestmark = pytest.mark.slow


def main(argv):
    """``python -m benchmarks precision ARGS`` in this process."""
    return benchmarks_main(["precision", *argv])

TINY = ["--t-end", "0.05", "--rtols", "1e-4,1e-7", "--targets", "3", "--rtol", "1e-5",
        "--repeats", "1"]
RECORD_FIELDS = {"problem", "method", "kind", "target", "rtol", "label", "success", "status",
                 "message", "t_reached", "wall", "walls", "cpu", "eps_u", "eps", "steps",
                 "newton_iterations", "nfev", "njev", "nlu"}
#: What may differ between two runs of the same bench in a record: the times.
TIMING_KEYS = {"wall", "walls", "cpu"}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    path = tmp_path_factory.mktemp("cache")
    old = os.environ.get("HFDI_CACHE_DIR")
    os.environ["HFDI_CACHE_DIR"] = str(path)
    yield path
    if old is None:
        os.environ.pop("HFDI_CACHE_DIR", None)
    else:
        os.environ["HFDI_CACHE_DIR"] = old


@pytest.fixture(scope="module")
def tiny(cache_dir, tmp_path_factory):
    """One serial bench of two tiny problems through the command line."""
    out = tmp_path_factory.mktemp("bench1")
    code = main(["--problems", "dumbbell,articulated", "--out", str(out),
                 "--jobs", "1", *TINY])
    assert code == 0
    return out


def _load(out, name):
    return json.loads((out / f"bench_{name}.json").read_text())


def test_outputs_are_written(tiny):
    for name in ("dumbbell", "articulated"):
        data = _load(tiny, name)
        assert data["problem"] == name and data["t_end"] == 0.05
        assert {"settings", "reference", "records", "speedup", "goal", "machine",
                "bench_time"} <= set(data)
        assert data["settings"]["rtols"] == [1e-4, 1e-7]
        assert "default_atol" in data["settings"]["atol_rule"]
        for key in ("platform", "cpu", "cpu_count", "numpy", "scipy", "scikit-sundae",
                    "threads"):
            assert key in data["machine"]
        methods = [(r["method"], r["target"], r["rtol"]) for r in data["records"]]
        # every scheme of hfdi.SCHEMES by default: generalized-α beside the paper's three
        assert methods == [("newmark", 3.0, None), ("bathe", 3.0, None), ("hfdi", 3.0, None),
                           ("generalized_alpha", 3.0, None),
                           ("newmark-rtol", None, 1e-5), ("bathe-rtol", None, 1e-5),
                           ("hfdi-rtol", None, 1e-5), ("generalized_alpha-rtol", None, 1e-5),
                           ("ida", None, 1e-4), ("ida", None, 1e-7),
                           ("ida_c", None, 1e-4), ("ida_c", None, 1e-7),
                           ("radau", None, 1e-4), ("radau", None, 1e-7),
                           ("bdf", None, 1e-4), ("bdf", None, 1e-7)]
        png = (tiny / f"bench_{name}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
    text = (tiny / "bench.md").read_text()
    assert "dumbbell" in text and "articulated" in text and "Speed-up" in text


def test_records_are_complete_and_finite(tiny):
    for name in ("dumbbell", "articulated"):
        for r in _load(tiny, name)["records"]:
            assert RECORD_FIELDS <= set(r)
            if r["method"] == "ida_c" and not ida_c_available()[0]:
                # one line says why: the library is not installed
                assert r["status"] == "SKIPPED" and "libsundials" in r["message"]
                continue
            assert r["success"], r
            assert r["status"] == "SUCCESS" and r["t_reached"] == 0.05
            assert r["wall"] > 0 and r["cpu"] > 0 and r["steps"] > 0 and r["nfev"] > 0
            assert r["eps_u"] is not None and 0 < r["eps_u"] < 1e-2
            assert math.isclose(r["eps"]["u"], r["eps_u"], rel_tol=1e-12)
            if r["kind"] == "ours" or r["method"] == "ida_c":
                assert r["newton_iterations"] >= r["steps"]
            else:
                assert r["newton_iterations"] is None


def test_competitors_converge_as_rtol_tightens(tiny):
    for name in ("dumbbell", "articulated"):
        records = _load(tiny, name)["records"]
        for method in ("ida", "ida_c", "radau", "bdf"):
            if method == "ida_c" and not ida_c_available()[0]:
                continue
            loose, tight = [r for r in records if r["method"] == method]
            assert tight["rtol"] < loose["rtol"]
            # three decades of rtol: at least one decade of ε
            assert tight["eps_u"] < 0.1 * loose["eps_u"], (name, method)
            assert tight["steps"] > loose["steps"]


def test_speedup_rows_refer_to_the_runs(tiny):
    data = _load(tiny, "dumbbell")
    front = data["speedup"]["ours_front"]
    assert front
    for row in front:
        assert row["method"] in ("newmark", "bathe", "hfdi", "generalized_alpha",
                                 "newmark-rtol", "bathe-rtol", "hfdi-rtol",
                                 "generalized_alpha-rtol")
        assert set(row["competitors"]) == {"ida", "ida_c", "radau", "bdf"}
        if row["ratio"] is not None:
            best = row["competitors"][row["best_competitor"]]
            assert best["range"] == "in range"
            assert math.isclose(row["ratio"], best["wall"] / row["wall"])
    g = data["goal"]
    assert g["rtol"] == 1e-6 and g["ida"] is None     # no IDA run at 1e-6 here
    assert "no successful IDA run" in g["note"]
    # the goals against IDA in C (rtol 1e-6 and 1e-8), by wall and CPU time
    assert [(g["rival"], g["rtol"], g["cost"]) for g in data["goals"]] == [
        (rival, rtol, cost) for rival, rtol in (("ida", 1e-6), ("ida_c", 1e-6), ("ida_c", 1e-8))
        for cost in ("wall", "cpu")]
    assert "no successful IDA (C) run" in data["goals"][2]["note"]


def test_generalized_alpha_has_its_rows_in_the_tables(tiny):
    """Generalized-α's rows (iteration count and error control) in the text
    table, its curves in the figure's legend, on the speed-up's front
    candidates; the method column is as wide as its longest name."""
    from benchmarks.precision import format_problem
    data = _load(tiny, "dumbbell")
    text = format_problem(data)
    rows = [line.split() for line in text.splitlines()]
    ours = {row[0]: row for row in rows if row and row[0].startswith("generalized_alpha")}
    assert set(ours) == {"generalized_alpha", "generalized_alpha-rtol"}
    assert ours["generalized_alpha"][1] == "N̄=3" and ours["generalized_alpha"][-1] == "SUCCESS"
    assert ours["generalized_alpha-rtol"][1] == "rtol=1e-05"
    header = next(line for line in text.splitlines() if "setting" in line)
    row = next(line for line in text.splitlines() if line.strip().startswith("bathe "))
    assert header.index("setting") == row.index("N̄=3")       # columns aligned
    assert "generalized_alpha" in data["speedup"]["ours"]
    assert data["settings"]["targets"]["generalized_alpha"] == [3.0]


def test_generalized_alpha_alone(cache_dir, tmp_path, capsys):
    """``--schemes generalized_alpha``: its runs only (no competitor), the
    default targets of every scheme when none are given."""
    from benchmarks.precision import TARGETS
    assert main(["--problems", "dumbbell", "--out", str(tmp_path), "--schemes",
                 "generalized_alpha", "--competitors", "none", "--rtol", "none",
                 "--t-end", "0.05", "--repeats", "1"]) == 0
    records = _load(tmp_path, "dumbbell")["records"]
    assert [(r["method"], r["target"]) for r in records] == [
        ("generalized_alpha", t) for t in TARGETS]
    assert all(r["success"] and 0 < r["eps_u"] < 1e-2 for r in records)
    # a looser target takes fewer steps
    assert records[0]["steps"] < records[-1]["steps"]
    assert "generalized_alpha " in capsys.readouterr().out


def test_style_and_names_of_every_method():
    from benchmarks.precision import DEFAULT_TARGETS, SCHEMES, _method_name, _style
    import hfdi
    assert SCHEMES == tuple(hfdi.SCHEMES) and set(DEFAULT_TARGETS) == set(SCHEMES)
    styles = {_style(s) for s in SCHEMES}
    assert len(styles) == len(SCHEMES)                    # one look per scheme
    assert _style("generalized_alpha-rtol")[2] == ":" and _style("generalized_alpha")[2] == "-"
    assert _style("something") == ("gray", "x", ":")
    assert [_method_name(m) for m in ("hfdi", "newmark-rtol", "generalized_alpha", "ida",
                                      "radau")] == [
        "HFDI", "Newmark (rtol)", "GeneralizedAlpha", "IDA", "Radau"]
    with pytest.raises(ValueError, match="schemes must be of newmark"):
        bench_problem("dumbbell", schemes=["euler"])


def test_jobs_give_the_same_numbers(tiny, tmp_path):
    assert main(["--problems", "dumbbell,articulated", "--out", str(tmp_path),
                 "--jobs", "2", *TINY]) == 0
    for name in ("dumbbell", "articulated"):
        a, b = _load(tiny, name), _load(tmp_path, name)
        assert a["settings"] == b["settings"]
        assert len(a["records"]) == len(b["records"])
        for ra, rb in zip(a["records"], b["records"]):
            strip = lambda r: {k: v for k, v in r.items() if k not in TIMING_KEYS}  # noqa: E731
            assert strip(ra) == strip(rb)


def test_blas_threads_do_not_change_the_numbers(cache_dir, tmp_path, monkeypatch):
    """Spawned workers single-threaded by the environment (as a Dask nanny
    leaves ``OPENBLAS_NUM_THREADS=1`` behind), this process on two BLAS
    threads: the records are still the same. (scipy's Radau moves ε in the 9th
    digit with OpenBLAS's thread count, so every task runs on one thread.)"""
    from validation import parallel
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.setattr(parallel, "_start_method", lambda: "spawn")
    args = ["--problems", "dumbbell", "--schemes", "hfdi", "--competitors",
            "radau,bdf", "--t-end", "0.05", "--rtols", "1e-4", "--targets", "3",
            "--repeats", "1"]
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=2, user_api="blas"):      # as on a machine with 2+ cores
        assert main([*args, "--out", str(tmp_path / "serial"), "--jobs", "1"]) == 0
    assert main([*args, "--out", str(tmp_path / "spawned"), "--jobs", "2"]) == 0
    a, b = _load(tmp_path / "serial", "dumbbell"), _load(tmp_path / "spawned", "dumbbell")
    strip = lambda r: {k: v for k, v in r.items() if k not in TIMING_KEYS}  # noqa: E731
    assert [strip(r) for r in a["records"]] == [strip(r) for r in b["records"]]


def test_a_failed_competitor_is_recorded_not_raised(cache_dir):
    competitors = ["ida", "bdf"] + (["ida_c"] if ida_c_available()[0] else [])
    res = bench_problem("dumbbell", schemes=["hfdi"], targets=[3.0], rtols=[1e-4, 1e-8],
                        competitors=competitors, t_end=0.05, repeats=1, max_nfev=40,
                        skip_nfev=10)
    by = {(r["method"], r["rtol"]): r for r in res["records"]}
    for method in competitors:
        failed, skipped = by[(method, 1e-4)], by[(method, 1e-8)]
        assert not failed["success"] and failed["status"] == "BUDGET"
        assert "work budget" in failed["message"] and failed["eps_u"] is None
        assert skipped["status"] == "SKIPPED" and "needed" in skipped["message"]
    assert by[("hfdi", None)]["success"]
    # no competitor curve: no ratio, and the report still formats
    assert all(p["ratio"] is None for p in res["speedup"]["ours_front"])
    json.dumps(res, allow_nan=False)


def test_pareto_front():
    eps = [1e-2, 1e-3, 5e-3, 1e-4, 2e-4, math.nan, 1e-5]
    wall = [1.0, 2.0, 3.0, 4.0, 3.5, 0.1, 10.0]
    # 5e-3 @ 3 is beaten by 1e-3 @ 2; 1e-4 @ 4 is beaten by... nothing (2e-4 @ 3.5 is
    # less accurate); NaN is left out
    assert pareto_front(eps, wall).tolist() == [0, 1, 4, 3, 6]
    assert pareto_front([], []).tolist() == []
    # equal wall: the more accurate one only
    assert pareto_front([1e-3, 1e-4], [1.0, 1.0]).tolist() == [1]


def test_interpolation_known_answers():
    # wall = 1e-2 / eps on the front: a straight line of slope -1 in log-log
    eps = [1e-2, 1e-4, 1e-6]
    wall = [1.0, 100.0, 1e4]
    value, where = interpolate_wall(eps, wall, 1e-3)
    assert where == "in range" and math.isclose(value, 10.0, rel_tol=1e-12)
    value, where = interpolate_wall(eps[::-1], wall[::-1], 1e-5)     # any order
    assert math.isclose(value, 1000.0, rel_tol=1e-12)
    # between two points of different slopes: geometric interpolation
    value, _ = interpolate_wall([1e-2, 1e-4], [1.0, 4.0], 1e-3)
    assert math.isclose(value, 2.0, rel_tol=1e-12)
    assert interpolate_wall(eps, wall, 1e-2) == (1.0, "in range")
    assert interpolate_wall(eps, wall, 1e-7) == (None, "below range")
    assert interpolate_wall(eps, wall, 1e-1) == (None, "above range")
    assert interpolate_wall([], [], 1e-3) == (None, "no data")


def _rec(method, eps, wall, target=None, rtol=None):
    return {"method": method, "kind": "competitor" if rtol else "ours", "target": target,
            "rtol": rtol, "label": f"{target or rtol}", "success": True, "eps_u": eps,
            "wall": wall, "steps": 1, "nfev": 1, "newton_iterations": 1}


def test_speedup_and_goal_on_synthetic_curves():
    records = [
        _rec("hfdi", 2e-5, 0.05, target=4.0), _rec("hfdi", 8e-6, 0.08, target=3.0),
        _rec("hfdi", 1e-6, 0.5, target=2.0),
        _rec("ida", 1e-3, 0.1, rtol=1e-4), _rec("ida", 1e-5, 1.0, rtol=1e-6),
        _rec("ida", 1e-7, 10.0, rtol=1e-8),
        _rec("radau", 1e-5, 0.4, rtol=1e-4), _rec("radau", 1e-6, 0.8, rtol=1e-5),
    ]
    s = speedups(records)
    rows = {p["label"]: p for p in s["ours_front"]}
    # ε 8e-6: IDA 1e-3→1e-5 is wall = 1e-3/ε^0.5 ... log-log line through the points
    ida_at = math.exp(np.interp(math.log(8e-6), [math.log(1e-7), math.log(1e-5)],
                                [math.log(10.0), math.log(1.0)]))
    radau_at = math.exp(np.interp(math.log(8e-6), [math.log(1e-6), math.log(1e-5)],
                                  [math.log(0.8), math.log(0.4)]))
    row = rows["3.0"]
    assert math.isclose(row["competitors"]["ida"]["wall"], ida_at, rel_tol=1e-12)
    assert math.isclose(row["competitors"]["radau"]["wall"], radau_at, rel_tol=1e-12)
    assert row["best_competitor"] == "radau"
    assert math.isclose(row["ratio"], radau_at / 0.08, rel_tol=1e-12)
    # ε 2e-5 is above Radau's range: its cheapest run (ε 1e-5, 0.4 s) bounds it
    row = rows["4.0"]
    assert row["competitors"]["radau"]["range"] == "above range"
    assert row["best_competitor"] == "ida"
    assert math.isclose(row["ratio_upper_bound"], 0.4 / 0.05, rel_tol=1e-12)
    assert row["ratio_upper_bound"] < row["ratio"]

    g = goal(records)
    assert g["ida"]["eps_u"] == 1e-5 and g["ida"]["wall"] == 1.0
    assert g["hfdi"]["target"] == 3.0                # the fastest with ε ≤ 1e-5
    assert math.isclose(g["ratio"], 1.0 / 0.08) and g["met"]
    hfdi_at = math.exp(np.interp(math.log(1e-5), [math.log(8e-6), math.log(2e-5)],
                                 [math.log(0.08), math.log(0.05)]))
    assert math.isclose(g["ratio_interpolated"], 1.0 / hfdi_at, rel_tol=1e-12)
    # no HFDI run that accurate: not met, and said why
    g = goal([r for r in records if not (r["method"] == "hfdi" and r["eps_u"] < 1e-5)])
    assert g["hfdi"] is None and not g["met"] and "no HFDI run reaches" in g["note"]


def test_a_false_success_is_marked_inaccurate():
    records = [_rec("bdf", 1e-2, 1.0, rtol=1e-3), _rec("bdf", 5e-3, 2.0, rtol=1e-4),
               _rec("bdf", 0.99, 0.01, rtol=1e-5), _rec("bdf", 4e-2, 3.0, rtol=1e-6),
               _rec("ida", 1e-3, 1.0, rtol=1e-3), _rec("ida", 9e-3, 1.0, rtol=1e-4)]
    for r in records:
        r["message"] = "ok"
        r["status"] = "SUCCESS"
    _mark_inaccurate(records)
    assert [r["status"] for r in records] == ["SUCCESS", "SUCCESS", "INACCURATE", "SUCCESS",
                                              "SUCCESS", "SUCCESS"]
    assert not records[2]["success"] and "9.90e-01" in records[2]["message"]
    assert records[2]["solver_status"] == "SUCCESS"
    # left out of the curve: the front of bdf no longer starts at (0.99, 0.01 s)
    assert [p["label"] for p in speedups(records)["fronts"]["bdf"]] == ["0.001", "0.0001"]


@pytest.mark.parametrize("args, words", [
    (["--competitors", "cvode"], "unknown competitor"),
    (["--rtols", "2"], "rtols must be numbers in (0, 1)"),
    (["--repeats", "0"], "integer in [1, 1000]"),
    (["--repeats", "10000000000"], "integer in [1, 1000]"),
    (["--problems", "pendulum"], "unknown problem"),
    (["--jobs", "0"], "integer in [1, "),
])
def test_bad_options_are_one_line(args, words, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*args])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]


@pytest.mark.parametrize("inputs", [False, True])
def test_cosim_runs_and_reports_a_ratio(inputs):
    """``python -m benchmarks cosim``: the FMU through fmpy and the library
    in-process take the same internal steps, with inputs changing or not."""
    pytest.importorskip("fmpy")
    from benchmarks.cosim import benchmark
    result = benchmark("dumbbell", "hfdi", t_end=0.2, repeats=1, inputs=inputs)
    assert result["inputs"] is inputs
    assert result["internal_steps_fmu"] == result["internal_steps_in_process"]
    assert result["communication_steps"] >= 1
    assert result["ratio"] > 0 and result["in_process_s"] > 0 and result["fmu_s"] > 0


def test_compiled_runs_give_the_records_of_the_python_path(tiny, tmp_path):
    """``--compiled``: our runs on the compiled path; on the dumbbell (whose
    kernels agree bit for bit with the Python model) every record but the
    times is the one of the Python path."""
    pytest.importorskip("numba")
    out = tmp_path / "compiled"
    assert main(["--problems", "dumbbell", "--out", str(out), "--competitors", "none",
                 "--compiled", *TINY]) == 0
    compiled = _load(out, "dumbbell")
    assert compiled["settings"]["compiled"] is True
    assert _load(tiny, "dumbbell")["settings"]["compiled"] is False
    python = {(r["method"], r["target"], r["rtol"]): r for r in _load(tiny, "dumbbell")["records"]}
    for record in compiled["records"]:
        reference = python[(record["method"], record["target"], record["rtol"])]
        for key in set(record) - TIMING_KEYS:
            assert record[key] == reference[key], (record["method"], key)


@pytest.mark.parametrize("argv, words", [
    (["cosim", "--t-end", "1e300"], "--t-end: at most"),
    (["cosim", "--communication-step", "1e-12"], "at most 10,000,000 communication steps"),
    (["cosim", "--repeats", "10000000000"], "integer in [1, 1000]"),
    (["profile", "--t-end", "1e300", "--problems", "dumbbell"], "too long for dumbbell"),
    (["scale", "--out", "", "--sizes", "6"], "--out must name a directory"),
    (["scale", "--out", "{tmp}", "--steps", "0"], "--steps: must be an integer in [1, 100000]"),
    (["scale", "--out", "{tmp}", "--target", "-1"], "--target: targets must be numbers"),
    (["scale", "--out", "{tmp}", "--sizes", "100000000000"], "sizes must be integers in"),
    (["scale", "--out", "{tmp}", "--timeout", "0"], "--timeout: must be a positive"),
    (["scale", "--out", "{tmp}", "--full-schemes", "foo"], "unknown scheme(s) 'foo'"),
    (["scale", "--out", "{tmp}", "--full-t-end", "1e9"], "--full-t-end: must be at most"),
    (["scale", "--out", "{tmp}", "--json", "{tmp}/missing/x.json"], "does not exist"),
    (["profile", "--target", "1,2"], "one target is taken here"),
    (["profile", "--paths", "--rtol", "1e-4,1e-6"], "one rtol is taken here"),
    (["cosim", "dumbbell,tetrahedra"], "one problem is taken here"),
    (["scale", "--out", "{tmp}", "--target", "2,3"], "one target is taken here"),
])
def test_bad_arguments_of_every_command_are_one_line_before_any_run(argv, words, tmp_path,
                                                                     capsys):
    """Huge or out-of-range settings ran for ever (cosim --t-end 1e300, a
    communication step of 1e-12), printed a time per iteration of zero steps
    (profile), or exited 0 or 1 after the measurements (scale), and a list
    where one value is taken was cut to its first; now exit 2 with one line,
    before anything runs."""
    from benchmarks.__main__ import main as benchmarks_main
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        code = benchmarks_main(argv)
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not any(tmp_path.glob("scale*"))
