"""The ``hfdi-validate`` command line."""
import json
import subprocess
import sys

import pytest

import hfdi

from validation.cli import main
from validation.experiments import EXPERIMENTS, paper_row

FIELDS = {"problem", "scheme", "target", "steps", "mean_iterations", "mean_step", "cpu_time",
          "status", "message", "t_reached", "eps"}


@pytest.mark.slow
def test_table_json_has_every_field(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "cache"))
    out, csv_out = tmp_path / "runs.json", tmp_path / "runs.csv"
    assert main(["table", "dumbbell", "--schemes", "hfdi,newmark", "--targets", "3.3",
                 "--t-end", "0.5", "--json", str(out), "--csv", str(csv_out)]) == 0
    records = json.loads(out.read_text())
    assert [(r["scheme"], r["target"]) for r in records] == [("hfdi", 3.3), ("newmark", 3.3)]
    for r in records:
        assert FIELDS <= set(r)
        assert r["status"] == "SUCCESS" and r["t_reached"] == 0.5
        assert r["steps"] > 0 and r["mean_iterations"] > 0
        assert set(r["eps"]) == {"u", "stretch"}
        assert 0 < r["eps"]["u"] < 1e-2
    # HFDI is the more accurate at equal target
    assert records[0]["eps"]["u"] < records[1]["eps"]["u"]
    printed = capsys.readouterr().out
    assert "HFDI" in printed and "Newmark" in printed and "(paper)" in printed
    assert "ε_u" in printed
    header = csv_out.read_text().splitlines()[0].split(",")
    assert "eps_u" in header and "eps_stretch" in header


