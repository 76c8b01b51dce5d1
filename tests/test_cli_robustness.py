"""Bad arguments and interruptions of ``hfdi-validate``, ``hfdi-fmu`` and
``python -m benchmarks``.

* Every bad argument exits non-zero with exactly one line on stderr that
  says what is wrong, no traceback, nothing on stdout, and nothing written
  to the working directory. The cases call each command's ``main`` in this
  process (a Python start with hfdi's imports costs about a second a case);
  those that reach a Dask scheduler, whose client leaves threads behind, run
  as the user runs them, in a subprocess ``python -m ...``.
* ``hfdi-validate all`` interrupted (SIGINT, SIGKILL) after it has written
  some outputs keeps them and the reference cache intact, leaves no
  temporary file in the output directory (SIGINT at once; SIGKILL after the
  next call), and a rerun skips what was done.

``python tests/test_cli_robustness.py`` prints the table of bad arguments and
the line each prints; with ``--write`` it puts the table in
``docs/robustness.md``.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from problems import sigint_as_in_a_terminal, write_doc_table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
# benchmarks/ is not installed: it is imported from the repository's root
sys.path.insert(0, str(ROOT))
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
# write_atomic's and the reference cache's temporary files: ".<name>.<random>.tmp"
TEMPORARY = re.compile(r"\..*\.tmp")


@dataclass(frozen=True)
class Case:
    """One bad command line.

    Attributes
    ----------
    module : str
        ``validation``, ``fmu`` or ``benchmarks``.
    args : tuple of str
        Arguments; ``{FILE}`` (a regular file), ``{RO}`` (a directory that
        cannot be written), ``{DIR}`` (a fresh directory), ``{ZIP}`` (a zip
        that is no FMU) and ``{OTHER_FMU}`` (an FMU of another model than
        the dumbbell) are filled in.
    expect : str
        A piece of the one line the command must print.
    """

    module: str
    args: tuple
    expect: str

    @property
    def command(self) -> str:
        """The command as the user types it, placeholders kept."""
        prog = {"validation": "hfdi-validate", "fmu": "hfdi-fmu",
                "benchmarks": "python -m benchmarks"}[self.module]
        return " ".join([prog, *(a if a.strip() else repr(a) for a in self.args)])


def V(*args, expect):
    """A bad ``hfdi-validate`` command line (see :class:`Case`)."""
    return Case("validation", args, expect)


def F(*args, expect):
    """A bad ``hfdi-fmu`` command line (see :class:`Case`)."""
    return Case("fmu", args, expect)


def B(*args, expect):
    """A bad ``python -m benchmarks`` command line (see :class:`Case`)."""
    return Case("benchmarks", args, expect)


BAD_TARGETS = ("0", "-1", "nan", "inf", "1e300", "text")
BAD_T_END = ("0", "-1", "nan", "inf", "text", "5e-324")
# figures and all take the same --targets and --t-end as table (one parser
# type each, and the same check of the runs): every value goes through
# table, some through figures and all.
SOME_TARGETS = ("0", "nan", "1e300", "text")
SOME_T_END = ("-1", "inf", "5e-324")


def t_end_complaint(value, problem="dumbbell"):
    """What a bad ``--t-end`` must be called: by the parser, or for one
    too close to t0 to step between, by the library before any run."""
    return f"cannot run {problem} to t = 4.94066e-324" if value == "5e-324" else "--t-end"


CASES = [
    # -- hfdi-validate: the command itself
    V(expect="required: command"),
    V("frobnicate", expect="invalid choice: 'frobnicate'"),
    V("models", "extra", expect="unrecognized arguments: extra"),
    # -- table
    V("table", expect="required: problem"),
    V("table", "pendulum", expect="unknown problem 'pendulum'"),
    V("table", "dumbbell", "--schemes", "euler", expect="unknown scheme(s) 'euler'"),
    V("table", "dumbbell", "--schemes", "", expect="unknown scheme(s) ''"),
    *[V("table", "dumbbell", "--targets", t, expect="--targets") for t in BAD_TARGETS],
    *[V("table", "dumbbell", "--t-end", t, expect=t_end_complaint(t)) for t in BAD_T_END],
    V("table", "dumbbell", "--t-end", expect="--t-end: expected one argument"),
    V("table", "dumbbell", "--json", "{FILE}/runs.json", expect="is not a directory"),
    V("table", "dumbbell", "--json", "{DIR}/missing/runs.json", expect="does not exist"),
    V("table", "dumbbell", "--csv", "{DIR}", expect="is a directory"),
    V("table", "dumbbell", "--csv", "{RO}/runs.csv", expect="is not writable"),
    V("table", "dumbbell", "--bogus", expect="unrecognized arguments: --bogus"),
    V("table", "dumbbell,pendulum", expect="unknown problem 'pendulum'"),
    # -- --jobs and --dask (table and all share them). An unreachable scheduler
    # is given up after 10 s; without the 'dask' extra every --dask says to
    # install it: the line names --dask either way.
    *[V("table", "dumbbell", "--jobs", j, expect="--jobs") for j in ("0", "-1", "x", "1.5")],
    V("table", "dumbbell", "--dask", "", expect="--dask"),
    V("table", "dumbbell", "--dask", "no-port", expect="--dask"),
    V("table", "dumbbell", "--dask", "tcp://127.0.0.1:1", expect="--dask"),
    # -- figures
    V("figures", expect="required: problem, --out"),
    V("figures", "dumbbell", expect="required: --out"),
    V("figures", "pendulum", "--out", "{DIR}/x", expect="unknown problem 'pendulum'"),
    V("figures", "dumbbell", "--out", "{DIR}/x", "--schemes", "euler",
      expect="unknown scheme(s) 'euler'"),
    *[V("figures", "dumbbell", "--out", "{DIR}/x", "--targets", t, expect="--targets")
      for t in SOME_TARGETS[:3]],
    *[V("figures", "dumbbell", "--out", "{DIR}/x", "--t-end", t, expect=t_end_complaint(t))
      for t in SOME_T_END],
    V("figures", "dumbbell", "--out", "{DIR}/x", "--long-t-end", "0",
      expect="--long-t-end"),
    V("figures", "dumbbell", "--out", "{FILE}", expect="exists and is not a directory"),
    V("figures", "dumbbell", "--out", "{FILE}/sub", expect="cannot create --out"),
    V("figures", "dumbbell", "--out", "{RO}", expect="is not writable"),
    V("figures", "dumbbell", "--out", "", expect="--out must name a directory"),
    # -- stability
    V("stability", expect="required: --out"),
    V("stability", "--out", "{FILE}", expect="exists and is not a directory"),
    V("stability", "--out", "{RO}", expect="is not writable"),
    V("stability", "--out", "", expect="--out must name a directory"),
    *[V("stability", "--out", "{DIR}/x", "--ratios", r, expect="--ratios")
      for r in ("0", "nan", "text", "")],
    # -- all
    V("all", expect="required: --out"),
    V("all", "--out", "{DIR}/x", "--problems", "dumbbell,pendulum",
      expect="unknown problem(s) 'pendulum'"),
    V("all", "--out", "{DIR}/x", "--schemes", "euler", expect="unknown scheme(s) 'euler'"),
    *[V("all", "--out", "{DIR}/x", "--targets", t, expect="--targets") for t in SOME_TARGETS],
    # every problem is checked before the first run, in the paper's order: the
    # first to refuse is named
    *[V("all", "--out", "{DIR}/x", "--t-end", t, expect=t_end_complaint(t, "dumbbell"))
      for t in SOME_T_END],
    V("all", "--out", "{DIR}/x", "--ratios", "-1", expect="--ratios"),
    V("all", "--out", "{FILE}", expect="exists and is not a directory"),
    V("all", "--out", "{RO}", expect="is not writable"),
    V("all", "--out", "", expect="--out must name a directory"),
    V("all", "--out", "{DIR}/x", "--jobs", "0", expect="--jobs"),
    V("all", "--out", "{DIR}/x", "--dask", "tcp://127.0.0.1:1", expect="--dask"),
    # -- hfdi-fmu
    F(expect="required: command"),
    F("frobnicate", expect="invalid choice: 'frobnicate'"),
    F("list", "extra", expect="unrecognized arguments: extra"),
    F("build", expect="required: problem"),
    F("build", "pendulum", "--out", "{DIR}/x", expect="unknown problem 'pendulum'"),
    F("build", "dumbbell", "--out", "{FILE}", expect="exists and is not a directory"),
    F("build", "dumbbell", "--out", "{FILE}/sub", expect="is not a writable directory"),
    F("build", "dumbbell", "--out", "{RO}", expect="is not a writable directory"),
    F("build", "dumbbell", "--out", "", expect="--out must name a directory"),
    F("build", "all", "--out", "{FILE}", expect="exists and is not a directory"),
    F("build", "dumbbell", "--bogus", expect="unrecognized arguments: --bogus"),
    F("demo", "pendulum", "--out", "{DIR}/x", expect="unknown problem 'pendulum'"),
    F("demo", "dumbbell", "--scheme", "euler", expect="invalid choice: 'euler'"),
    F("demo", "dumbbell", "--out", "{FILE}", expect="exists and is not a directory"),
    F("demo", "dumbbell", "--out", "{RO}", expect="is not a writable directory"),
    F("master", "{DIR}/missing.fmu", expect="does not exist"),
    F("master", "{FILE}", expect="is not an FMU"),
    F("master", "{ZIP}", expect="no modelDescription.xml"),
    F("master", "{OTHER_FMU}", expect="is the FMU of 'hfdi_tetrahedra'"),
    *[F("master", "--t-end", t, expect="--t-end") for t in ("0", "-1", "nan", "inf", "text")],
    F("master", "--step", "0", expect="--step"),
    F("master", "--step", "nan", expect="--step"),
    F("master", "--stiffness", "-1", expect="--stiffness"),
    F("master", "--damping", "nan", expect="--damping"),
    F("master", "--scheme", "euler", expect="invalid choice: 'euler'"),
    # -- python -m benchmarks
    B(expect="a command is required"),
    B("frobnicate", expect="unknown command 'frobnicate'"),
    B("precision", "--problems", "pendulum", expect="unknown problem(s) 'pendulum'"),
    B("precision", "--competitors", "cvode", expect="unknown competitor(s) 'cvode'"),
    B("precision", "--problems", "dumbbell", "--t-end", "1e9", "--out", "{DIR}/x",
      expect="is too long for dumbbell"),
    B("scale", "--out", "{DIR}/x", "--sizes", "a", expect="--sizes"),
    B("profile", "--targets", "3", expect="unrecognized arguments: --targets"),
    B("profile", "--target", "0", expect="--target"),
    B("cosim", "pendulum", expect="unknown problem(s) 'pendulum'"),
    B("cosim", "dumbbell", "--scheme", "euler", expect="invalid choice: 'euler'"),
    *[B("cosim", "dumbbell", "--repeats", r, expect="--repeats") for r in ("0", "-1", "text")],
    B("cosim", "dumbbell", "--json", "{FILE}/bench.json", expect="is not a directory"),
    B("cosim", "dumbbell", "--json", "{DIR}", expect="is a directory"),
]


def unwritable_directory(base: Path) -> str | None:
    """A directory this process cannot create files in, or ``None``.

    A directory without write permission, unless we are root (who may write
    anyway); then ``/sys/kernel``, which sysfs refuses even to root.
    """
    if os.name == "posix" and os.geteuid() != 0:
        path = base / "read-only"
        path.mkdir(exist_ok=True)
        path.chmod(0o555)
        return str(path)
    probe = Path("/sys/kernel")
    if probe.is_dir():
        try:
            with tempfile.TemporaryFile(dir=probe):
                return None
        except OSError:
            return str(probe)
    return None


def fixtures(base: Path) -> dict:
    """The files the placeholders of :class:`Case` stand for, made in ``base``.

    Returns
    -------
    dict
        Placeholder name to path (``RO`` may be ``None``: see
        :func:`unwritable_directory`).
    """
    regular = base / "a-file"
    regular.write_text("not a directory\n")
    not_fmu = base / "not-an-fmu.zip"
    with zipfile.ZipFile(not_fmu, "w") as archive:
        archive.writestr("readme.txt", "no modelDescription.xml here\n")
    other = base / "hfdi_tetrahedra.fmu"
    with zipfile.ZipFile(other, "w") as archive:
        archive.writestr("modelDescription.xml",
                         '<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription '
                         'fmiVersion="2.0" modelName="hfdi_tetrahedra" guid="x"/>\n')
    return {"FILE": str(regular), "ZIP": str(not_fmu), "OTHER_FMU": str(other),
            "RO": unwritable_directory(base)}


def _in_subprocess(case: Case) -> bool:
    """Whether ``case`` runs as a subprocess: a Dask client left behind (its
    threads) would change how later tests of this process fork."""
    return any(a.startswith("tcp://") for a in case.args)


def _main(module: str):
    if module == "validation":
        from validation.cli import main
    elif module == "fmu":
        from fmu.cli import main
    else:
        from benchmarks.__main__ import main
    return main


def _call(module: str, args: list, cwd: Path, env: dict) -> tuple:
    """``main(args)`` of ``module`` in this process, in ``cwd`` with ``env``:
    ``(exit status, stdout, stderr)``; an exception escaping ``main`` is a
    traceback on stderr, as the command would print it."""
    out, err = io.StringIO(), io.StringIO()
    old_cwd, old_env = os.getcwd(), dict(os.environ)
    os.chdir(cwd)
    os.environ.update(env)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = _main(module)(args)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            except BaseException:
                traceback.print_exc()
                code = 1
    finally:
        os.chdir(old_cwd)
        os.environ.clear()
        os.environ.update(old_env)
    return code, out.getvalue(), err.getvalue()


def run_case(case: Case, index: int, base: Path, files: dict) -> dict:
    """Run one bad command line in a fresh working directory.

    Returns
    -------
    dict
        ``returncode``, ``stdout``, ``stderr``, ``cwd`` (the working
        directory, to check nothing was written there), or ``skip`` when the
        case needs an unwritable directory and there is none.
    """
    if any("{RO}" in a for a in case.args) and files["RO"] is None:
        return {"skip": "no unwritable directory for this user"}
    cwd = base / f"case{index:03d}"
    scratch = base / f"dir{index:03d}"
    cwd.mkdir()
    scratch.mkdir()
    args = [a.format(DIR=scratch, **files) for a in case.args]
    env = {"HFDI_CACHE_DIR": str(base / "cache")}
    if _in_subprocess(case):
        proc = subprocess.run([sys.executable, "-m", case.module, *args], cwd=cwd,
                              env=dict(os.environ, PYTHONPATH=str(ROOT), **env),
                              capture_output=True, text=True, timeout=300)
        code, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
    else:
        code, stdout, stderr = _call(case.module, args, cwd, env)
    shown = stderr.strip()
    for name, path in [("DIR", scratch), *files.items()]:
        if path is not None:
            shown = shown.replace(str(path), "{%s}" % name)
    return {"returncode": code, "stdout": stdout, "stderr": stderr, "cwd": cwd, "shown": shown}


def run_all_cases(base: Path) -> dict:
    """Run every case of :data:`CASES`: the subprocesses in the background,
    the others meanwhile in this process, one after the other (they change
    the working directory)."""
    files = fixtures(base)
    indexed = list(enumerate(CASES))
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        futures = {case: pool.submit(run_case, case, i, base, files)
                   for i, case in indexed if _in_subprocess(case)}
        done = {case: run_case(case, i, base, files)
                for i, case in indexed if not _in_subprocess(case)}
        done.update({case: future.result() for case, future in futures.items()})
    return {case: done[case] for case in CASES}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return run_all_cases(tmp_path_factory.mktemp("bad-arguments"))


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=lambda c: c.command)
def test_bad_argument_is_one_clear_line(case, results):
    result = results[case]
    if "skip" in result:
        pytest.skip(result["skip"])
    err = result["stderr"]
    assert result["returncode"] != 0, err
    assert "Traceback" not in err, err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert "error" in lines[0] and case.expect in lines[0], lines[0]
    assert result["stdout"] == ""
    # and nothing written where the command ran (an empty --out is not ".")
    assert list(result["cwd"].iterdir()) == []


# -- an interrupted `hfdi-validate all` -------------------------------------------

ALL_ARGS = ["all", "--problems", "dumbbell", "--t-end", "0.3"]


def start_all(out: Path, cache: Path) -> subprocess.Popen:
    """Start ``hfdi-validate all`` on the short dumbbell in a subprocess.

    Parameters
    ----------
    out, cache : Path
        Output directory and reference cache (``HFDI_CACHE_DIR``).
    """
    env = dict(os.environ, HFDI_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, "-m", "validation", *ALL_ARGS, "--out", str(out)],
                            cwd=out.parent, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=sigint_as_in_a_terminal)


def wait_for(proc: subprocess.Popen, path: Path, timeout: float = 120.0) -> None:
    """Poll until ``path`` exists (``all`` writes it atomically, so it is complete)."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"finished before writing {path}: {proc.communicate()}"
        assert time.monotonic() < deadline, f"{path} not written in {timeout} s"
        time.sleep(0.02)


