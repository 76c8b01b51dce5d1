"""The Python side of the FMU's native layer (``fmu/native/hfdi_fmi2.c`` and ``hfdi_fmi3.c``).

:mod:`fmu.build` copies this file into the FMU's resources as
``hfdi_fmu_entry_<digest of the file>.py`` and writes ``hfdi_fmu.json``
beside it (the slave's module and class, the modules it runs on, the GUID,
the build interpreter's ``sys.path``). The native layer runs this file as a
module of that name (after checking the digest), without touching
``sys.path``, and calls :func:`instantiate`; every later FMI call is a
method of the :class:`Adapter` it returns.

**The FMU's code is imported under private names, from its own files only.**
The host's ``sys.path`` is never changed: the FMU's modules (the slave, its
core, pythonfmu, the bundled ``hfdi``) are found by :class:`Importer`, a
finder placed first on ``sys.meta_path`` that answers for the FMU's private,
build-specific module names only (``hfdi_fmu_core_*``, ``_hfdi_fmu_*``, ...)
and for nothing else, so the host's own ``import hfdi`` or ``import
pythonfmu`` finds what it found before. Every file it loads is hashed and
compared with the SHA-256 taken from the FMU's extraction when the instance
was made, and the bytes compared are the bytes compiled: bytecode
(``__pycache__``) is never read nor written, so a file planted or changed in
a cache or an extraction folder is refused, never run. The bundled ``hfdi``
runs from a lasting copy in ``$HFDI_CACHE_DIR/fmu/`` where one can be kept
(:func:`lasting_copy`): the copy is used only when each of its files has the
bundle's digest, and checked again when a module is imported from it.

The first instantiation in a process loads these modules under a lock, so
that instances made from several threads at once all get the finished
modules (Python's import locks do the rest).

The contract with the native layer: a method returns plain values (floats,
ints, bools, str, bytes, lists) or raises. An exception is that call's
``fmi2Error`` with the exception's text as the log message, and the instance
is as before the call (the slave checks everything before it changes
anything). ``do_step`` returning ``False`` is ``fmi2Discard``. Messages the
slave queued are collected after every call by :meth:`Adapter.take_log`.

This module imports nothing of the project: it must run in any host that
can load the FMU.
"""
from __future__ import annotations

import ctypes
import hashlib
import importlib
import importlib.machinery
import importlib.util
import json
import os
import shutil
import sys
import tempfile
import threading
import time

__all__ = ["instantiate", "Adapter", "Importer", "CONFIG", "GATE_FIELDS", "package_digest",
           "package_files", "lasting_copy"]

#: The build's description of the FMU, in its resources folder.
CONFIG = "hfdi_fmu.json"

#: The entries of the native path's gate, in the order of the native layer's
#: ``GATE_*`` (``fmu/native/hfdi_fmu_core.h``, which describes the protocol): armed,
#: dirty (native steps not yet taken over by the slave), the C function and its
#: context (:class:`hfdi.compiled.NativeAdvance`), the addresses of the time,
#: of the state arrays and of the inputs, the value-reference table and its
#: length, the CPU nanoseconds of the native steps not yet counted, and the
#: doSteps, reads and writes the native path served (for tests and
#: diagnostics), whether the states may be read there (also on the
#: Python path, from a copy the slave makes after its doStep), and the
#: address of the last time a doStep may end at (the slave's ``_stop_limit``).
GATE_FIELDS = ("armed", "dirty", "function", "context", "time", "state", "inputs", "table",
               "table_length", "cpu_ns", "steps", "reads", "writes", "readable", "stop")
GATE_SIZE = 16


# -- the FMU's files -------------------------------------------------------------------
def _walk(package):
    """``(relative path, bytes)`` of the files of the directory ``package``, in
    order of path; ``__pycache__`` folders are left out."""
    root = os.path.abspath(package)
    found = []
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        for name in files:
            path = os.path.join(folder, name)
            found.append((os.path.relpath(path, root).replace(os.sep, "/"), path))
    for relative, path in sorted(found):
        with open(path, "rb") as f:
            yield relative, f.read()


