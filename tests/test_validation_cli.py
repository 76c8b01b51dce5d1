"""The ``hfdi-validate`` command line."""
import json
import subprocess
import sys

import pytest

from validation.cli import main
from validation.paper import PAPER_TABLES, paper_row

FIELDS = {"problem", "scheme", "target", "steps", "mean_iterations", "mean_step", "cpu_time",
          "status", "message", "t_reached", "eps"}


def test_table_json_has_every_field(tmp_path, capsys):
    out = tmp_path / "runs.json"
    assert main(["table", "dumbbell", "--schemes", "hfdi,newmark", "--targets", "3.3",
                 "--t-end", "0.5", "--json", str(out)]) == 0
    records = json.loads(out.read_text())
    assert [(r["scheme"], r["target"]) for r in records] == [("hfdi", 3.3), ("newmark", 3.3)]
    for r in records:
        assert FIELDS <= set(r)
        assert r["status"] == "SUCCESS" and r["t_reached"] == 0.5
        assert r["steps"] > 0 and r["mean_iterations"] > 0
    printed = capsys.readouterr().out
    assert "HFDI" in printed and "Newmark" in printed and "(paper)" in printed


def test_unknown_problem_is_one_clear_line(capsys):
    assert main(["table", "pendulum"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown problem 'pendulum'" in err[0]


@pytest.mark.parametrize("args", [["--schemes", "euler"], ["--targets", "0.5"],
                                  ["--targets", "x"], ["--t-end", "-1"]])
def test_bad_arguments_exit_nonzero_without_traceback(args):
    proc = subprocess.run([sys.executable, "-m", "validation", "table", "dumbbell", *args],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "error" in proc.stderr


def test_paper_tables_are_complete():
    for problem, schemes in PAPER_TABLES.items():
        assert set(schemes) == {"newmark", "bathe", "hfdi"}
    assert paper_row("dumbbell", "hfdi", 3.3)["steps"] == 45
    assert paper_row("dumbbell", "newmark", 4.5) is None          # "div"