def outputs(out: Path) -> dict:
    """Every file under ``out`` (temporary ones included) with its mtime."""
    return {p: p.stat().st_mtime_ns for p in sorted(out.rglob("*")) if p.is_file()}


def temporaries(directory: Path) -> list:
    """Temporary files of an atomic write left in ``directory`` or below."""
    return [p for p in directory.rglob("*") if TEMPORARY.fullmatch(p.name)]


def assert_complete(path: Path) -> None:
    """A finished output: JSON that parses, a PNG with its end chunk, a non-empty text."""
    data = path.read_bytes()
    if path.suffix == ".json":
        json.loads(data)
    elif path.suffix == ".png":
        assert data.startswith(PNG_SIGNATURE) and data.endswith(PNG_END), path
    else:
        assert data.strip(), path


def assert_cache_intact(cache: Path) -> None:
    """Every reference in the cache loads, with its key and finite arrays."""
    files = sorted(cache.glob("reference-*.npz"))
    assert files, "no reference cached"
    for path in files:
        with np.load(path) as data:
            assert "key" in data.files
            for name in data.files:
                if data[name].dtype.kind == "f":
                    assert np.all(np.isfinite(data[name])), (path, name)


def resume(out: Path, cache: Path, before: dict) -> str:
    """Rerun ``all`` in ``out`` and check it skips every output of ``before``.

    Returns
    -------
    str
        The rerun's stderr.
    """
    env = dict(os.environ, HFDI_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-m", "validation", *ALL_ARGS, "--out", str(out)],
                          cwd=out.parent, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    done = [p for p in before
            if not TEMPORARY.fullmatch(p.name) and p.name != "hfdi-validate-all.json"]
    assert done
    for path in done:
        assert f"{path}: exists, skipped" in proc.stderr, path
        assert path.stat().st_mtime_ns == before[path], f"{path} was rewritten"
    # the reference the finished outputs drew on is read back, not recomputed
    assert "rtol 1e-12: " in proc.stderr and "from cache" in proc.stderr
    assert not re.search(r"rtol 1e-12: \d+ nodes, computed", proc.stderr)
    assert temporaries(out) == []
    for path in outputs(out):
        assert_complete(path)
    assert (out / "report.md").exists()
    return proc.stderr


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One reference cache for both interruptions: each must leave it intact."""
    return tmp_path_factory.mktemp("cache")


@pytest.mark.slow
def test_sigint_keeps_the_outputs_and_resumes(tmp_path, cache):
    out = tmp_path / "out"
    proc = start_all(out, cache)
    try:
        wait_for(proc, out / "dumbbell_table.json")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    # the last line (after the progress lines) says what happened and what to do
    assert "hfdi-validate: interrupted; outputs written so far are kept" in err.splitlines()[-1]
    # KeyboardInterrupt unwinds through write_atomic, which removes its file
    assert temporaries(out) == []
    assert temporaries(cache) == []
    before = outputs(out)
    for path in before:
        assert_complete(path)
    assert_cache_intact(cache)
    resume(out, cache, before)


@pytest.mark.slow
def test_sigkill_keeps_the_outputs_and_resumes(tmp_path, cache):
    out = tmp_path / "out"
    proc = start_all(out, cache)
    try:
        wait_for(proc, out / "figures" / "dumbbell_fig05_stretch.png")
        proc.kill()
        proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == -signal.SIGKILL
    before = outputs(out)
    # no half-written output: whatever was being written is in a temporary file
    for path in before:
        if not TEMPORARY.fullmatch(path.name):
            assert_complete(path)
    assert_cache_intact(cache)
    # What a kill in the middle of a write leaves (here made on purpose, as a
    # kill lands there rarely): the rerun removes it and writes the output.
    stale = out / "figures" / ".dumbbell_fig06_energy_increment.png.k1ll3d_x.tmp"
    stale.write_bytes(PNG_SIGNATURE + b"half a figure")
    err = resume(out, cache, before)
    assert not stale.exists()
    assert "figure " + str(out / "figures" / "dumbbell_fig06_energy_increment.png") in err


def cli_table(base: Path) -> str:
    """The markdown table of every case of :data:`CASES`: the command, its
    exit status and the line it prints (paths shown as their placeholders)."""
    lines = ["| command | exit | stderr (one line) |", "|---|---|---|"]
    for case, result in run_all_cases(base).items():
        if "skip" in result:
            continue
        line = result["shown"].replace("|", "\\|")
        lines.append(f"| `{case.command}` | {result['returncode']} | {line} |")
    return "\n".join(lines)


if __name__ == "__main__":
    # python tests/test_cli_robustness.py          prints the table
    # python tests/test_cli_robustness.py --write  updates it in docs/robustness.md
    with tempfile.TemporaryDirectory() as tmp:
        generated = cli_table(Path(tmp))
    if "--write" in sys.argv[1:]:
        print(write_doc_table('cli', generated))
    else:
        print(generated)


def _interrupt_inside_an_import(*args, **kwargs):
    """What Ctrl-C during a C extension's initialisation raises (matplotlib's Agg)."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as interrupt:
        raise ImportError("initialization failed") from interrupt