def package_digest(package, *texts: str) -> str:
    """12 hex digits of SHA-256 over ``texts`` and the files of the directory
    ``package`` (relative path and content, in order of path); ``__pycache__``
    folders are left out. The FMU's private module names carry it
    (:mod:`fmu.build`), which keeps different builds apart in one process."""
    h = hashlib.sha256()
    for text in texts:
        h.update(text.encode("utf-8") + b"\0")
    if package is not None:
        for relative, data in _walk(package):
            h.update(relative.encode("utf-8") + b"\0")
            h.update(data + b"\0")
    return h.hexdigest()[:12]


def package_files(package) -> dict:
    """The SHA-256 (hex) of every file of the directory ``package`` by its
    relative path (``a/b.py``); ``__pycache__`` folders are left out."""
    return {relative: hashlib.sha256(data).hexdigest() for relative, data in _walk(package)}


def _holds(folder, files) -> bool:
    """Whether ``folder`` has every file of ``files`` (:func:`package_files`)
    with that digest."""
    try:
        for relative, digest in files.items():
            with open(os.path.join(folder, *relative.split("/")), "rb") as f:
                if hashlib.sha256(f.read()).hexdigest() != digest:
                    return False
    except OSError:
        return False
    return True


def lasting_copy(alias: str, bundled: str, files=None) -> str:
    """The folder of a lasting copy of the bundled package ``bundled``, made if
    needed; ``bundled`` itself where no copy can be kept.

    fmpy and other masters extract an FMU into a new folder each time, and
    numba keys its cache on the path of the source: without a copy that stays,
    the compiled path would compile the bundled kernels again (about half a
    minute) at every extraction. The copy lies in ``$HFDI_CACHE_DIR/fmu/``
    (default ``~/.cache/hfdi/fmu/``) under the bundle's module name, which
    carries the digest of the package's files. The cache is not trusted: the
    copy is used only when each of its files has the SHA-256 of the bundle's
    file (``files``, :func:`package_files` of ``bundled``; other files in it,
    ``__pycache__`` included, are never run), else it is made again; it is put
    in place by renaming a finished copy, so that concurrent instances never
    see a partial one. A bundle that does not give the digest of its name
    (a damaged FMU) is never copied: ``bundled`` is returned.
    """
    digest = alias.rsplit("_", 1)[-1]
    root = os.environ.get("HFDI_CACHE_DIR") or os.path.join(os.path.expanduser("~"),
                                                           ".cache", "hfdi")
    if not os.path.isabs(root):        # no home folder found: nowhere to keep a copy
        return bundled
    home = os.path.join(root, "fmu", alias)
    target = os.path.join(home, "hfdi")
    try:
        if package_digest(bundled) != digest:
            return bundled      # a damaged or foreign bundle: never copied, nor replaced
        if files is None:
            files = package_files(bundled)
        if os.path.isdir(target) and _holds(target, files):
            os.utime(home)                      # in use: kept by _forget_unused
            return target
        _forget_unused(os.path.join(root, "fmu"))
        os.makedirs(home, exist_ok=True)
        staging = tempfile.mkdtemp(prefix=".staging-", dir=home)
        try:
            shutil.copytree(bundled, os.path.join(staging, "hfdi"),
                            ignore=shutil.ignore_patterns("__pycache__"))
            if os.path.isdir(target):           # a changed copy: set aside, then removed
                stale = tempfile.mkdtemp(prefix=".stale-", dir=home)
                os.replace(target, os.path.join(stale, "hfdi"))
                shutil.rmtree(stale, ignore_errors=True)
            try:
                os.replace(os.path.join(staging, "hfdi"), target)
            except OSError:                     # another instance put its copy first
                pass
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return target if _holds(target, files) else bundled
    except OSError:
        return bundled


