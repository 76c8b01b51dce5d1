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
        # the paper's table has a row for every target of every scheme, and no other
        assert set(exp.paper) == set(exp.targets) == set(hfdi.SCHEMES)
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
    assert main(["table", "dumbbell", "--schemes", "hfdi", "--rtol", "1e-3,1e-6",
                 "--t-end", "0.5", "--json", str(out)]) == 0
    records = json.loads(out.read_text())
    assert [(r["target"], r["rtol"]) for r in records] == [(None, 1e-3), (None, 1e-6)]
    assert all(r["status"] == "SUCCESS" for r in records)
    assert records[1]["eps"]["u"] < 0.1 * records[0]["eps"]["u"]
    assert records[1]["steps"] > records[0]["steps"]
    printed = capsys.readouterr().out
    assert "rtol" in printed and "1e-06" in printed and "(paper)" not in printed


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


def test_table_json_is_written_atomically(tmp_path, monkeypatch, capsys):
    """A failure while writing (the disk full) leaves the previous file."""
    import os
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "runs.json"
    out.write_text("previous")

    def disk_full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    assert main(["table", "dumbbell", "--schemes", "hfdi", "--targets", "3.3", "--t-end", "0.2",
                 "--no-eps", "--json", str(out)]) != 0
    assert out.read_text() == "previous"
    assert [p.name for p in tmp_path.iterdir() if p.name != "cache"] == ["runs.json"]

