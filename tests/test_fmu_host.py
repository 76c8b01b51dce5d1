"""The FMU in its host: the host's import path and modules left alone,
nothing run from a cache that was not checked, instances made from several
threads at once, refused calls that change nothing, sizes the native layer
checks, and the hostile-call fuzz under ASan/UBSan.

Hosts that might crash run in a process of their own, so that a crash fails
the test, not the run; every such process gets its own ``HFDI_CACHE_DIR``,
except the fuzz, which runs the compiled loop from the session's cache (the
``fmus`` fixture fills it): it probes the native layer, and compiling the loop
anew under the sanitizers' runtime took 40 of its 70 s.
"""
import importlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path

import pytest

pytest.importorskip("pythonfmu")
fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402

from fmu.master import Unit  # noqa: E402

#: the FMU tests run in one worker (--dist loadgroup): the FMUs are built, and
#: their copy of the compiled loops loaded, once per session rather than per worker
pytestmark = pytest.mark.xdist_group("fmu")

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).with_name("data")
STEPS = 20                        # of 0.01, by every thread
NAMES = ["u[1]", "v[2]", "a[4]", "W"]


@pytest.fixture
def fmu(dumbbell_fmu):
    return dumbbell_fmu[0]


def isolated(script, cache, timeout=300):
    """``script`` in a fresh Python process with the project importable and
    ``HFDI_CACHE_DIR`` set to ``cache``; its completed process."""
    preamble = f"import sys\nsys.path.insert(0, {str(ROOT)!r})\n"
    env = dict(os.environ, HFDI_CACHE_DIR=str(cache))
    return subprocess.run([sys.executable, "-c", preamble + textwrap.dedent(script)],
                          capture_output=True, text=True, timeout=timeout, env=env)


def vrs_of(path, names):
    variables = read_model_description(str(path)).modelVariables
    by_name = {v.name: v.valueReference for v in variables}
    return [by_name[n] for n in names]


def reference_values(fmu, unzip):
    """``NAMES`` after ``STEPS`` steps of 0.01 from the defaults, in this process."""
    unit = Unit(fmu, "reference", unzip_dir=unzip)
    unit.initialize({}, start_time=0.0)
    t = 0.0
    for _ in range(STEPS):                   # the times of the C hosts: t += h
        assert unit.step(t, 0.01)
        t += 0.01
    values = [float(x) for x in unit.get(NAMES)]
    unit.close()
    return values