#: A lasting copy not used for this long is removed when another is made.
UNUSED_COPY_DAYS = 30


def _forget_unused(folder):
    """Remove the lasting copies in ``folder`` unused for :data:`UNUSED_COPY_DAYS`
    (one is made per build of an FMU that runs here; they would pile up)."""
    limit = time.time() - UNUSED_COPY_DAYS * 86400.0
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        try:
            if entry.is_dir() and entry.name.startswith("_hfdi_fmu_") and \
                    entry.stat().st_mtime < limit:
                shutil.rmtree(entry.path, ignore_errors=True)
        except OSError:
            pass


# -- the importer -----------------------------------------------------------------------
class _CheckedLoader(importlib.machinery.SourceFileLoader):
    """Runs a source file only when its bytes have the expected SHA-256; never
    reads nor writes bytecode."""

    def __init__(self, fullname, path, digest):
        super().__init__(fullname, path)
        self.digest = digest

    def get_code(self, fullname):
        source = self.get_data(self.path)
        if hashlib.sha256(source).hexdigest() != self.digest:
            raise ImportError(f"{self.path} is not the file of the FMU it belongs to "
                              "(changed since the instance was made): not run",
                              name=fullname, path=self.path)
        return self.source_to_code(source, self.path)


class Importer:
    """A finder on ``sys.meta_path`` for the FMU's modules under their private names.

    It knows a few top-level names (:meth:`add`), each a package folder or a
    module file with the SHA-256 of its files, and loads them with
    :class:`_CheckedLoader`: a top-level name only in :meth:`load`, and
    later the submodules of the packages it loaded (a package imported
    under the same name by anyone else, as pythonfmu's builder does with the
    staged copy when an FMU is built, is left to the usual finders). It
    answers ``None`` for any other name, which leaves the host's imports as
    they were; a submodule that is not among the files is refused
    (``ModuleNotFoundError``) rather than looked for elsewhere.
    """

    def __init__(self):
        self._roots = {}
        self._open = set()          # the top-level names load() is importing

    def add(self, name, folder, files, module_file=None):
        """Serve ``name`` from ``folder``: a package whose files are ``files``
        (:func:`package_files`), or, with ``module_file``, the module of that
        file. A name served and imported already must have the same files
        (another extraction of the same FMU: its folder is used from now on).

        Raises
        ------
        ImportError
            When ``name`` is served with other files: another FMU in this
            process has different code under the same private name.
        """
        known = self._roots.get(name)
        if known is not None and (known[1], known[2]) != (files, module_file) \
                and name in sys.modules:
            raise ImportError(f"the module {name} of this FMU is loaded in this process "
                              "already, from another FMU with other files", name=name)
        self._roots[name] = (folder, files, module_file)

    def load(self, name):
        """Import the top-level module ``name`` (:meth:`add`) through this importer."""
        self._open.add(name)
        try:
            return importlib.import_module(name)
        finally:
            self._open.discard(name)

    def find_spec(self, fullname, path=None, target=None):
        top, _, rest = fullname.partition(".")
        root = self._roots.get(top)
        if root is None:
            return None
        if not rest and top not in self._open:
            return None
        if rest and not isinstance(getattr(getattr(sys.modules.get(top), "__spec__", None),
                                           "loader", None), _CheckedLoader):
            return None                         # a package of that name not loaded here
        folder, files, module_file = root
        if module_file is not None:
            candidates = [] if rest else [(module_file, False)]
        else:
            parts = rest.split(".") if rest else []
            candidates = [("/".join(parts + ["__init__.py"]), True)]
            if parts:
                candidates.append(("/".join(parts) + ".py", False))
        for relative, package in candidates:
            digest = files.get(relative)
            if digest is None:
                continue
            origin = os.path.join(folder, *relative.split("/"))
            return importlib.util.spec_from_file_location(
                fullname, origin, loader=_CheckedLoader(fullname, origin, digest),
                submodule_search_locations=[os.path.dirname(origin)] if package else None)
        raise ModuleNotFoundError(f"No module named {fullname!r} in the FMU", name=fullname)

    def invalidate_caches(self):
        pass


