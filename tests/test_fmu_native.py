"""The FMU's native layer (``fmu/native/hfdi_fmi2.c``): hosts that are not
Python, paths with any character, a damaged FMU, a wrong GUID, atomic
builds. A damaged FMU is loaded in a fresh process each time: the host
must survive it, and the bundled ``hfdi`` of a good FMU must not be the one
cached in the process already.
"""
import os
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pythonfmu")
fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description  # noqa: E402

from fmu.build import BuildError, build  # noqa: E402
from fmu.master import CoSimulationError, Unit  # noqa: E402
from problems import run_in_ecos  # noqa: E402

#: the FMU tests run in one worker (--dist loadgroup): the FMUs are built, and
#: their copy of the compiled loops loaded, once per session rather than per worker
pytestmark = pytest.mark.xdist_group("fmu")

ROOT = Path(__file__).resolve().parents[1]
HOST_SOURCE = Path(__file__).with_name("data") / "fmi2_host.c"
STEPS = 20                                   # of 0.01 in the C host


@pytest.fixture
def fmu(dumbbell_fmu):
    """The dumbbell FMU of the session (conftest.py); a test extracts its own copy."""
    return dumbbell_fmu[0]


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    """A C program that loads an FMU's binary and steps it: a host without Python."""
    headers = Path(fmpy.__file__).parent / "c-code"
    program = tmp_path_factory.mktemp("host") / "fmi2_host"
    done = subprocess.run([os.environ.get("CC", "cc"), "-O1", "-o", str(program),
                           str(HOST_SOURCE), f"-I{headers}", "-ldl"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return program


def in_process_values(fmu, unzip, names, steps=STEPS, h=0.01):
    unit = Unit(fmu, "reference", unzip_dir=unzip)
    unit.initialize({}, start_time=0.0)
    t = 0.0
    for _ in range(steps):
        assert unit.step(t, h)
        t += h
    values = unit.get(names)
    unit.close()
    return values


#: BLAS settings of this process (OPENBLAS_CORETYPE picks OpenBLAS's kernels):
#: the host gets them too, so that "bit for bit" compares the same arithmetic.
BLAS_ENV = {k: v for k, v in os.environ.items()
            if k.startswith(("OPENBLAS_", "OMP_", "MKL_", "GOTO_"))}


def run_host(host, unzip, guid=None, vrs=(), env=None):
    """Run the C host with no Python in its environment (only PATH and BLAS settings)."""
    md = read_model_description(str(unzip))
    library = Path(unzip) / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    uri = (Path(unzip) / "resources").as_uri()
    return subprocess.run([str(host), str(library), uri, guid or md.guid, str(STEPS),
                           *map(str, vrs)], capture_output=True, text=True, timeout=300,
                          env=env if env is not None else {"PATH": "/usr/bin:/bin", **BLAS_ENV})


def isolated(script, timeout=300, **kwargs):
    """Run ``script`` in a fresh Python process with the project importable:
    a crash of the host fails the test, not the run."""
    preamble = f"import sys\nsys.path.insert(0, {str(ROOT)!r})\n"
    return subprocess.run([sys.executable, "-c", preamble + textwrap.dedent(script)],
                          capture_output=True, text=True, timeout=timeout, **kwargs)


def vr_of(fmu, name):
    return next(v.valueReference for v in read_model_description(str(fmu)).modelVariables
                if v.name == name)


@pytest.mark.slow
def test_the_fmu_leaves_a_c_hosts_locale_alone(fmu, host, tmp_path):
    """Python's initialization sets LC_CTYPE from the environment (here
    C.UTF-8); a host that never chose a locale keeps "C" (its parsers, its
    multibyte conversions)."""
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    done = run_host(host, unzip, env={"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8",
                                      "LC_ALL": "C.UTF-8", **BLAS_ENV})
    assert done.returncode == 0, (done.stdout, done.stderr)
    assert "locale C\n" in done.stdout, done.stdout[-500:]


@pytest.mark.slow
def test_a_host_without_python_runs_the_fmu(fmu, host, tmp_path):
    """A C program with an empty environment: the native layer loads the
    Python library the FMU was built with, and the run gives the same values
    as in this Python process, bit for bit."""
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    md = read_model_description(str(fmu))
    names = ["u[1]", "u[2]", "v[3]"]
    vrs = [next(v.valueReference for v in md.modelVariables if v.name == n) for n in names]
    done = run_host(host, unzip, vrs=vrs)
    assert done.returncode == 0, (done.stdout, done.stderr)
    values = [float(line.split()[2]) for line in done.stdout.splitlines()
              if line.startswith("value ")]
    expected = in_process_values(fmu, unzip, names)
    assert values == list(expected)


@pytest.mark.slow
def test_a_host_without_python_runs_the_compiled_fmu_natively(fmu, host, tmp_path):
    """``compiled = true`` in a C host: the doSteps run in the native layer
    (it says so in the log), an input set in the middle of the run included,
    and the values are those of the same run in this Python process, bit for
    bit. The compiled code comes from the FMU cache of this user."""
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    names = ["u[1]", "u[2]", "v[3]", "a[4]"]
    vrs = [vr_of(fmu, n) for n in names]
    force = 25.0
    env = {"PATH": "/usr/bin:/bin", "HOME": os.path.expanduser("~"), **BLAS_ENV}
    if os.environ.get("HFDI_CACHE_DIR"):
        env["HFDI_CACHE_DIR"] = os.environ["HFDI_CACHE_DIR"]
    done = run_host(host, unzip, vrs=[f"b{vr_of(fmu, 'compiled')}=1",
                                      f"r{vr_of(fmu, 'F[2]')}={force!r}", *vrs], env=env)
    assert done.returncode == 0, (done.stdout, done.stderr)
    assert "run in the native layer" in done.stdout
    values = [float(line.split()[2]) for line in done.stdout.splitlines()
              if line.startswith("value ")]
    unit = Unit(fmu, "reference", unzip_dir=unzip)
    unit.initialize({"compiled": True}, start_time=0.0)
    t, h = 0.0, 0.01
    for k in range(STEPS):
        if k == STEPS // 2:
            unit.set({"F[2]": force})
        assert unit.step(t, h)
        t += h
    expected = unit.get(names)
    unit.close()
    assert values == list(expected)


@pytest.mark.parametrize("name", ["a b", "ü", "a (b)", "100%", "x#y", "%s%n"])
@pytest.mark.slow
def test_paths_with_any_character(fmu, host, tmp_path, name):
    """Extracted under such a folder, the FMU instantiates and steps, in this
    process (fmpy) and in the C host."""
    unzip = extract(str(fmu), unzipdir=str(tmp_path / name / "fmu"))
    expected = in_process_values(fmu, unzip, ["u[1]"])
    assert np.isfinite(expected).all()
    done = run_host(host, unzip)
    assert done.returncode == 0, (done.stdout, done.stderr)


def test_wrong_guid_is_refused_with_one_message(fmu, tmp_path):
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    done = isolated(f"""
        import fmpy
        from fmpy import read_model_description
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE,
                               fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE)
        md = read_model_description({str(unzip)!r})
        messages = []
        slave = FMU2Slave(guid="{{not-this-fmu}}", unzipDirectory={str(unzip)!r},
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName="g")
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda env, name, status, category, message: messages.append(message.decode()))
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        try:
            slave.instantiate(callbacks=callbacks)
        except Exception as exc:
            print("refused", len(messages), messages[0] if messages else "")
    """)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("refused 1 ") and "GUID" in done.stdout, done.stdout


#: How to damage an extracted FMU (a path relative to it to remove, or a file to cut short).
DAMAGES = {
    "no-resources": ("remove", "resources"),
    "no-description-of-the-slave": ("remove", "resources/hfdi_fmu.json"),
    "slave-module-missing": ("remove", "resources/{module}.py"),
    "bundled-hfdi-truncated": ("truncate", "resources/hfdi/__init__.py"),
    "bundled-hfdi-missing": ("remove", "resources/hfdi"),
    "no-python-description": ("remove", "resources/hfdi_fmu_python.txt"),
}


def damage(unzip, how):
    action, relative = DAMAGES[how]
    config = Path(unzip) / "resources" / "hfdi_fmu.json"
    module = config.read_text().split('"module": "')[1].split('"')[0]
    target = Path(unzip) / relative.format(module=module)
    if action == "remove":
        shutil.rmtree(target) if target.is_dir() else target.unlink()
    else:
        text = target.read_text()
        target.write_text(text[:len(text) // 3])


@pytest.mark.parametrize("how", sorted(DAMAGES))
def test_damaged_fmu_fails_to_instantiate_and_the_host_survives(fmu, tmp_path, how):
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    damage(unzip, how)
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from fmu.master import CoSimulationError, Unit
        try:
            Unit({str(fmu)!r}, "damaged", unzip_dir={str(unzip)!r})
        except CoSimulationError as exc:
            print("refused:", exc)
        else:
            print("instantiated")
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("refused:"), done.stdout
    assert "fmi2Instantiate failed" in done.stdout and "\n" not in done.stdout.strip()


@pytest.mark.parametrize("how", ["no-resources", "no-python-description",
                                 "bundled-hfdi-truncated"])
@pytest.mark.slow
def test_damaged_fmu_in_a_host_without_python(fmu, host, tmp_path, how):
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    damage(unzip, how)
    done = run_host(host, unzip)
    assert done.returncode == 1, (done.stdout, done.stderr)         # NULL, no crash
    logged = [line for line in done.stdout.splitlines() if line.startswith("log ")]
    assert len(logged) == 1, done.stdout


@pytest.mark.slow
def test_cli_master_with_a_damaged_fmu_prints_one_line(fmu, tmp_path):
    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(fmu) as old, zipfile.ZipFile(broken, "w") as new:
        for item in old.infolist():
            if item.filename != "resources/hfdi_fmu.json":
                new.writestr(item, old.read(item.filename))
    done = subprocess.run([sys.executable, "-m", "fmu", "master", str(broken), "--t-end", "0.1"],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 1
    assert done.stdout == ""
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hfdi-fmu: error:"), done.stderr


@pytest.mark.slow
def test_cli_master_with_any_character_in_tmpdir(tmp_path):
    tmpdir = tmp_path / "tmp ü(%#)"
    tmpdir.mkdir()
    done = subprocess.run([sys.executable, "-m", "fmu", "master", "--t-end", "0.05"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600,
                          env={**os.environ, "TMPDIR": str(tmpdir)})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "communication steps" in done.stdout


@pytest.mark.parametrize("where", ["while writing", "at the rename"])
@pytest.mark.slow
def test_build_is_atomic_when_it_fails(fmu, tmp_path, monkeypatch, where):
    """A build that fails half-way (the disk full) leaves the good FMU in
    place and no partial file beside it."""
    import fmu.build as builder
    out = tmp_path / "out"
    out.mkdir()
    good = build("dumbbell", out)
    before = good.read_bytes()

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    if where == "while writing":
        monkeypatch.setattr(builder.json, "dumps", disk_full)
    else:
        monkeypatch.setattr(builder.os, "replace", disk_full)
    with pytest.raises(OSError):
        build("dumbbell", out)
    monkeypatch.undo()
    assert good.read_bytes() == before
    assert sorted(p.name for p in out.iterdir()) == [good.name]


def test_a_missing_compiler_is_one_line(fmu, tmp_path, monkeypatch):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    with pytest.raises(BuildError) as info:
        build("dumbbell", tmp_path)
    assert "C compiler" in str(info.value) and "\n" not in str(info.value)


def test_instantiation_failure_is_a_cosimulation_error(fmu, tmp_path):
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    damage(unzip, "no-description-of-the-slave")
    with pytest.raises(CoSimulationError, match="damaged"):
        Unit(fmu, "d", unzip_dir=unzip)


@pytest.mark.slow
def test_the_fmu_needs_no_sympy_in_its_host(fmu, tmp_path):
    """The bundled hfdi loads sympy only for symbolic models: a host where
    sympy cannot be imported runs the FMU."""
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    script = textwrap.dedent(f"""
        import sys
        sys.modules["sympy"] = None          # import sympy raises ImportError
        sys.path.insert(0, {str(ROOT)!r})
        from fmu.master import Unit
        unit = Unit({str(fmu)!r}, "no-sympy", unzip_dir={str(unzip)!r})
        unit.initialize({{}})
        assert unit.step(0.0, 0.05)
        print(unit.get(["u[1]"])[0], "sympy" in sys.modules and sys.modules["sympy"] is not None)
        unit.close()
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    value, loaded = done.stdout.split()
    assert float(value) != 0.0 and loaded == "False"


def test_import_hfdi_loads_neither_sympy_nor_matplotlib():
    """An FMU host needs neither: importing hfdi and building every registered
    model loads no sympy (the symbolic models load it when asked for) and no
    matplotlib (only validation draws)."""
    script = textwrap.dedent("""
        import sys
        import hfdi
        for name in hfdi.models.available():
            hfdi.models.get(name)
        print(sorted(m for m in ("sympy", "matplotlib") if m in sys.modules))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "[]", (done.stdout, done.stderr)


@pytest.mark.slow
def test_a_second_master_ecos_gets_the_same_values(fmu, tmp_path):
    """Ecos (``ecospy``, a C++ co-simulation engine) runs the FMU through its
    own FMI 2.0 import: same values as fmpy's, bit for bit. In a subprocess,
    so that a crash of the host would show as such."""
    t, (u1, v2) = run_in_ecos(fmu, 0.2, [("real", "u[1]"), ("real", "v[2]")], tmp_path)
    steps = round(t / 0.01)
    assert 15 <= steps <= 20
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    assert list(in_process_values(fmu, unzip, ["u[1]", "v[2]"], steps=steps)) == [u1, v2]


@pytest.mark.parametrize("how", ["pickle-after-magic", "object-array", "integrator-pickle"])
@pytest.mark.slow
def test_serialized_state_never_runs_code(fmu, tmp_path, how):
    """Bytes crafted to run code when read (the state's magic line followed by
    a pickle whose ``__reduce__`` creates a file; an object array inside the
    .npz; the same as the integrator's part): refused with fmi2Error, nothing
    runs, the FMU unchanged and usable."""
    marker = tmp_path / "ran"
    done = isolated(f"""
        import io, pickle
        import numpy as np
        from fmpy.fmi1 import FMICallException
        from fmu.master import Unit

        class RunsCode:
            def __reduce__(self):
                return (open, ({str(marker)!r}, "w"))

        u = Unit({str(fmu)!r}, "crafted")
        u.initialize({{}})
        assert u.step(0.0, 0.05)
        before = u.get(["u[1]", "v[1]"])
        magic, body = u.serialize(u.get_state()).split(bytes([10]), 1)
        with np.load(io.BytesIO(body)) as z:
            arrays = {{key: z[key] for key in z.files}}
        if {how!r} == "pickle-after-magic":
            data = magic + bytes([10]) + pickle.dumps(RunsCode())
        else:
            key = "inputs" if {how!r} == "object-array" else "integrator"
            arrays[key] = np.array([RunsCode()], dtype=object)
            buffer = io.BytesIO()
            np.savez(buffer, **arrays)
            data = magic + bytes([10]) + buffer.getvalue()
        try:
            u.set_state(u.deserialize(data))
        except FMICallException as exc:
            print("status", exc.status)
        assert np.array_equal(u.get(["u[1]", "v[1]"]), before)
        assert u.step(0.05, 0.05)
        u.close()
    """)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["status", "3"]          # fmi2Error
    assert not marker.exists()


@pytest.mark.slow
def test_messages_are_printf_literals_for_a_c_logger(fmu, host, tmp_path):
    """FMI 2.0's logger formats the message as printf does (as the C host's
    does). A parameter value full of conversions reaches it as text: the
    host prints it and survives (unescaped, ``%n`` writes through a stray
    pointer and ``%s`` reads one)."""
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    value = "%s%p%n" * 16
    done = run_host(host, unzip, vrs=[f"s{vr_of(fmu, 'scheme')}={value}"])
    assert done.returncode == 4, (done.returncode, done.stdout[-2000:])  # refused, no crash
    assert any(value in line and "scheme" in line for line in done.stdout.splitlines()
               if line.startswith("log ")), done.stdout


@pytest.mark.slow
def test_messages_are_printf_literals_for_fmpy(fmu, tmp_path):
    """The same through fmpy, reading the raw messages: every '%' doubled."""
    done = isolated(f"""
        from fmpy.fmi1 import FMICallException
        from fmu.master import Unit
        raw = []

        class RawUnit(Unit):
            def _log(self, env, instance, status, category, message):
                raw.append(message.decode("utf-8", "replace") if message else "")
                super()._log(env, instance, status, category, message)

        u = RawUnit({str(fmu)!r}, "printf")
        value = "%s%p%n" * 8
        try:
            u.initialize({{"scheme": value}})
        except FMICallException:
            pass
        mentions = [m for m in raw if "%" in m]
        assert mentions
        assert all("%" not in m.replace("%%", "") for m in mentions), mentions
        assert any(value in m[2] for m in u.messages)       # the master formats them back
        print("ok")
        u.close(terminate=False)
    """)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


@pytest.mark.slow
def test_a_host_with_only_numpy_and_scipy(fmu, host, tmp_path):
    """The C host, its Python given nothing but the standard library, numpy
    and scipy (the FMU's package path pointed at a folder holding only
    those): the FMU runs and gives the in-process values."""
    import json

    import numpy
    import scipy
    site = tmp_path / "site"
    site.mkdir()
    for package in (numpy, scipy):
        folder = Path(package.__file__).parent
        for item in folder.parent.iterdir():
            # the package, its bundled libraries (numpy.libs) and metadata
            if item.name == folder.name or item.name.startswith(folder.name + "."):
                (site / item.name).symlink_to(item)
    unzip = extract(str(fmu), unzipdir=str(tmp_path / "x"))
    config = Path(unzip) / "resources" / "hfdi_fmu.json"
    data = json.loads(config.read_text())
    data["path"] = [str(site)]
    config.write_text(json.dumps(data))
    names = ["u[1]", "a[4]"]
    done = run_host(host, unzip, vrs=[vr_of(fmu, n) for n in names])
    assert done.returncode == 0, (done.stdout, done.stderr)
    values = [float(line.split()[2]) for line in done.stdout.splitlines()
              if line.startswith("value ")]
    assert values == list(in_process_values(fmu, unzip, names))