def _refused(*args, **kwargs):
    raise ValueError("t_end must be > 0")


@pytest.mark.parametrize("fault, status, line", [
    (_interrupt_inside_an_import, 130, "interrupted"),
    (_refused, 1, "error: t_end must be > 0"),
])
def test_an_interrupt_inside_an_import_is_an_interrupt(monkeypatch, capsys, tmp_path,
                                                       fault, status, line):
    """Ctrl-C that arrives while a C extension initialises comes out as an
    ImportError chained to it: each command line exits 130 and says it was
    interrupted, as for a plain KeyboardInterrupt; real errors keep their status."""
    import benchmarks.__main__ as bench_main
    import benchmarks.profile
    import benchmarks.scale
    import validation.cli

    monkeypatch.setattr(validation.cli, "_models", fault)
    monkeypatch.setattr(benchmarks.profile, "main", fault)
    monkeypatch.setattr(benchmarks.scale, "run_scale", fault)
    runs = {"hfdi-validate": lambda: validation.cli.main(["models"]),
            "python -m benchmarks profile": lambda: bench_main.main(["profile"]),
            "benchmarks scale": lambda: benchmarks.scale.main(
                ["--out", str(tmp_path), "--sizes", "6"])}
    for prog, run in runs.items():
        assert run() == status, prog
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith(prog) and line in err[-1], (prog, err)
        assert "Traceback" not in "\n".join(err)


