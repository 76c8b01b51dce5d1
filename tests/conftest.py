"""Fixtures shared by the test modules, and how the suite is split by speed.

``pytest`` runs everything (``make test``). ``pytest -m "not slow"`` is the
inner loop: the tests marked ``@pytest.mark.slow`` (each taking more than
about 0.2 s: long runs, subprocesses, FMU hosts, the CLI as a user runs it)
are left out, the rest run in seconds. Every test that builds or hosts an
FMU (it asks for the ``fmus`` fixture, directly or through another) is
marked slow here: the FMU bundles its own copy of ``hfdi``, whose loops
compile again after any edit of the library (about two minutes).

Shared helpers that are not fixtures live in modules beside this one:
:mod:`problems` (small test problems, the DOP853 reference, the writer of
the generated tables in ``docs/``), :mod:`exact_problems` (problems with
exact solutions) and :mod:`strategies` (hypothesis strategies). This
directory is on ``sys.path`` when pytest runs, so they import by name.
"""
from __future__ import annotations

from pathlib import Path

import pytest

#: The repository's root (its ``docs/`` hold the generated tables).
ROOT = Path(__file__).resolve().parents[1]


def _warm(scheme):
    """A short run of ``scheme``: its compiled loop loaded from the disk cache, or compiled."""
    import hfdi
    hfdi.integrate(hfdi.models.get("dumbbell"), scheme, 1e-3, rtol=1e-3)


def pytest_sessionstart(session):
    """The integrator's two compiled loops (affine and HFDI stages), ready
    before the first test.

    In xdist's controller (``-n 2``, the default), before the workers start
    (xdist's own ``pytest_sessionstart`` runs last): compiled into the disk
    cache by two processes at once, so that the workers load them instead
    of each compiling both (some 40 s a loop on a cold cache; a second or two
    when the cache holds them). In a worker, or a run without workers: loaded
    (or compiled) in the process, from the cache that ``HFDI_CACHE_DIR``
    names at the start, so that a test module that points it at a cache of
    its own (for its references or kernels) does not compile the loops anew.
    Nothing when only collecting; a failure is a warning (the tests that
    need the loops then fail themselves)."""
    import os
    import subprocess
    import sys
    import warnings
    config = session.config
    if config.option.collectonly:
        return
    if hasattr(config, "workerinput") or not config.pluginmanager.hasplugin("dsession"):
        try:
            for scheme in ("newmark", "hfdi"):
                _warm(scheme)
        except Exception as exc:        # noqa: BLE001 - reported, not fatal
            warnings.warn(f"the compiled loops could not be loaded before the tests: "
                          f"{type(exc).__name__}: {exc}")
        return
    if os.environ.get("HFDI_NO_DISK_CACHE"):
        return                          # nothing the workers could load
    code = "import sys, conftest\nconftest._warm(sys.argv[1])\n"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), os.environ.get("PYTHONPATH", "")]))
    runs = [subprocess.Popen([sys.executable, "-c", code, scheme], cwd=Path(__file__).parent,
                             env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            for scheme in ("newmark", "hfdi")]
    for run in runs:
        try:
            _, err = run.communicate(timeout=900)
        except subprocess.TimeoutExpired:
            run.kill()
            _, err = run.communicate()
        if run.returncode:
            warnings.warn(f"the compiled loops could not be compiled before the tests: "
                          f"{err.decode(errors='replace').strip().splitlines()[-1:]}")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The tests that need a built FMU go to the slow tier (before ``-m``
    selects): the rule of the module's docstring, kept by the fixture's
    name rather than by a list of tests."""
    for item in items:
        if "fmus" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def fmus(tmp_path_factory):
    """Every registered model built as an FMU once per session: ``{name: Path}``."""
    from fmu.build import build_all
    out = tmp_path_factory.mktemp("fmus")
    built = build_all(out)
    failed = {name: str(r) for name, r in built.items() if not isinstance(r, Path)}
    assert not failed, failed
    _compile_fmu_loops(built["dumbbell"])
    return built


def _compile_fmu_loops(path):
    """The compiled FMU's two loops (affine and HFDI stages) and its native C
    function compiled into the cache in a process of their own, once, before
    the tests that run them (compiled in a test process that holds this
    library, the copy's cached loop named the library's module until its
    numba types carried the package: docs/compiled.md, "An FMU's copy beside
    the library"; tests/test_fmu_host.py checks them)."""
    import subprocess
    import sys
    code = ("import sys\nfrom fmpy import extract\nfrom fmu.master import Unit\n"
            "for scheme in ('newmark', 'hfdi'):\n"
            "    with Unit(sys.argv[1], 'warm', unzip_dir=extract(sys.argv[1])) as unit:\n"
            "        unit.initialize({'compiled': True, 'scheme': scheme}, stop_time=1.0)\n"
            "        assert unit.step(0.0, 0.01)\n")
    subprocess.run([sys.executable, "-c", code, str(path)], cwd=ROOT, timeout=900,
                   capture_output=True, check=True)


@pytest.fixture(scope="session")
def dumbbell_fmu(fmus, tmp_path_factory):
    """The dumbbell FMU and one extraction of it, shared by the session's units:
    ``(path, unzip_dir)``. Tests that damage an FMU extract their own copy."""
    from fmpy import extract
    path = fmus["dumbbell"]
    return path, extract(str(path), unzipdir=str(tmp_path_factory.mktemp("dumbbell_fmu")))
