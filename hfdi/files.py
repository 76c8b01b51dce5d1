"""Files: atomic output (a killed run leaves the old file or none, never half
of one) and the directory of the project's caches.

:func:`atomic_file` and :func:`write_atomic` write a file of the program's own
(a cache entry), replacing whatever is at the path, a symbolic link included;
:func:`atomic_output` and :func:`write_output` write an output the user named,
following a symbolic link, writing a FIFO or character device as it is, and
refusing other special files (docs/robustness.md, "CLI section").
"""
from __future__ import annotations

import contextlib
import errno
import io
import os
import stat
import tempfile
from pathlib import Path

__all__ = ["atomic_file", "write_atomic", "atomic_output", "write_output", "cache_dir"]


def cache_dir() -> Path:
    """``$HFDI_CACHE_DIR``, or ``~/.cache/hfdi``: IDA references
    (``validation``) and generated kernels (:mod:`hfdi.compiled.symbolic`)."""
    env = os.environ.get("HFDI_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "hfdi"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_file(path, *, mode: int | None = None):
    """A binary file handle whose content replaces ``path`` only when the block ends.

    The data go to a temporary file ``.<name>.*.tmp`` beside ``path``, are
    synced and then moved over ``path`` with ``os.replace``; on any exception
    the temporary file is removed. The file gets the permission bits
    ``mode``, by default the usual ones (``0o666`` less the umask), not the
    owner-only ones of ``mkstemp``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask() if mode is None else mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_atomic(path, data) -> Path:
    """Write ``data`` (str, as UTF-8, or bytes) to ``path`` atomically; returns the path."""
    with atomic_file(path) as fh:
        fh.write(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)


def _special_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a regular file"


def _output_target(path: Path):
    """``("file", where, mode)``: the regular file to replace (the target of a
    symbolic link; ``mode`` its permission bits, ``None`` for a new file), or
    ``("stream", path, None)`` for a FIFO or character device.

    Raises
    ------
    OSError
        For a directory, a socket, a block device, a loop of links.
    """
    try:
        status = os.stat(path)                  # through symbolic links
    except FileNotFoundError:
        if os.path.islink(path):                # a dangling link: make its target
            return "file", Path(os.path.realpath(path)), None
        return "file", path, None
    if stat.S_ISREG(status.st_mode):
        where = Path(os.path.realpath(path)) if os.path.islink(path) else path
        return "file", where, stat.S_IMODE(status.st_mode)
    if stat.S_ISFIFO(status.st_mode) or stat.S_ISCHR(status.st_mode):
        return "stream", path, None
    kind = _special_kind(status.st_mode)
    raise OSError(errno.EISDIR if kind == "a directory" else errno.EINVAL,
                  f"{kind}, not a file an output can be written to; nothing written",
                  str(path))


def _write_stream(path: Path, data: bytes) -> None:
    """Write ``data`` into the FIFO or character device ``path`` as it is."""
    try:
        # O_NONBLOCK: a FIFO without a reader fails at once (ENXIO) instead of
        # waiting for one; never O_CREAT nor O_TRUNC
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError as exc:
        if exc.errno == errno.ENXIO:
            raise OSError(errno.ENXIO, "a FIFO with no reader; nothing written",
                          str(path)) from None
        raise
    try:
        status = os.fstat(fd)
        if not (stat.S_ISFIFO(status.st_mode) or stat.S_ISCHR(status.st_mode)):
            # replaced since it was looked at: not written in place
            raise OSError(errno.EINVAL, "changed while the output was made; nothing written",
                          str(path))
        os.set_blocking(fd, True)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_output(path):
    """A binary file handle for an output the user named (see the module):
    a regular file (the target of a symbolic link) is replaced atomically
    when the block ends, a FIFO or character device gets the whole output
    then, as it is; on an exception nothing is written.

    Raises
    ------
    OSError
        For a directory, a socket, a block device, a FIFO with no reader, a
        device that refuses the data (``/dev/full``); a file already there
        is then as it was.
    """
    kind, where, mode = _output_target(Path(path))
    if kind == "file":
        with atomic_file(where, mode=mode) as fh:
            yield fh
        return
    buffer = io.BytesIO()
    yield buffer
    _write_stream(where, buffer.getvalue())


def write_output(path, data) -> Path:
    """Write ``data`` (str, as UTF-8, or bytes) to the output ``path`` (see
    :func:`atomic_output`); returns the path."""
    with atomic_output(path) as fh:
        fh.write(data.encode("utf-8") if isinstance(data, str) else data)
    return Path(path)
