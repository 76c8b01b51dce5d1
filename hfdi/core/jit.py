"""One source, two speeds: how the core's functions run compiled and as plain Python.

The core (:mod:`hfdi.core`) is written as plain functions on arrays, numbers
and small records, in numpy's ``out=`` style, with status codes instead of
exceptions. Each such function is declared :func:`jitable`: called from
Python it *is* the plain function; called from compiled code numba compiles
it into the caller. A run on a model with compiled kernels enters the core
through a few :func:`entry` points compiled as a whole (the loop, one attempt,
one accepted step); a run on a Python model calls the very same functions as
Python. The two speeds therefore share every line of the algorithm, and
``tests/test_one_implementation.py`` runs both on the same problems.

Where the two differ on purpose, the difference is one small function with two
bodies, never the algorithm:

- :func:`primitive` — a numpy body for Python and a loop body for numba
  (elementwise array arithmetic in one pass without temporaries, LAPACK
  bound by name); both compute the same operations in the same order, so
  the two speeds round alike.
- :func:`python_only` — a branch that only Python-mode runs take (sparse and
  banded linear algebra, a model's Python-side faults); compiled code gets a
  stub that is never reached there.

Compiled code is cached on disk (:func:`entry`), keyed on the source of the
modules it compiles in (their syntax trees without docstrings), not on file
times: a comment or docstring edit recompiles nothing, any change of code
recompiles what depends on it. The cache lives in ``$HFDI_CACHE_DIR/numba``
(``~/.cache/hfdi/numba``), a directory that must belong to the user and be
writable by nobody else, checked as ssh checks its files: numba's index
files are pickles, so a cache others can write would run their code.
Where the check fails the code is compiled in memory, and that is said once.
"""
from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import logging
import os
import stat
import sys
import threading
import time
import types
import warnings
from pathlib import Path

from ..files import cache_dir

__all__ = ["jitable", "twin", "native", "primitive", "python_only", "entry", "JIT_OPTIONS",
           "compiling", "numba_cache_dir", "cache_trusted"]

_log = logging.getLogger("hfdi")



@functools.lru_cache(maxsize=None)
def _numba():
    """numba, imported when compiled code is first made (the Python steps need
    none of it): with the disk cache's locator installed."""
    import numba
    from numba.core import caching
    from numba.core.errors import NumbaExperimentalFeatureWarning

    # the first-class functions the compiled loop calls the model's kernels
    # through are "experimental" to numba since 0.49; the tests hold what they
    # do here
    warnings.filterwarnings("ignore", category=NumbaExperimentalFeatureWarning,
                            module=r"numba\..*|hfdi\..*")
    locator = _source_keyed_locator(caching)
    if locator not in caching.CacheImpl._locator_classes:
        caching.CacheImpl._locator_classes.insert(0, locator)
    _share_inlined_scopes()
    return numba


#: Per inlining of one of this package's functions: the copy of each variable
#: scope made so far (by the original's id).
_SCOPE_COPIES = []


def _share_inlined_scopes():
    """Make numba copy a callee's variable scope once per inlining, not once
    per block.

    numba inlines a function (``inline="always"``) by deep-copying its IR
    block by block, each block with a memo of its own, so the function's
    whole scope (every variable) is copied again for each block: quadratic
    in the size of the loop's inlined call tree, a third of its compile time
    (43 → 30 s of CPU for the affine loop, the code the same). While one of
    this package's functions is inlined, every block's copy takes the same
    copy of the scope, as one deep copy of the function would.

    Decision: a patch of numba's ``InlineWorker.inline_ir`` and
    ``ir.Scope.__deepcopy__``, active only while this package's functions are
    inlined and applied only where numba has them (0.60–0.68); elsewhere
    compiling is slower, not different."""
    import copy

    try:
        from numba.core import ir
        from numba.core.inline_closurecall import InlineWorker
        original = InlineWorker.inline_ir
    except (ImportError, AttributeError):
        return
    if getattr(original, "_hfdi_shared_scopes", False):
        return

    def inline_ir(self, caller_ir, block, i, callee_ir, callee_freevars, arg_typs=None):
        module = getattr(getattr(callee_ir.func_id, "func", None), "__module__", "") or ""
        ours = module.startswith(("hfdi", "_hfdi"))
        if ours:
            _SCOPE_COPIES.append({})
        try:
            return original(self, caller_ir, block, i, callee_ir, callee_freevars,
                            arg_typs=arg_typs)
        finally:
            if ours:
                _SCOPE_COPIES.pop()

    def scope_deepcopy(self, memo):
        copies = _SCOPE_COPIES[-1] if _SCOPE_COPIES else None
        made = None if copies is None else copies.get(id(self))
        if made is None:
            made = copy._reconstruct(self, memo, *self.__reduce_ex__(4))
            if copies is not None:
                copies[id(self)] = made
        memo[id(self)] = made
        return made

    inline_ir._hfdi_shared_scopes = True
    InlineWorker.inline_ir = inline_ir
    if "__deepcopy__" not in vars(ir.Scope):
        ir.Scope.__deepcopy__ = scope_deepcopy