#: The one importer of this module, on ``sys.meta_path`` from the first instance on.
IMPORTER = Importer()
#: Held while the FMU's modules are registered and imported.
_LOADING = threading.Lock()


def _module_file(name, path):
    """``{file name: SHA-256}`` of the module file ``path``."""
    with open(path, "rb") as f:
        return {os.path.basename(path): hashlib.sha256(f.read()).hexdigest()}


def load_slave(resources: str, config: dict):
    """Import the FMU's slave class from ``resources`` (see the module's
    docstring): pythonfmu as ``<core>_pythonfmu``, the bundled ``hfdi`` as
    its private name (from its lasting copy where one can be kept), the core
    and the slave's module, all through :data:`IMPORTER`.

    Raises
    ------
    ValueError
        Damaged resources (a file missing, a bundle whose files do not give
        the digest of its name), in one line.
    """
    core, module_name, alias = config["core"], config["module"], config["bundle"]
    bundled = os.path.join(resources, "hfdi")
    try:
        with _LOADING:
            if IMPORTER not in sys.meta_path:
                sys.meta_path.insert(0, IMPORTER)
            IMPORTER.add(f"{core}_pythonfmu", os.path.join(resources, "pythonfmu"),
                         package_files(os.path.join(resources, "pythonfmu")))
            files = package_files(bundled)
            if not files or package_digest(bundled) != alias.rsplit("_", 1)[-1]:
                raise ValueError(f"the bundled hfdi in {bundled} is missing or not the one "
                                 f"its name {alias} says")
            IMPORTER.add(alias, lasting_copy(alias, bundled, files), files)
            for name in (core, module_name):
                path = os.path.join(resources, name + ".py")
                IMPORTER.add(name, resources, _module_file(name, path), os.path.basename(path))
            with open(os.path.join(resources, core + ".py"), "rb") as f:
                if package_digest(None, f.read().decode("utf-8")) != core.rsplit("_", 1)[-1]:
                    raise ValueError(f"{core}.py is not the file its name says")
            for name in (f"{core}_pythonfmu", alias, core):
                IMPORTER.load(name)
            return getattr(IMPORTER.load(module_name), config["class"])
    except ValueError as exc:
        raise ValueError(f"the FMU's resources are damaged: {exc}") from None
    except Exception as exc:
        raise ValueError(f"the FMU's resources are damaged: its slave {module_name}."
                         f"{config['class']} cannot be loaded ({type(exc).__name__}: "
                         f"{exc})") from None


def instantiate(resources: str, instance_name: str, guid: str, visible: bool,
                logging_on: bool, own_interpreter: bool = False) -> "Adapter":
    """``fmi2Instantiate``: check the GUID and the resources, make the slave.

    ``own_interpreter``: the native layer started this interpreter (a host
    that is not Python); the build interpreter's package folders are then
    added to ``sys.path``. A Python host keeps its own environment.

    Raises
    ------
    ValueError
        For a GUID that is not this FMU's, or damaged resources; the message
        says which, in one line.
    """
    path = os.path.join(resources, CONFIG)
    try:
        with open(path, encoding="utf-8") as f:
            config = json.load(f)
        for key in ("module", "class", "core", "bundle", "guid"):
            if not isinstance(config[key], str):
                raise TypeError(key)
        extra_path = [str(p) for p in config.get("path", [])]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"the FMU's resources are damaged: {path} cannot be read "
                         f"({type(exc).__name__})") from None
    if guid != config["guid"]:
        raise ValueError(f"the GUID {guid!r} is not this FMU's ({config['guid']}): the model "
                         f"description and the binary do not belong together")
    # the build interpreter's packages (numpy, scipy) for a host that has no
    # Python of its own, whose path this FMU's interpreter is: ahead of the
    # site folders of that interpreter's installation (which may hold other
    # versions), after its standard library
    if own_interpreter:
        site_at = next((i for i, entry in enumerate(sys.path)
                        if os.path.basename(entry.rstrip(os.sep)) in ("site-packages",
                                                                       "dist-packages")),
                       len(sys.path))
        sys.path[site_at:site_at] = [entry for entry in extra_path if entry not in sys.path]
    version = config.get("fmi_version", 2)
    if version not in (2, 3):
        raise ValueError(f"the FMU's resources are damaged: {path} names FMI version "
                         f"{version!r}")
    return Adapter(load_slave(resources, config), resources, instance_name, visible, version)


