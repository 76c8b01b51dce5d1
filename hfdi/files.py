"""Files: atomic output (a killed run leaves the old file or none, never half
of one) and the directory of the project's caches."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_file", "write_atomic", "cache_dir"]


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
def atomic_file(path):
    """A binary file handle whose content replaces ``path`` only when the block ends.

    The data go to a temporary file ``.<name>.*.tmp`` beside ``path``, are
    synced and then moved over ``path`` with ``os.replace``; on any exception
    the temporary file is removed. The file gets the usual permissions
    (``0o666`` less the umask), not the owner-only ones of ``mkstemp``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
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