#: Options of every compiled entry point: division by zero gives inf/NaN as
#: in numpy (a non-finite value fails an attempt, as on the Python path);
#: no GIL, so that an FMU's native layer and threads can run it.
JIT_OPTIONS = dict(error_model="numpy", nogil=True)

#: The core's functions and how compiled code takes each: the plain function
#: (Python's) to ``(kind, the function numba compiles)``.
_CORE = {}
#: Their compiled twins, made on demand (:func:`twin`).
_TWINS = {}


def jitable(function=None, *, inline=False):
    """Declare a core function: plain Python when called from Python; in
    compiled code its twin (:func:`twin`), the same code with the core
    functions it calls replaced by theirs. ``inline``: compiled into each
    caller at numba's level rather than as a function of its own — numba
    compiles each function of its own into a module that it then optimises
    again in every caller's module, once per level of the call tree, so the
    layers that only orchestrate (the loop's) are inlined."""
    def declare(fn):
        _CORE[fn] = ("inline" if inline else "function", fn)
        return fn
    return declare if function is None else declare(function)


def primitive(compiled_body):
    """Declare a primitive with two bodies: the decorated function (numpy, for
    Python) and ``compiled_body`` (for numba, usually a loop). Both must give
    the same numbers."""
    def declare(python_body):
        _CORE[python_body] = ("inline", compiled_body)
        return python_body
    return declare


def python_only(stub):
    """Declare a function that only Python-mode runs call (sparse systems,
    Python models): compiled code gets ``stub``, which has its signature and
    returns a value of the same type, and is never reached there."""
    return primitive(stub)


def twin(function):
    """The compiled twin of a core function: a numba dispatcher of the code
    it declared for compiled code, whose globals name the twins of the core
    functions it calls. Made once; compiled when first called (an entry) or
    inlined into its callers."""
    made = _TWINS.get(function)
    if made is not None:
        return made
    kind, source = _CORE[function]
    options = dict(JIT_OPTIONS)
    if kind == "inline":
        options["inline"] = "always"
    clone = _clone(source)
    made = _TWINS[function] = _numba().njit(**options)(clone)
    _link(clone, source)
    return made


def _clone(source):
    """``source`` with globals of its own (for :func:`_link`)."""
    clone = types.FunctionType(source.__code__, dict(source.__globals__), source.__name__,
                               source.__defaults__, source.__closure__)
    clone.__qualname__, clone.__module__ = source.__qualname__, source.__module__
    clone.__doc__ = source.__doc__
    return clone


def _link(clone, source):
    """The core functions ``clone``'s code names, their twins in its globals
    (after the twin of ``clone`` exists, so that functions may name each other),
    and the names the module gives compiled code only (its
    ``_compiled_globals()``, e.g. LAPACK's routines bound for numba)."""
    module = sys.modules.get(source.__module__)
    extra = getattr(module, "_compiled_globals", None)
    if extra is not None:
        clone.__globals__.update(extra())
    for name, value in source.__globals__.items():
        if _is_core(value):
            clone.__globals__[name] = twin(value)
        elif isinstance(value, _Entry):
            clone.__globals__[name] = value.dispatcher


def native(function, signature):
    """``function`` as a C function (a numba ``cfunc`` of ``signature``, cached on
    disk where :func:`cache_trusted`), the core functions it names being their
    twins; compiled when this is called."""
    clone = _clone(function)
    _link(clone, function)
    return _numba().cfunc(signature, cache=cache_trusted()[0], **JIT_OPTIONS)(clone)


def _is_core(value) -> bool:
    return isinstance(value, types.FunctionType) and value in _CORE


# -- the disk cache ---------------------------------------------------------------

def numba_cache_dir() -> Path:
    """Where compiled code is cached: ``cache_dir()/numba``."""
    return cache_dir() / "numba"


def _safe_directory(path: Path) -> bool:
    """Whether ``path`` is a directory of this user that nobody else can write
    (``st_uid`` ours, no group or world write bit), as ssh checks ``~/.ssh``."""
    try:
        info = os.lstat(path)
    except OSError:
        return False
    if not stat.S_ISDIR(info.st_mode):
        return False
    if hasattr(os, "getuid") and info.st_uid != os.getuid():
        return False
    return not info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def cache_trusted() -> tuple[bool, str]:
    """``(True, "")`` when the numba cache directory exists (made ``0o700``
    here if missing) and it and its parent are safe (:func:`_safe_directory`);
    else ``(False, why)``. Decided once per process and directory (the
    directory follows ``HFDI_CACHE_DIR`` as it is now)."""
    if os.environ.get("HFDI_NO_DISK_CACHE"):
        return False, "HFDI_NO_DISK_CACHE is set"
    path = numba_cache_dir()
    if not path.is_dir():           # removed since it was checked: made and checked again
        _directory_trusted.cache_clear()
    return _directory_trusted(path)