def _swallowed_ctrl_c():
    """A real SIGINT to this process while a C extension initialises, dropped by
    an optional import's ``except ImportError`` as libraries write them."""
    try:
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt as interrupt:
            raise ImportError("initialization failed") from interrupt
    except ImportError:
        pass


@pytest.fixture
def python_sigint():
    """SIGINT with Python's own handler, as under a terminal: a suite started
    in the background by a non-interactive shell inherits it ignored, and the
    commands then rightly install nothing (validation.options)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.slow
def test_a_swallowed_ctrl_c_still_ends_the_command(monkeypatch, capsys, tmp_path,
                                                    python_sigint):
    """A Ctrl-C that a library swallows: ``all`` stops before its next output
    and exits 130 with its line, as does ``python -m benchmarks``; the next
    command in the process runs as usual and SIGINT is Python's own handler
    again."""
    import validation.cli
    import validation.report

    written = tmp_path / "after the interrupt"

    def run_all(out, problems, schemes, targets, t_end, long_t_end, ratios, force,
                progress, runner, compiled):
        _swallowed_ctrl_c()
        progress.say("table dumbbell")
        written.write_text("an output after Ctrl-C")

    monkeypatch.setattr(validation.report, "run_all", run_all)
    status = validation.cli.main(["all", "--out", str(tmp_path / "out"), "--problems", "dumbbell"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 130, err
    assert not written.exists()
    assert "hfdi-validate: interrupted" in err[-1] and "Traceback" not in "\n".join(err)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler

    # a command that goes on to its end after a swallowed Ctrl-C exits 130 too
    monkeypatch.setattr(validation.cli, "_models", lambda args: _swallowed_ctrl_c())
    assert validation.cli.main(["models"]) == 130
    import benchmarks.__main__ as bench_main
    import benchmarks.profile

    def profile(argv):
        _swallowed_ctrl_c()
        return 0

    monkeypatch.setattr(benchmarks.profile, "main", profile)
    assert bench_main.main(["profile"]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == \
        "python -m benchmarks profile: interrupted"
    monkeypatch.undo()
    assert validation.cli.main(["models"]) == 0
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("during", ["import", "run"])
@pytest.mark.parametrize("fault", ["plain", "inside a C extension"])
def test_hfdi_fmu_says_interrupted_whenever_ctrl_c_comes(monkeypatch, capsys, during, fault):
    """Ctrl-C while hfdi-fmu imports its build machinery (hfdi, numba) or while
    it runs: exit status 130 and one line, no traceback."""
    import fmu.build
    import fmu.cli

    def interrupt(*args, **kwargs):
        if fault == "plain":
            raise KeyboardInterrupt
        _interrupt_inside_an_import()

    if during == "import":
        class Interrupting(type(fmu.build)):
            def __getattr__(self, name):
                interrupt()
        monkeypatch.setitem(sys.modules, "fmu.build", Interrupting("fmu.build"))
    else:
        monkeypatch.setattr(fmu.build, "problems", interrupt)
    assert fmu.cli.main(["list"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["hfdi-fmu: interrupted"]


def test_other_exceptions_still_propagate(monkeypatch):
    import validation.cli

    def broken(args):
        raise RuntimeError("a bug, not an interrupt")

    monkeypatch.setattr(validation.cli, "_models", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        validation.cli.main(["models"])