def test_unknown_problem_is_one_clear_line(capsys):
    assert main(["table", "pendulum"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown problem 'pendulum'" in err[0]


def test_models_are_listed(capsys):
    assert main(["models"]) == 0
    printed = capsys.readouterr().out
    for name in ("dumbbell", "tetrahedra", "articulated", "toss_rule"):
        assert name in printed
    assert "n_elements = 6" in printed


@pytest.mark.parametrize("args", [["--schemes", "euler"], ["--targets", "0.5"],
                                  ["--targets", "x"], ["--t-end", "-1"]])
@pytest.mark.slow
def test_bad_arguments_exit_nonzero_without_traceback(args):
    proc = subprocess.run([sys.executable, "-m", "validation", "table", "dumbbell", *args],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "error" in proc.stderr


def test_paper_tables_are_complete():
    assert paper_row("dumbbell", "hfdi", 3.3)["steps"] == 45
    assert paper_row("dumbbell", "newmark", 4.5) is None          # "div"
    for name, exp in EXPERIMENTS.items():
        assert name in hfdi.models.available()
        # the paper's table has a row for every target of every scheme of its
        # tables, and no other (generalized-α is not in the paper)
        assert set(exp.paper) == set(exp.targets) == set(hfdi.PAPER_SCHEMES)
        for scheme, targets in exp.targets.items():
            assert sorted(exp.paper[scheme]) == sorted(targets), (name, scheme)
        # the runs the figures draw are runs of the table
        for runs in exp.shown_runs.values():
            assert all(target in exp.targets[scheme] for scheme, target in runs), name
        assert exp.long_time >= exp.observation_time > 0


def test_paper_facts_are_not_in_the_models():
    """T_o, the targets and the long T_o are the experiments' (validation.experiments)."""
    for name in hfdi.models.available():
        model = hfdi.models.get(name)
        for field in ("observation_time", "paper_targets", "long_observation_time"):
            assert not hasattr(model, field), (name, field)


@pytest.mark.slow
def test_table_rtol_runs_are_error_controlled(tmp_path, capsys, monkeypatch):
    """``--rtol``: error-controlled runs, more accurate the tighter the tolerance,
    labelled by rtol and without the paper's rows (it has no such runs)."""
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "runs.json"
    # 600 and 3,200 steps on the Python path (1e-3 and 1e-6 to 0.5 s: 38,000)
    assert main(["table", "dumbbell", "--schemes", "hfdi", "--rtol", "1e-2,1e-4",
                 "--t-end", "0.2", "--json", str(out)]) == 0
    records = json.loads(out.read_text())
    assert [(r["target"], r["rtol"]) for r in records] == [(None, 1e-2), (None, 1e-4)]
    assert all(r["status"] == "SUCCESS" for r in records)
    assert records[1]["eps"]["u"] < 0.1 * records[0]["eps"]["u"]
    assert records[1]["steps"] > records[0]["steps"]
    printed = capsys.readouterr().out
    assert "rtol" in printed and "1e-04" in printed and "(paper)" not in printed


def test_table_compiled_takes_the_same_steps(tmp_path, monkeypatch):
    """``--compiled``: the same runs (steps, N̄, Δt_mv) in compiled code."""
    records = {}
    for compiled in (False, True):
        out = tmp_path / f"runs-{compiled}.json"
        assert main(["table", "dumbbell", "--schemes", "hfdi,newmark", "--targets", "3.3",
                     "--t-end", "0.2", "--no-eps", "--json", str(out)]
                    + (["--compiled"] if compiled else [])) == 0
        records[compiled] = json.loads(out.read_text())
    same = ("scheme", "target", "steps", "mean_iterations", "mean_step", "status")
    assert [{k: r[k] for k in same} for r in records[False]] == \
        [{k: r[k] for k in same} for r in records[True]]


def test_the_runs_of_all_and_figures_take_compiled(monkeypatch):
    """``all --compiled`` and ``figures --compiled`` hand it to every run of
    the problem (ProblemRuns): the same steps and N̄, the steps compiled."""
    import validation.runs as runs
    asked = []

    def integrate(*args, compiled=False, **kwargs):
        asked.append(compiled)
        return hfdi_integrate(*args, compiled=compiled, **kwargs)
    hfdi_integrate = runs.integrate
    monkeypatch.setattr(runs, "integrate", integrate)
    results = {}
    for compiled in (False, True):
        ctx = runs.ProblemRuns("dumbbell", ("hfdi",), (3.0,), t_end=0.2, compiled=compiled)
        results[compiled] = ctx.run("hfdi", 3.0)
    # the Python path's run, then the compiled one's loading run and its run
    assert asked == [False, None, None]
    assert results[True].stats.steps == results[False].stats.steps
    assert results[True].stats.mean_iterations == results[False].stats.mean_iterations


@pytest.mark.parametrize("bad", ["0.5", "1e-20", "x", ""])
def test_table_rtol_out_of_range_is_one_line(bad, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["table", "dumbbell", "--rtol", bad])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rtol" in err[0]


@pytest.mark.parametrize("args", [["table", "dumbbell", "--t-end", "1e300"],
                                  ["all", "--problems", "dumbbell", "--long-t-end", "1e9"]])
def test_absurd_t_end_is_refused_before_any_work(tmp_path, capsys, args):
    """--t-end = 1e300 used to be accepted; the IDA reference then ran without
    end, memory growing."""
    assert main([*args, "--out", str(tmp_path / "out")] if args[0] != "table" else args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is too long for dumbbell: at most 100" in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option", ["--json", "--csv"])
def test_table_outputs_are_written_atomically(option, tmp_path, monkeypatch, capsys):
    """A failure while writing (the disk full) leaves the previous file."""
    import os
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "runs.out"
    out.write_text("previous")

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    assert main(["table", "dumbbell", "--schemes", "hfdi", "--targets", "3.3", "--t-end", "0.2",
                 "--no-eps", option, str(out)]) != 0
    assert out.read_text() == "previous"
    assert [p.name for p in tmp_path.iterdir() if p.name != "cache"] == ["runs.out"]



# -- generalized-α: a scheme of the library, not of the paper -------------------------

def test_every_scheme_has_a_style_and_the_papers_keep_theirs():
    """Colours and markers come from the scheme registry with a fallback: no
    KeyError for generalized-α or a scheme added later."""
    from validation.experiments import SCHEME_COLOURS, SchemeStyle
    assert [SCHEME_COLOURS[s] for s in ("newmark", "bathe", "hfdi")] == [
        "tab:blue", "tab:orange", "tab:green"]
    colours = [SCHEME_COLOURS[s] for s in hfdi.SCHEMES]
    assert len(set(colours)) == len(colours) and "generalized_alpha" in SCHEME_COLOURS
    assert SCHEME_COLOURS["not_a_scheme"] == "tab:gray"
    markers = SchemeStyle(("o",), "x")
    assert {markers[s] for s in hfdi.SCHEMES} == {"o"} and markers["other"] == "x"
    assert list(SCHEME_COLOURS) == list(hfdi.SCHEMES)


def test_table_targets_are_the_papers_for_its_schemes_only():
    from validation.experiments import OTHER_SCHEME_TARGETS
    for name, exp in EXPERIMENTS.items():
        for scheme in hfdi.PAPER_SCHEMES:
            assert exp.table_targets(scheme) == tuple(exp.targets[scheme])
        assert "generalized_alpha" not in exp.targets and "generalized_alpha" not in exp.paper
        assert exp.table_targets("generalized_alpha") == OTHER_SCHEME_TARGETS
    with pytest.raises(ValueError, match="unknown scheme 'euler'; available: newmark"):
        EXPERIMENTS["dumbbell"].table_targets("euler")
    with pytest.raises(KeyError):
        paper_row("dumbbell", "generalized_alpha", 3.0)


def test_schemes_option_takes_generalized_alpha_and_names_it_when_refusing():
    import argparse
    from validation import options as opt
    assert opt.schemes("generalized_alpha, HFDI") == ["generalized_alpha", "hfdi"]
    with pytest.raises(argparse.ArgumentTypeError,
                       match="unknown scheme.*'euler'.*generalized_alpha"):
        opt.schemes("euler")


def test_models_lists_the_default_targets_of_the_other_schemes(capsys):
    assert main(["models"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("default targets of the other schemes (not in the paper): "
                         "generalized_alpha 3, 3.5, 4, 4.5, 5") == len(EXPERIMENTS)


def test_generalized_alpha_table_has_its_own_targets_and_no_paper_rows(tmp_path, capsys):
    """``table --schemes generalized_alpha``: the documented default targets
    (OTHER_SCHEME_TARGETS), beside no paper numbers (the paper has none)."""
    out = tmp_path / "runs.json"
    assert main(["table", "dumbbell", "--schemes", "generalized_alpha,hfdi", "--t-end", "0.1",
                 "--no-eps", "--json", str(out)]) == 0
    records = json.loads(out.read_text())
    assert [(r["scheme"], r["target"]) for r in records] == [
        ("generalized_alpha", t) for t in (3.0, 3.5, 4.0, 4.5, 5.0)] + [
        ("hfdi", t) for t in (3.0, 3.1, 3.2, 3.3, 3.5)]
    assert all(r["status"] == "SUCCESS" and r["steps"] > 0 for r in records)
    printed = capsys.readouterr().out
    # HFDI first, in the order of hfdi.SCHEMES; the paper's numbers beneath it only
    theirs, ours = printed.split("GeneralizedAlpha\n")
    assert "HFDI\n" in theirs and "(paper)" in theirs
    assert "(paper)" not in ours and "N_mv" in ours


def test_a_table_of_every_scheme_is_in_registry_order():
    from validation.runs import RunRecord
    from validation.tables import format_table
    records = [RunRecord("dumbbell", s, 3.0, 10, 3.0, 0.01, 0.1, "SUCCESS", "", 0.1)
               for s in reversed(list(hfdi.SCHEMES))]
    text = format_table(records)
    titles = [line for line in text.splitlines() if line and not line.startswith(" ")]
    assert titles == ["Newmark", "Bathe", "HFDI", "GeneralizedAlpha"]
    assert text.count("(paper)") == 3 * 4         # four rows under each paper scheme


@pytest.mark.slow
def test_the_report_says_a_scheme_is_not_in_the_paper():
    from validation.report import _comparison_summary, stability_schemes
    from validation.runs import RunRecord
    records = [RunRecord("dumbbell", s, 3.0, 10, 3.0, 0.01, 0.1, "SUCCESS", "", 2.0)
               for s in ("hfdi", "generalized_alpha")]
    lines = _comparison_summary("dumbbell", records)
    assert lines[0].startswith("- HFDI: steps ours/paper")
    assert lines[1] == ("- GeneralizedAlpha: not in the paper (its targets: 3.0); div here "
                        "at N̄ = none.")
    # the stability outputs of `all`: the paper's three, then the other schemes asked for
    assert stability_schemes(["hfdi"]) == ["newmark", "bathe", "hfdi"]
    assert stability_schemes(["generalized_alpha", "bathe"]) == [
        "newmark", "bathe", "hfdi", "generalized_alpha"]


def test_stability_rows_of_generalized_alpha_reach_its_rho_inf():
    from validation.stability import stability_rows
    rows = stability_rows([0.01, 1e4], ["generalized_alpha"])
    assert [(r["scheme"], r["ratio"]) for r in rows] == [("generalized_alpha", 0.01),
                                                         ("generalized_alpha", 1e4)]
    assert rows[0]["spectral_radius"] == pytest.approx(1.0, abs=1e-3)
    assert rows[1]["spectral_radius"] == pytest.approx(0.8, abs=1e-3)   # ρ∞ = 0.8