@functools.lru_cache(maxsize=None)
def _directory_trusted(path: Path) -> tuple[bool, str]:
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        path.mkdir(mode=0o700, exist_ok=True)
    except OSError as exc:
        return False, f"{path} cannot be made ({exc.strerror})"
    for directory in (path, path.parent):
        if not _safe_directory(directory):
            return False, (f"{directory} is not a directory of this user that only this "
                           f"user can write")
    return True, ""


@functools.lru_cache(maxsize=None)
def _module_digest(path: str, mtime_ns: int, size: int) -> tuple[str, tuple]:
    """The digest of one module's code (its syntax tree without docstrings)
    and the package-relative modules it imports."""
    source = Path(path).read_text(encoding="utf-8")
    tree = ast.parse(source)
    imports = []
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)) \
                and body and isinstance(body[0], ast.Expr) \
                and isinstance(getattr(body[0], "value", None), ast.Constant) \
                and isinstance(body[0].value.value, str):
            node.body = body[1:] or [ast.Pass()]
        if isinstance(node, ast.ImportFrom) and node.level:
            imports.append((node.level, node.module or "", tuple(a.name for a in node.names)))
    digest = hashlib.sha256(ast.dump(tree, annotate_fields=False).encode()).hexdigest()
    return digest, tuple(imports)


def _resolve(path: Path, level: int, module: str, names: tuple) -> list[Path]:
    """The files a relative import ``from <level dots><module> import names`` of
    ``path`` reads (the module, or the submodules named)."""
    base = path.parent
    for _ in range(level - 1):
        base = base.parent
    target = base.joinpath(*module.split(".")) if module else base
    found = []
    if target.with_suffix(".py").is_file():
        found.append(target.with_suffix(".py"))
    elif target.is_dir():
        modules = [target / f"{name}.py" for name in names]
        found += [module for module in modules if module.is_file()]
        # the package's __init__ only where a name is its own (``from . import
        # checks`` reads checks.py: the package's __init__ imports everything)
        if len(found) < len(names) and (target / "__init__.py").is_file():
            found.append(target / "__init__.py")
    return found


def source_digest(path) -> str:
    """The digest of ``path``'s code and of every module of the package it
    imports, recursively: what compiled code from ``path`` depends on."""
    seen, todo, parts = set(), [Path(path).resolve()], []
    while todo:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        info = current.stat()
        digest, imports = _module_digest(str(current), info.st_mtime_ns, info.st_size)
        parts.append(f"{current.name}:{digest}")
        for level, module, names in imports:
            todo += _resolve(current, level, module, names)
    return hashlib.sha256("\n".join(sorted(parts)).encode()).hexdigest()[:20]


@functools.lru_cache(maxsize=None)
def _source_keyed_locator(caching):
    """numba's cache locator of this package's functions (a class of numba's
    ``_CacheLocator``, made when numba is imported)."""

    class SourceKeyedLocator(caching._CacheLocator):
        """In :func:`numba_cache_dir`, stamped with :func:`source_digest` of the
        function's module."""

        def __init__(self, py_file, package):
            # the package's name in the key: numba's files pickle objects that
            # name their modules, so a copy of these sources imported under
            # another name (an FMU's) must not load this package's files
            self._digest = f"{package}-{source_digest(py_file)}"
            self._path = numba_cache_dir()

        def ensure_cache_path(self):
            # made and checked here too: the directory may have changed since
            # the options of a function were set (HFDI_CACHE_DIR)
            trusted, why = _directory_trusted(self._path)
            if not trusted:
                raise OSError(why)

        def get_cache_path(self):
            return str(self._path)

        def get_source_stamp(self):
            return self._digest

        def get_disambiguator(self):
            return self._digest

        @classmethod
        def from_function(cls, py_func, py_file):
            module = getattr(py_func, "__module__", "") or ""
            if not module.startswith(("hfdi", "_hfdi")) or not os.path.isfile(py_file):
                return None
            return cls(py_file, module.split(".")[0])

    return SourceKeyedLocator