#: The FMI 2.0 functions the slave's messages name, by their FMI 3.0 names.
_FMI3_NAMES = {
    "fmi2SetupExperiment": "fmi3EnterInitializationMode",
    "fmi2EnterInitializationMode": "fmi3EnterInitializationMode",
    "fmi2ExitInitializationMode": "fmi3ExitInitializationMode",
    "fmi2Instantiate": "fmi3InstantiateCoSimulation", "fmi2Terminate": "fmi3Terminate",
    "fmi2Reset": "fmi3Reset", "fmi2DoStep": "fmi3DoStep",
    "fmi2GetReal": "fmi3GetFloat64", "fmi2SetReal": "fmi3SetFloat64",
    "fmi2GetInteger": "fmi3GetInt32", "fmi2SetInteger": "fmi3SetInt32",
    "fmi2GetBoolean": "fmi3GetBoolean", "fmi2SetBoolean": "fmi3SetBoolean",
    "fmi2GetString": "fmi3GetString", "fmi2SetString": "fmi3SetString",
    "fmi2GetFMUstate": "fmi3GetFMUState", "fmi2SetFMUstate": "fmi3SetFMUState",
    "fmi2SerializeFMUstate": "fmi3SerializeFMUState",
    "fmi2DeSerializeFMUstate": "fmi3DeserializeFMUState",
    "fmi2LastSuccessfulTime": "lastSuccessfulTime",
}


class Fmi3Refusal(Exception):
    """A refusal of the slave, its message naming the FMI 3.0 functions."""


def _fmi3_names(method):
    """``method`` of :class:`Adapter` whose exceptions name the FMI 3.0 functions
    in an FMI 3.0 FMU (the slave's messages name FMI 2.0's)."""
    def call(self, *args):
        try:
            return method(self, *args)
        except Exception as exc:
            if self.fmi_version != 3:
                raise
            raise Fmi3Refusal(_fmi3_text(str(exc))) from None
    call.__name__, call.__doc__ = method.__name__, method.__doc__
    return call


def _fmi3_text(text: str) -> str:
    """A slave's message with the FMI 3.0 names of the functions it names."""
    if "fmi2" not in text:
        return text
    for old, new in _FMI3_NAMES.items():
        text = text.replace(old, new)
    return text


