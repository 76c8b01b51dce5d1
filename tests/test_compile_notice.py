"""The notice of a compilation (``hfdi.core.jit.compiling``): said once when
numba compiles for longer than ``ANNOUNCE_AFTER``, timed over the
compilations only, deaf to other threads' compilations, and never in the way
of the compilation itself. numba's compile events are raised by hand here."""
import logging
import threading
import time

import pytest

pytest.importorskip("numba")

from numba.core import event  # noqa: E402

from hfdi.core import jit  # noqa: E402

KIND = "numba:compile"


@pytest.fixture
def notices(monkeypatch, caplog):
    monkeypatch.setattr(jit, "ANNOUNCE_AFTER", 0.05)
    monkeypatch.setattr(jit, "_SAID", set())
    caplog.set_level(logging.WARNING, logger="hfdi")
    return caplog


def compile_for(seconds):
    event.start_event(KIND)
    time.sleep(seconds)
    event.end_event(KIND)


def said(caplog):
    return [r.getMessage() for r in caplog.records if r.name == "hfdi"]


def test_a_short_compilation_is_not_announced_and_stays_watched(notices):
    with jit.compiling("a"):
        compile_for(0.0)
    assert said(notices) == [] and "a" not in jit._SAID


def test_a_long_compilation_is_announced_once_with_its_own_time(notices):
    with jit.compiling("b"):
        compile_for(0.15)
        time.sleep(0.3)                # the rest of the context: not the compilation's
    messages = said(notices)
    assert len(messages) == 2 and messages[0].startswith("hfdi: compiling b (once")
    seconds = float(messages[1].split(" in ")[1].rstrip(" s"))
    assert messages[1].startswith("hfdi: compiled b") and 0.1 <= seconds < 0.3
    with jit.compiling("b"):           # said: not watched again
        compile_for(0.15)
    assert len(said(notices)) == 2


def test_short_compilations_add_up(notices):
    with jit.compiling("c"):
        for _ in range(4):
            compile_for(0.02)
    assert len(said(notices)) == 2


def test_nested_events_count_as_one_compilation(notices):
    with jit.compiling("d"):
        event.start_event(KIND)
        compile_for(0.0)               # a function compiled within another
        time.sleep(0.1)
        event.end_event(KIND)
    assert len(said(notices)) == 2


def test_another_threads_compilation_is_not_this_ones(notices):
    with jit.compiling("e"):
        other = threading.Thread(target=compile_for, args=(0.15,))
        other.start()
        other.join()
    assert said(notices) == []


def test_no_thread_for_the_timer_leaves_the_compilation_alone(notices, monkeypatch):
    def refuse(self):
        raise RuntimeError("can't create new thread at interpreter shutdown")

    monkeypatch.setattr(threading.Timer, "start", refuse)
    with jit.compiling("f"):
        compile_for(0.1)
    assert said(notices) == []


def test_a_compilation_cut_short_stops_its_timer(notices):
    before = threading.active_count()
    with pytest.raises(ValueError):
        with jit.compiling("g"):
            event.start_event(KIND)
            raise ValueError("the compilation failed")
    assert threading.active_count() == before
    time.sleep(0.1)                    # past ANNOUNCE_AFTER: the timer was stopped
    assert said(notices) == []


def _package(root, files):
    for name, text in files.items():
        path = root / "pkg" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root / "pkg"


def test_the_cache_key_follows_what_a_module_reads_not_the_package_init(tmp_path):
    """``from . import b`` reads b.py, not the package's __init__ (which imports
    every module of the library): an edit of a Python-only module must not
    recompile code that does not read it; a name of the __init__ itself does."""
    pkg = _package(tmp_path, {"__init__.py": "from . import a, c\nVALUE = 1\n",
                              "a.py": "from . import b\n", "b.py": "X = 1\n",
                              "c.py": "Y = 1\n", "d.py": "from . import VALUE\n"})
    key_a, key_d = jit.source_digest(pkg / "a.py"), jit.source_digest(pkg / "d.py")
    (pkg / "c.py").write_text("Y = 22\n")
    (pkg / "__init__.py").write_text("from . import a, c\nVALUE = 1\nZ = 3\n")
    assert jit.source_digest(pkg / "a.py") == key_a
    assert jit.source_digest(pkg / "d.py") != key_d       # d reads the __init__'s VALUE
    (pkg / "b.py").write_text("X = 22\n")
    assert jit.source_digest(pkg / "a.py") != key_a
