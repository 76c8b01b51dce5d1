"""``--jobs`` and ``--dask``: the same results in every mode, and clear failures.

* ``hfdi-validate table`` of several problems, serially and with two worker
  processes: the same records, field by field, apart from the measured CPU
  time, and the same printed tables apart from the t_T rows.
* ``hfdi-validate all``, serially and with two workers: the same files; the
  PNGs byte for byte, the JSON apart from timing fields, ``report.md`` apart
  from its t_T column and header.
* On a Dask ``LocalCluster`` (skipped without the ``dask`` extra), whose
  workers have a reference cache of their own (empty): they compute the
  references themselves, and the records are the same again.
* ``Runner`` returns a task's exception as the serial run raises it; bad
  ``--jobs``/``--dask`` values, a missing ``dask`` extra, Ctrl-C and a killed
  parent.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from problems import sigint_as_in_a_terminal
from validation import parallel
from validation.cli import main
from validation.parallel import Runner, RunnerError
from validation.reference import IDAError

# every test here runs worker processes and a Dask cluster: not in the quick loop
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
TIMING = {"cpu_time", "wall_time"}
PROBLEMS = "dumbbell,articulated"
SHORT = ["--t-end", "0.25", "--targets", "3.5,4.5"]


def without_timing(value):
    """``value`` (parsed JSON) without its measured times, at any depth."""
    if isinstance(value, dict):
        return {k: without_timing(v) for k, v in value.items() if k not in TIMING}
    if isinstance(value, list):
        return [without_timing(v) for v in value]
    return value


def without_t_T(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if "t_T" not in line)


def table(args, tmp_path, capsys, name):
    out = tmp_path / f"{name}.json"
    assert main(["table", PROBLEMS, *SHORT, "--json", str(out), *args]) == 0
    printed = capsys.readouterr()
    return json.loads(out.read_text()), printed.out, printed.err


@pytest.fixture
def cache(tmp_path, monkeypatch):
    path = tmp_path / "cache"
    monkeypatch.setenv("HFDI_CACHE_DIR", str(path))
    return path


# -- Runner --------------------------------------------------------------------------------

def square(x):
    return x * x, os.getpid()


def fail_at(x, bad):
    if x in bad:
        # an exception whose __init__ does not take its args: not picklable as is
        raise IDAError(-3, f"failed on {x}", "[IDASolve, Error: -3]", 0.5 * x)
    return x


def test_runner_orders_results_and_uses_processes():
    serial = Runner(1).map(square, [(i,) for i in range(8)])
    seen = []
    with Runner(2) as runner:
        first = runner.map(square, [(i,) for i in range(8)], on_result=lambda i, r: seen.append(i))
        second = runner.map(square, [(i,) for i in range(8, 12)])        # the same pool
    assert [r for r, _ in first] == [r for r, _ in serial] == [i * i for i in range(8)]
    assert [r for r, _ in second] == [i * i for i in range(8, 12)]
    assert seen == list(range(8))
    assert {pid for _, pid in serial} == {os.getpid()}
    assert os.getpid() not in {pid for _, pid in first + second}


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_task_exception_comes_back_as_in_a_serial_run(jobs):
    with pytest.raises(IDAError) as info:
        # the first failure in the order of the tasks, whichever finishes first
        Runner(jobs).map(fail_at, [(i, (3, 5)) for i in range(8)])
    exc = info.value
    assert (exc.status, exc.message, exc.t) == (-3, "failed on 3", 1.5)
    assert str(exc).startswith("IDA failed with status -3 at t = 1.5: failed on 3")


def threads(_):
    return parallel.blas_threads()


@pytest.mark.parametrize("start", ["fork", "spawn"])
def test_tasks_run_with_one_blas_thread_in_every_mode(start, monkeypatch):
    # a spawned worker reads OPENBLAS_NUM_THREADS when it starts, this process
    # did long ago: only the setting at run time makes them agree
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    monkeypatch.setattr(parallel, "_start_method", lambda: start)
    before = parallel.blas_threads()
    assert len(before) >= 2                         # numpy's and scipy's OpenBLAS
    for jobs in (1, 2):
        for counts in Runner(jobs).map(threads, [(i,) for i in range(4)]):
            assert counts and set(counts) == {1}, (jobs, counts)
    assert parallel.blas_threads() == before        # this process's setting is put back
    with Runner(1):                                 # a serial caller inside the block
        assert set(parallel.blas_threads()) == {1}
    assert parallel.blas_threads() == before


def test_bad_jobs_are_refused():
    for jobs in (0, -1, 1.5, True, parallel.max_jobs() + 1, 10**20):
        with pytest.raises(ValueError, match=r"jobs must be an integer in \[1, "):
            Runner(jobs)
    assert Runner(parallel.max_jobs()).jobs == parallel.max_jobs()


def test_a_jobs_count_beyond_the_machine_is_a_usage_error(capsys):
    """``--jobs 100000`` forked thousands of workers; ``--jobs 1e20`` raised an
    OverflowError with a traceback. Both are exit 2 with one line."""
    from validation.cli import main
    for text in ("100000", "99999999999999999999", "0", "two"):
        with pytest.raises(SystemExit) as info:
            main(["table", "dumbbell", "--jobs", text])
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert "--jobs" in err and "Traceback" not in err


# -- identical results ---------------------------------------------------------------------

def test_table_with_two_jobs_gives_the_serial_records(tmp_path, capsys, cache):
    # a fresh cache: the parent computes the references, the workers load them
    serial, out1, err1 = table([], tmp_path, capsys, "serial")
    assert "computed once" in err1
    jobs2, out2, err2 = table(["--jobs", "2"], tmp_path, capsys, "jobs2")
    assert [(r["problem"], r["scheme"], r["target"]) for r in serial] == \
        [(r["problem"], r["scheme"], r["target"]) for r in jobs2]
    assert len(serial) == 2 * 3 * 2 and {r["problem"] for r in serial} == {"dumbbell",
                                                                         "articulated"}
    assert all(r["eps"] for r in serial)
    assert without_timing(serial) == without_timing(jobs2)
    assert without_t_T(out1) == without_t_T(out2)
    assert out1.count("computational characteristics") == 2
    # progress lines in the order of the runs in both modes
    assert err1.splitlines() == err2.splitlines()


def test_one_problem_prints_as_before(tmp_path, capsys, cache):
    assert main(["table", "dumbbell", *SHORT, "--no-eps"]) == 0
    printed = capsys.readouterr()
    assert printed.out.startswith("dumbbell: computational characteristics (ours, with the "
                                  "paper's beneath)\n\nNewmark\n")
    assert printed.err.splitlines()[0].startswith("  newmark  N̄=3.5  steps=")


def all_outputs(out: Path) -> dict:
    return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def assert_same_outputs(a: Path, b: Path) -> None:
    """Two ``all`` directories hold the same outputs, apart from measured times."""
    first, second = all_outputs(a), all_outputs(b)
    assert set(first) == set(second)
    for name, data in first.items():
        other = second[name]
        if name.suffix == ".json":
            assert without_timing(json.loads(data)) == without_timing(json.loads(other)), name
        elif name.name == "report.md":
            lines, others = data.decode().splitlines(), other.decode().splitlines()
            assert len(lines) == len(others)
            for x, y in zip(lines, others):
                if x.startswith("Made by"):
                    continue
                if x.startswith("| ") and x != y:
                    # the t_T column (ours) is the 9th cell of the table rows
                    x, y = x.split("|"), y.split("|")
                    del x[9], y[9]
                assert x == y
        else:
            assert data == other, name           # the figures, byte for byte


def test_all_with_two_jobs_writes_the_serial_outputs(tmp_path, cache):
    args = ["all", "--problems", "dumbbell", "--t-end", "0.25", "--long-t-end", "0.25",
            "--targets", "3.5,4.5", "--ratios", "0.1,1"]
    assert main([*args, "--out", str(tmp_path / "serial")]) == 0
    assert main([*args, "--out", str(tmp_path / "jobs2"), "--jobs", "2"]) == 0
    assert_same_outputs(tmp_path / "serial", tmp_path / "jobs2")
    names = {p.name for p in all_outputs(tmp_path / "jobs2")}
    assert {"dumbbell_table.json", "dumbbell_reference_convergence.json", "stability.json",
            "report.md", "dumbbell_fig05_stretch.png"} <= names
    # a rerun with two jobs finds everything done
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "jobs2").rglob("*.png")}
    assert main([*args, "--out", str(tmp_path / "jobs2"), "--jobs", "2"]) == 0
    assert before == {p: p.stat().st_mtime_ns for p in (tmp_path / "jobs2").rglob("*.png")}


# -- failures ------------------------------------------------------------------------------

def run_cli(*args, env=None, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))
    return subprocess.run([sys.executable, "-m", "validation", *args], env=env,
                          capture_output=True, text=True, timeout=120, **kw)


@pytest.mark.parametrize("args, expect", [
    (["table", "dumbbell", "--jobs", "0"], "argument --jobs: must be an integer in [1, "),
    (["table", "dumbbell", "--jobs", "x"], "argument --jobs: must be an integer in [1, "),
    (["all", "--out", "unused", "--jobs", "-2"], "argument --jobs"),
    (["table", "dumbbell", "--dask", ""], "argument --dask"),
])
def test_bad_option_is_one_line(args, expect, capsys):
    with pytest.raises(SystemExit) as info:
        main(args)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0], err


def test_dask_without_the_extra_says_what_to_install(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)        # import fails
    assert main(["table", "dumbbell", "--dask", "tcp://127.0.0.1:8786"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--dask" in err[0] and "install the 'dask' extra" in err[0], err


def raise_value_error(*_):
    raise ValueError("the model refuses this run")


def test_a_worker_exception_is_the_serial_one_line_error(tmp_path, capsys, cache, monkeypatch):
    if parallel._start_method() != "fork":
        # (spawned workers: not on Linux, or a thread left by an earlier test)
        pytest.skip("the patched function reaches the workers by fork only")
    import validation.runs as runs
    monkeypatch.setattr(runs, "run_experiment", raise_value_error)
    lines = []
    for jobs in ("1", "2"):
        assert main(["table", PROBLEMS, *SHORT, "--no-eps", "--jobs", jobs]) == 1
        lines.append(capsys.readouterr().err.strip().splitlines())
    assert lines[0] == lines[1] == ["hfdi-validate: error: the model refuses this run"]


def children(pid: int) -> list:
    proc = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True)
    return [int(p) for p in proc.stdout.split()]


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc").is_dir() or os.name != "posix",
                    reason="needs /proc and process groups")
@pytest.mark.parametrize("how", ["ctrl-c", "kill"])
def test_interrupted_parallel_table_leaves_no_worker(how, tmp_path):
    """Ctrl-C in a terminal signals the whole process group: exit 130, one
    line; a killed parent: its workers exit on their own."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), HFDI_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.Popen([sys.executable, "-m", "validation", "table",
                             "dumbbell,tetrahedra,articulated,toss_rule", "--no-eps",
                             "--jobs", "2"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=sigint_as_in_a_terminal)
    try:
        proc.stderr.readline()                         # the first run is done: workers are up
        workers = children(proc.pid)
        assert len(workers) == 2
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.kill()
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    if how == "ctrl-c":
        assert proc.returncode == 130
        assert "Traceback" not in err
        assert err.splitlines()[-1].startswith("hfdi-validate: interrupted")
    deadline = time.monotonic() + 10
    while any(alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(alive(w) for w in workers)


# -- Dask ----------------------------------------------------------------------------------

def test_dask_local_cluster_gives_the_serial_records(tmp_path, capsys, cache):
    distributed = pytest.importorskip("distributed")
    serial, out1, _ = table([], tmp_path, capsys, "serial")
    # The workers' cache is another, empty directory (as on other machines):
    # they compute the references themselves, and get the same ones.
    worker_cache = tmp_path / "worker-cache"
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=":0",
                                  env={"HFDI_CACHE_DIR": str(worker_cache)}) as cluster:
        on_dask, out2, _ = table(["--dask", cluster.scheduler_address], tmp_path, capsys,
                                 "dask")
        pids = Runner(dask_address=cluster.scheduler_address).map(square, [(1,), (2,)])
    assert without_timing(serial) == without_timing(on_dask)
    assert without_t_T(out1) == without_t_T(out2)
    assert os.getpid() not in {pid for _, pid in pids}
    assert list(worker_cache.glob("reference-*.npz"))


def test_unreachable_scheduler_fails_in_bounded_time():
    pytest.importorskip("distributed")
    start = time.monotonic()
    with pytest.raises(RunnerError, match=r"--dask tcp://127.0.0.1:1: cannot connect"):
        with Runner(dask_address="tcp://127.0.0.1:1", connect_timeout=1.0):
            pass
    assert time.monotonic() - start < 30
    with pytest.raises(RunnerError, match="is not a scheduler address"):
        Runner(dask_address="no-port").map(square, [(1,)])