class _Entry:
    """An entry point of compiled code: a numba dispatcher made when first
    used (so that importing the library imports no numba), with ``py_func``,
    the plain function, at hand without it."""

    def __init__(self, function, options):
        self.py_func = function
        self._options = options
        self._dispatcher = None
        functools.update_wrapper(self, function)

    @property
    def dispatcher(self):
        if self._dispatcher is None:
            trusted, why = cache_trusted()
            if not trusted:
                _say_uncached(why)
            clone = _clone(self.py_func)
            self._dispatcher = _numba().njit(cache=trusted, **JIT_OPTIONS,
                                             **self._options)(clone)
            _link(clone, self.py_func)
        return self._dispatcher

    def __call__(self, *args):
        return self.dispatcher(*args)

    def __getattr__(self, name):       # overloads, compile, stats, address ... of numba's
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.dispatcher, name)


def entry(function=None, **options):
    """Compile ``function`` as an entry point of compiled code (``numba.njit``
    with :data:`JIT_OPTIONS`), cached on disk where :func:`cache_trusted`; the
    core functions it calls are their twins (:func:`twin`). Made when first
    used and compiled at the first call with new argument types; see
    :func:`compiling` for the notice of a first compilation."""
    def wrap(fn):
        return _Entry(fn, options)
    return wrap if function is None else wrap(function)


_SAID = set()


def _say_uncached(why):
    if why not in _SAID:
        _SAID.add(why)
        _log.warning("hfdi: compiled code is not cached on disk (%s); it is compiled in "
                     "every process", why)


#: A compilation shorter than this (s) is not announced: loading code from the
#: disk cache compiles small wrappers (tenths of a second) in every process.
ANNOUNCE_AFTER = 1.0


class _CompileNotice:
    """The compilations numba makes in one thread (the one that entered
    :func:`compiling`; numba's listeners hear every thread's), timed from
    the start of each outermost compilation to its end: a timer announces
    them once they have taken :data:`ANNOUNCE_AFTER` in all."""

    def __init__(self, what):
        self.what, self.thread = what, threading.get_ident()
        self.depth, self.spent, self.since = 0, 0.0, 0.0
        self.timer, self.where = None, None
        self.announced = threading.Event()

    def start(self):
        if threading.get_ident() != self.thread:
            return
        self.depth += 1
        if self.depth > 1 or self.announced.is_set():
            return
        self.since = time.perf_counter()
        if self.where is None:      # in the compiling thread: HFDI_CACHE_DIR as it is now
            self.where = numba_cache_dir() if cache_trusted()[0] else "memory only"
        timer = threading.Timer(max(ANNOUNCE_AFTER - self.spent, 0.0), self._announce)
        timer.daemon = True
        try:
            timer.start()
        except RuntimeError:        # no new thread (interpreter shutdown): no notice
            return
        self.timer = timer

    def end(self):
        if threading.get_ident() != self.thread or self.depth == 0:
            return
        self.depth -= 1
        if self.depth == 0:
            self._stop()

    def _announce(self):
        self.announced.set()
        _log.warning("hfdi: compiling %s (once: the code is kept in %s) ...", self.what,
                     self.where)

    def _stop(self):
        self.spent += time.perf_counter() - self.since
        timer, self.timer = self.timer, None
        if timer is not None:
            timer.cancel()
            timer.join()

    def close(self):
        """After the context: the time spent, counting a compilation cut short."""
        if self.depth:
            self.depth = 0
            self._stop()


#: The notices of the contexts of :func:`compiling` open in each thread, innermost last.
_NOTICES = threading.local()
_LISTENING = []


def _listen():
    """Register, once per process, the listener of numba's compilations that
    tells the innermost notice of the compiling thread (registering one per
    context cost tens of µs a run)."""
    if _LISTENING:
        return
    from numba.core import event

    class Listener(event.Listener):
        def on_start(self, _):
            notices = getattr(_NOTICES, "open", None)
            if notices:
                notices[-1].start()

        def on_end(self, _):
            notices = getattr(_NOTICES, "open", None)
            if notices:
                notices[-1].end()

    event.register("numba:compile", Listener())
    _LISTENING.append(True)


@contextlib.contextmanager
def compiling(what: str):
    """Within this context numba may compile ``what``: when it does (code not
    found in the disk cache) for longer than :data:`ANNOUNCE_AFTER`, say so
    once per process on stderr, as a log record at WARNING of the logger
    ``hfdi``, while the compilation goes on and again with the time it took
    (the compilations' time, not the rest of the context's)."""
    if what in _SAID:
        yield
        return
    _numba()                    # imported with the cache's locator installed
    _listen()
    notice = _CompileNotice(what)
    notices = getattr(_NOTICES, "open", None)
    if notices is None:
        notices = _NOTICES.open = []
    notices.append(notice)
    try:
        yield
    finally:
        notices.remove(notice)
        notice.close()
    if notice.announced.is_set():
        _SAID.add(what)         # not watched again in this process
        _log.warning("hfdi: compiled %s in %.1f s", what, notice.spent)
