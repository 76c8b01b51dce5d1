"""numba's on-disk cache of this package, kept in step with its sources.

numba keys a cached function on its own file's timestamp and size only, not
on the functions it compiles into itself from other files: the driver
(``driver.py``) compiles the attempt (``attempt.py``) into its own code, so
after an edit of ``attempt.py`` alone the driver's cache would hand back the
old attempt. The cache is therefore kept for one state of the whole package:
a stamp of the sources of ``hfdi/compiled`` (names, sizes and modification
times) lies beside numba's files, and where it differs from the sources the
package's cached functions are removed before any is loaded. The stamp also
covers ``hfdi/corrector.py``, ``hfdi/evaluation.py`` and ``hfdi/linalg.py``,
whose rules (the convergence test, short steps, the energy overflow, the
symmetry tolerance of a dense solve) are compiled in.

This covers numba's default place for the cache, ``__pycache__`` beside the
sources. A cache elsewhere (``NUMBA_CACHE_DIR``, or a user-wide one where the
package cannot be written) is left to numba: there the sources change only by
a new installation, which gives every file a new timestamp.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

from ..files import write_atomic

__all__ = ["drop_stale_cache", "source_stamp"]

_PACKAGE = Path(__file__).resolve().parent
_STAMP = "hfdi-compiled-sources.stamp"
#: Sources outside the package whose functions or constants its compiled code
#: compiles in (the corrector's convergence test and short steps, the energy
#: overflow, the symmetry tolerance of a dense solve).
_COMPILED_IN = (_PACKAGE.parent / "corrector.py", _PACKAGE.parent / "evaluation.py",
                _PACKAGE.parent / "linalg.py")


def source_stamp(package: Path = _PACKAGE, compiled_in=_COMPILED_IN) -> str:
    """A digest of the names, sizes and modification times of ``package``'s
    sources and of the sources ``compiled_in``."""
    digest = hashlib.sha256()
    for path in sorted(package.glob("*.py")) + list(compiled_in):
        status = path.stat()
        digest.update(f"{path.name} {status.st_size} {status.st_mtime_ns}\n".encode())
    return digest.hexdigest()


def drop_stale_cache(package: Path = _PACKAGE, compiled_in=_COMPILED_IN) -> bool:
    """Remove numba's cached functions of ``package`` when its sources (or the
    sources ``compiled_in``) changed since they were cached; True when
    something was removed."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return False
    cache = package / "__pycache__"
    try:
        stamp = source_stamp(package, compiled_in)
    except OSError:          # sources that cannot be read: numba will not cache them either
        return False
    try:
        if (cache / _STAMP).read_text() == stamp:
            return False
    except OSError:
        pass
    removed = False
    try:
        for path in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            path.unlink(missing_ok=True)
            removed = True
        cache.mkdir(exist_ok=True)
        write_atomic(cache / _STAMP, stamp)
    except OSError:          # a package that cannot be written: numba caches elsewhere
        pass
    return removed