def compile_c(source, program, *flags):
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        pytest.skip(f"no C compiler ({compiler})")
    headers = Path(fmpy.__file__).parent / "c-code"
    done = subprocess.run([compiler, "-O1", *flags, "-o", str(program), str(source),
                           f"-I{headers}", "-ldl"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return program


# -- 1. the host's import path ------------------------------------------------------------
@pytest.mark.slow
def test_the_hosts_import_path_and_modules_are_left_alone(fmu, tmp_path):
    """In a Python host, an instance neither changes ``sys.path`` nor makes the
    host's own ``import hfdi`` and ``import pythonfmu`` find the FMU's copies;
    after ``fmi2FreeInstance`` nothing of the extraction folder is on
    ``sys.path`` (the folder may be made again by anyone)."""
    unzip = str(extract(str(fmu), unzipdir=str(tmp_path / "x")))
    done = isolated(f"""
        import json
        from fmu.master import Unit
        before = list(sys.path)
        first = sorted(m for m in ("hfdi", "pythonfmu") if m in sys.modules)
        unit = Unit({str(fmu)!r}, "host", unzip_dir={unzip!r})
        unit.initialize({{}})
        assert unit.step(0.0, 0.01)
        during = list(sys.path)
        import hfdi
        import pythonfmu
        files = [hfdi.__file__, pythonfmu.__file__]
        unit.close()
        print(json.dumps({{"first": first, "same": during == before, "files": files,
                          "after": [p for p in sys.path if p.startswith({unzip!r})]}}))
    """, tmp_path / "cache")
    assert done.returncode == 0, done.stderr[-3000:]
    seen = json.loads(done.stdout.splitlines()[-1])
    assert seen["first"] == []                       # neither imported by the host before
    assert seen["same"], "the instance changed sys.path"
    hfdi_file, pythonfmu_file = seen["files"]
    assert Path(hfdi_file).resolve() == ROOT / "hfdi" / "__init__.py"
    assert not pythonfmu_file.startswith(unzip), pythonfmu_file
    assert seen["after"] == []


# -- 2. code from the cache ----------------------------------------------------------------
def plant_bytecode(source: Path, marker: Path):
    """A valid bytecode file for ``source`` (its header matches the file's time
    and size, as an import checks) whose code creates ``marker``."""
    from importlib import _bootstrap_external
    code = compile(source.read_text() + f"\nopen({str(marker)!r}, 'w').close()\n",
                   str(source), "exec")
    status = source.stat()
    pyc = Path(importlib.util.cache_from_source(str(source)))
    pyc.parent.mkdir(exist_ok=True)
    pyc.write_bytes(_bootstrap_external._code_to_timestamp_pyc(code, status.st_mtime,
                                                               status.st_size))
    return pyc


@pytest.mark.slow
def test_bytecode_planted_in_the_cache_is_never_run(fmu, tmp_path):
    """Someone who can write the cache plants ``__pycache__/*.pyc`` files in
    the FMU's lasting copy of ``hfdi`` (and in the extraction): the next
    instance runs none of them and computes what it computed before."""
    unzip = str(extract(str(fmu), unzipdir=str(tmp_path / "x")))
    cache = tmp_path / "cache"
    script = f"""
        from fmu.master import Unit
        unit = Unit({str(fmu)!r}, "cached", unzip_dir={unzip!r})
        unit.initialize({{}})
        for k in range({STEPS}):
            assert unit.step(k * 0.01, 0.01)
        print(repr(list(map(float, unit.get({NAMES!r})))))
        unit.close()
    """
    first = isolated(script, cache)
    assert first.returncode == 0, first.stderr[-3000:]
    copies = list((cache / "fmu").glob("_hfdi_fmu_*/hfdi"))
    assert len(copies) == 1, copies
    marker = tmp_path / "planted-code-ran"
    planted = [plant_bytecode(copies[0] / "__init__.py", marker),
               plant_bytecode(copies[0] / "models" / "__init__.py", marker)]
    config = json.loads((Path(unzip) / "resources" / "hfdi_fmu.json").read_text())
    planted.append(plant_bytecode(Path(unzip) / "resources" / f"{config['module']}.py", marker))
    second = isolated(script, cache)
    assert second.returncode == 0, second.stderr[-3000:]
    assert not marker.exists(), "bytecode planted in the cache was run"
    assert second.stdout.splitlines()[-1] == first.stdout.splitlines()[-1]
    assert all(p.exists() for p in planted)         # not even looked at


def test_the_importer_runs_only_the_files_it_was_given(tmp_path, monkeypatch):
    """``fmu.entry.Importer``: a package under a private name, its files'
    digests taken once; a module runs only from a file that still has its
    digest, never from bytecode (none is read or written), a file that is
    not among them is not looked for elsewhere, and ``sys.path`` is not
    touched."""
    from fmu.entry import Importer, package_files
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("from . import a\n")
    (package / "a.py").write_text("A = 1\n")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "b.py").write_text("B = 2\n")
    (package / "sub" / "c.py").write_text("C = 3\n")
    name = f"_hfdi_fmu_test_{uuid.uuid4().hex}"
    importer = Importer()
    importer.add(name, str(package), package_files(package))
    monkeypatch.setattr(sys, "meta_path", [importer, *sys.meta_path])
    path = list(sys.path)
    try:
        assert importer.find_spec(name) is None          # a top-level name: only in load()
        assert importer.load(name).a.A == 1
        marker = tmp_path / "ran"
        plant_bytecode(package / "sub" / "b.py", marker)
        assert importlib.import_module(f"{name}.sub.b").B == 2
        assert not marker.exists()
        (package / "sub" / "c.py").write_text("C = 666\n")        # changed since
        with pytest.raises(ImportError, match="not run"):
            importlib.import_module(f"{name}.sub.c")
        (package / "sub" / "d.py").write_text("D = 4\n")          # not among the files
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module(f"{name}.sub.d")
        assert importer.find_spec("json") is None                # other names: not its own
        assert importer.find_spec(name) is None
        assert sys.path == path
        assert not (package / "__pycache__").exists()
        with pytest.raises(ImportError, match="other files"):
            importer.add(name, str(package), {})
        other = f"{name}_other"                  # not imported: may be served anew
        importer.add(other, str(package), {})
        importer.add(other, str(package), package_files(package))
    finally:
        for key in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
            del sys.modules[key]


def test_a_copy_imported_beside_the_library_has_compiled_types_of_its_own(monkeypatch):
    """The FMU's copy of hfdi, imported under its own name in a process that
    holds the library (an FMU simulated in the user's Python): every numba
    type its compiled loop takes is the copy's. The stage function's type
    was the library's (numba names a named tuple by its class's name and
    interns a function type by its signature's name), so the copy's cached
    loop named the library's ``Stage``, and a C host without the library
    could not load it: its native path was off, with a warning."""
    import hfdi
    from hfdi.core import numba_types
    from fmu.entry import Importer, package_files
    source = Path(hfdi.__file__).parent
    name = f"_hfdi_fmu_test_{uuid.uuid4().hex}"
    importer = Importer()
    importer.add(name, str(source), package_files(source))
    monkeypatch.setattr(sys, "meta_path", [importer, *sys.meta_path])
    try:
        importer.load(name)
        copy = importlib.import_module(f"{name}.core.numba_types")
        state = importlib.import_module(f"{name}.core.state")
        ours = numba_types.field_type("function STAGE_FUNCTION")
        theirs = copy.field_type("function STAGE_FUNCTION")
        assert theirs != ours
        assert theirs.signature.return_type.instance_class is state.Stage
        assert ours.signature.return_type.instance_class is hfdi.core.state.Stage
        for record in ("DATA", "VECTORS", "FUNCTIONS"):
            assert copy.struct_type(getattr(state, record)) != \
                numba_types.struct_type(getattr(hfdi.core.state, record))
    finally:
        for key in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
            del sys.modules[key]


# -- 3. threads at the first instantiation -------------------------------------------------
@pytest.mark.parametrize("threads", [2, 8])
@pytest.mark.slow
def test_a_c_host_instantiating_from_threads_at_once(fmu, tmp_path, threads):
    """A C master (no Python of its own) whose first ``fmi2Instantiate`` comes
    from several threads at once, three times in a row: every instance is
    made, and all give the values of the same run in this process, bit for
    bit. (The interpreter was started without a lock: SIGSEGV, SIGABRT.)"""
    program = compile_c(DATA / "fmi2_threads.c", tmp_path / "fmi2_threads", "-pthread")
    unzip = str(extract(str(fmu), unzipdir=str(tmp_path / "x")))
    md = read_model_description(str(unzip))
    library = Path(unzip) / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    expected = reference_values(fmu, unzip)
    env = {"PATH": "/usr/bin:/bin", "HFDI_CACHE_DIR": str(tmp_path / "cache"),
           **{k: v for k, v in os.environ.items() if k.startswith(("OPENBLAS_", "OMP_"))}}
    for run in range(3):
        done = subprocess.run([str(program), str(library), (Path(unzip) / "resources").as_uri(),
                               md.guid, str(threads), str(STEPS),
                               *map(str, vrs_of(unzip, NAMES))],
                              capture_output=True, text=True, timeout=300, env=env)
        assert done.returncode == 0, (run, done.returncode, done.stdout[-2000:],
                                      done.stderr[-2000:])
        values = {}
        for line in done.stdout.splitlines():
            if line.startswith("value "):
                _, thread, vr, x = line.split()
                values.setdefault(int(thread), []).append(float(x))
        assert sorted(values) == list(range(threads))
        assert all(v == expected for v in values.values()), (values, expected)


@pytest.mark.slow
def test_a_python_host_instantiating_from_8_threads_at_once(fmu, tmp_path):
    """fmpy in 8 threads whose first instantiation of the FMU comes at once:
    8 working instances with identical values (before: 7 of 8 NULL, "cannot
    access submodule 'models' ... circular import")."""
    unzip = str(extract(str(fmu), unzipdir=str(tmp_path / "x")))
    expected = reference_values(fmu, unzip)
    done = isolated(f"""
        import threading
        from fmu.master import Unit
        barrier = threading.Barrier(8)
        results = {{}}

        def run(k):
            barrier.wait()
            try:
                unit = Unit({str(fmu)!r}, f"thread{{k}}", unzip_dir={unzip!r})
                unit.initialize({{}})
                t = 0.0
                for _ in range({STEPS}):
                    assert unit.step(t, 0.01)
                    t += 0.01
                results[k] = list(map(float, unit.get({NAMES!r})))
                unit.close()
            except Exception as exc:
                results[k] = repr(exc)

        threads = [threading.Thread(target=run, args=(k,)) for k in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        print(repr([results[k] for k in range(8)]))
    """, tmp_path / "cache")
    assert done.returncode == 0, done.stderr[-3000:]
    results = eval(done.stdout.splitlines()[-1])
    assert results == [expected] * 8, results


# -- 5. a refused set changes nothing ---------------------------------------------------
def test_a_refused_set_changes_nothing(dumbbell_fmu):
    """``fmi2SetReal([A, scheme])`` (scheme is a String), and after
    initialization ``fmi2SetReal([F[1], scheme])``: ``fmi2Error`` with one
    message, and ``A`` and ``F[1]`` keep their values; the same for the
    other setters."""
    path, unzip = dumbbell_fmu
    unit = Unit(path, "refused", unzip_dir=unzip)
    fmu, vr = unit.fmu, unit.vr
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        a = fmu.getReal([vr("A")])
        calls = [("setReal", [vr("A"), vr("scheme")], [5.0, 1.0]),
                 ("setReal", [vr("A"), vr("max_internal_steps")], [5.0, 1.0]),
                 ("setInteger", [vr("max_internal_steps"), vr("A")], [7, 1]),
                 ("setBoolean", [vr("compiled"), vr("A")], [True, True]),
                 ("setString", [vr("scheme"), vr("A")], ["newmark", "x"])]
        before = {name: fmu.getReal([vr(name)]) for name in ("A", "F[1]")}
        before.update(max_internal_steps=fmu.getInteger([vr("max_internal_steps")]),
                      compiled=fmu.getBoolean([vr("compiled")]),
                      scheme=fmu.getString([vr("scheme")]))
        for setter, refs, values in calls:
            count = len(unit.messages)
            with pytest.raises(FMICallException) as info:
                getattr(fmu, setter)(refs, values)
            assert info.value.status == 3                       # fmi2Error
            new = unit.messages[count:]
            assert len(new) == 1 and "no value was set" in new[0][2], new
        assert fmu.getReal([vr("A")]) == a
        assert fmu.getInteger([vr("max_internal_steps")]) == before["max_internal_steps"]
        assert fmu.getBoolean([vr("compiled")]) == before["compiled"]
        assert fmu.getString([vr("scheme")]) == before["scheme"]
        fmu.exitInitializationMode()
        with pytest.raises(FMICallException):
            fmu.setReal([vr("F[1]"), vr("scheme")], [7.0, 1.0])
        assert fmu.getReal([vr("F[1]")]) == before["F[1]"]
        fmu.doStep(0.0, 0.01)
        assert fmu.getReal([vr("A")]) == a
    finally:
        unit.close()


# -- 6. sizes ---------------------------------------------------------------------------
@pytest.mark.slow
def test_sizes_beyond_every_limit_are_refused_with_a_log_line(fmu, tmp_path):
    """``nvr`` of 2^24 + 1, 2^40 and SIZE_MAX to every getter and setter, a
    deserialize size of 2^63 + 5 and SIZE_MAX, through ctypes: ``fmi2Error``
    and one log line each, no Python exception left pending (ctypes would
    raise SystemError), the host alive and the instance as it was."""
    unzip = str(extract(str(fmu), unzipdir=str(tmp_path / "x")))
    done = isolated(f"""
        import ctypes
        from ctypes import POINTER, byref, c_char_p, c_double, c_int, c_size_t, c_uint, c_void_p
        from fmu.master import Unit
        unit = Unit({str(fmu)!r}, "sizes", unzip_dir={unzip!r})
        unit.initialize({{}})
        assert unit.step(0.0, 0.01)
        before = list(unit.get(["u[1]", "v[1]"]))
        dll, c = unit.fmu.dll, unit.fmu.component
        vr = (c_uint * 1)(unit.vr("u[1]"))
        arrays = {{"Real": (c_double * 1)(), "Integer": (c_int * 1)(),
                  "Boolean": (c_int * 1)(), "String": (c_char_p * 1)(b"x")}}
        results = []
        for nvr in (2 ** 24 + 1, 2 ** 40, 2 ** 64 - 1):
            for kind, values in arrays.items():
                for what in ("Get", "Set"):
                    f = ctypes.CFUNCTYPE(c_int, c_void_p, c_void_p, c_size_t, c_void_p)(
                        (f"fmi2{{what}}{{kind}}", dll))
                    count = len(unit.messages)
                    status = f(c, vr, nvr, values)
                    results.append((f"{{what}}{{kind}} {{nvr}}", status,
                                    len(unit.messages) - count))
        data = ctypes.create_string_buffer(64)
        state = c_void_p()
        f = ctypes.CFUNCTYPE(c_int, c_void_p, c_char_p, c_size_t, POINTER(c_void_p))(
            ("fmi2DeSerializeFMUstate", dll))
        for size in (2 ** 63 + 5, 2 ** 64 - 1):
            count = len(unit.messages)
            status = f(c, data, size, byref(state))
            results.append((f"DeSerialize {{size}}", status, len(unit.messages) - count))
        after = list(unit.get(["u[1]", "v[1]"]))
        assert unit.step(0.01, 0.01)
        unit.close()
        print(repr((results, before == after)))
    """, tmp_path / "cache")
    assert done.returncode == 0, (done.returncode, done.stderr[-3000:])
    results, unchanged = eval(done.stdout.splitlines()[-1])
    assert unchanged
    bad = [r for r in results if r[1:] != (3, 1)]            # fmi2Error, one message
    assert not bad, bad
    assert len(results) == 3 * 8 + 2


# -- the fuzz under ASan/UBSan ------------------------------------------------------------
@pytest.mark.slow
def test_fuzz_under_sanitizers(fmu, tmp_path):
    """``tests/fmu_fuzz.py`` (hostile arguments to every fmi2 function and
    fuzzed serialized states) against the native layer compiled with
    AddressSanitizer and UndefinedBehaviorSanitizer: no sanitizer report, no
    crash, no fmi2Fatal, every refusal logged. docs/robustness.md records a
    longer run of the same command."""
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        pytest.skip(f"no C compiler ({compiler})")
    runtime = subprocess.run([compiler, "-print-file-name=libasan.so"], capture_output=True,
                             text=True).stdout.strip()
    if not os.path.isabs(runtime):
        pytest.skip(f"{compiler} has no AddressSanitizer runtime (libasan)")
    unzip = str(extract(str(fmu), unzipdir=str(tmp_path / "x")))
    md = read_model_description(str(unzip))
    library = Path(unzip) / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    headers = Path(fmpy.__file__).parent / "c-code"
    done = subprocess.run([compiler, "-shared", "-fPIC", "-O1", "-g", "-std=c99", "-pthread",
                           "-fno-omit-frame-pointer", "-fsanitize=address,undefined",
                           "-fno-sanitize-recover=all", "-o", str(library),
                           str(ROOT / "fmu" / "native" / "hfdi_fmi2.c"), f"-I{headers}",
                           "-ldl", "-lm"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    env = dict(os.environ, LD_PRELOAD=runtime,
               ASAN_OPTIONS="detect_leaks=0:abort_on_error=1",
               UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1")
    done = subprocess.run([sys.executable, str(ROOT / "tests" / "fmu_fuzz.py"), str(unzip),
                           "--cases", "3000"], capture_output=True, text=True, timeout=900,
                          env=env)
    report = [line for line in done.stderr.splitlines()
              if "Sanitizer" in line or "runtime error" in line]
    assert done.returncode == 0 and not report, (done.stdout[-2000:], report,
                                                 done.stderr[-3000:])
    assert "no fatal, every refusal logged" in done.stdout