class Adapter:
    """One FMU instance: the slave and the calls of the native layer."""

    def __init__(self, slave_class, resources, instance_name, visible, fmi_version=2):
        self._make = lambda: slave_class(instance_name=instance_name, resources=resources,
                                         visible=visible)
        self.fmi_version = fmi_version
        self._pending = []
        # the native path's gate: lives as long as this adapter, across resets
        self.gate = (ctypes.c_int64 * GATE_SIZE)()
        self.slave = self._attached(self._make())

    def _attached(self, slave):
        attach = getattr(slave, "attach_native_gate", None)
        if attach is not None:
            attach(self.gate, GATE_FIELDS)
        return slave

    # -- the native path ----------------------------------------------------------
    def native_gate(self) -> int:
        """The gate's address, for the native layer (0: no native path)."""
        if getattr(self.slave, "attach_native_gate", None) is None:
            return 0
        return ctypes.addressof(self.gate)

    @_fmi3_names
    def sync_native(self):
        """The slave takes over the steps the native layer took."""
        self.slave.sync_native()

    # -- log ------------------------------------------------------------------
    def take_log(self) -> list:
        """The slave's queued messages as ``(status, category, text)``, emptied."""
        if not self._pending and not self.slave.log_queue:     # after almost every call
            return []
        queue = self._pending + list(self.slave.log_queue)
        self._pending = []
        del self.slave.log_queue[:]
        text = _fmi3_text if self.fmi_version == 3 else str
        return [(int(m.status), str(m.category or ""), text(str(m.msg))) for m in queue]

    # -- life cycle ---------------------------------------------------------------
    @_fmi3_names
    def setup_experiment(self, start_time, stop_time, tolerance):
        self.slave.setup_experiment(start_time, stop_time, tolerance)

    @_fmi3_names
    def enter_initialization_mode(self):
        self.slave.enter_initialization_mode()

    @_fmi3_names
    def exit_initialization_mode(self):
        self.slave.exit_initialization_mode()

    @_fmi3_names
    def terminate(self):
        self.slave.terminate()

    @_fmi3_names
    def reset(self):
        """``fmi2Reset``: a new slave, as after ``fmi2Instantiate``."""
        for i in range(GATE_SIZE):
            self.gate[i] = 0
        fresh = self._attached(self._make())
        self._pending += list(self.slave.log_queue)
        self.slave = fresh

    @_fmi3_names
    def enter_initialization(self, start_time, stop_time, tolerance):
        """``fmi3EnterInitializationMode``: the experiment and the mode in one call
        (refused as a whole: the slave is as before when either part is)."""
        if self.slave._phase != "instantiated":
            self.slave.enter_initialization_mode()      # refuses, naming the phase
        self.slave.setup_experiment(start_time, stop_time, tolerance)
        self.slave.enter_initialization_mode()

    @_fmi3_names
    def do_step(self, current_time, step_size) -> bool:
        return bool(self.slave.do_step(current_time, step_size))

    @_fmi3_names
    def do_step_early(self, current_time, step_size, early_return_allowed):
        """``fmi3DoStep``: ``(taken, returned early, the FMU's time)``; a step
        taken returned early when it ended before ``current_time + step_size``
        (the slave's own end time), at a zero of an event function."""
        taken = bool(self.slave.do_step(current_time, step_size, bool(early_return_allowed)))
        time = float(self.slave.time())
        return taken, taken and time < float(current_time) + float(step_size), time

    @_fmi3_names
    def time(self) -> float:
        return self.slave.time()

    # -- values -------------------------------------------------------------------
    @_fmi3_names
    def get_real(self, refs):
        return list(map(float, self.slave.get_real(refs)))

    @_fmi3_names
    def get_integer(self, refs):
        return [int(x) for x in self.slave.get_integer(refs)]

    @_fmi3_names
    def get_boolean(self, refs):
        return [bool(x) for x in self.slave.get_boolean(refs)]

    @_fmi3_names
    def get_string(self, refs):
        return [str(x) for x in self.slave.get_string(refs)]

    @_fmi3_names
    def set_real(self, refs, values):
        self.slave.set_real(refs, values)

    @_fmi3_names
    def set_integer(self, refs, values):
        self.slave.set_integer(refs, values)

    @_fmi3_names
    def set_boolean(self, refs, values):
        self.slave.set_boolean(refs, values)

    @_fmi3_names
    def set_string(self, refs, values):
        self.slave.set_string(refs, values)

    # -- FMU states ---------------------------------------------------------------
    @_fmi3_names
    def get_state(self):
        return self.slave._get_fmu_state()

    @_fmi3_names
    def set_state(self, state):
        self.slave._set_fmu_state(state)

    @_fmi3_names
    def serialize(self, state) -> bytes:
        return bytes(self.slave.serialize_state(state))

    @_fmi3_names
    def deserialize(self, data: bytes):
        return self.slave.deserialize_state(data)

