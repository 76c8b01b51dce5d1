"""The records the core works on, each with named fields in both speeds.

- A :class:`Scalars` record (``Config``, ``Run``) is a set of named numbers.
  In Python it is a small object with ``__slots__``; compiled code gets the
  same fields as one element of a numpy structured array, which numba reads
  and writes by name. :meth:`Scalars.pack` and :meth:`Scalars.unpack` copy
  one into the other at the door of compiled code.
- An :class:`Arrays` record (``Data``, ``Vectors``) is a set of named arrays.
  In Python it is a named tuple; compiled code gets a numba ``StructRef``
  holding the same arrays (no copy: both see every write), made once by
  :meth:`Arrays.compiled`.
- The functions a run calls (the model's kernels, the scheme's stage
  function) are an :class:`Arrays` record of first-class functions, so that
  the compiled core is compiled once for all models and schemes.

Nothing here knows what the fields mean: :mod:`hfdi.core.state` declares them.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

__all__ = ["Scalars", "Arrays", "ARRAY_KINDS"]

_NUMPY_OF = {"f8": np.float64, "i8": np.int64, "b1": np.bool_}
_PYTHON_OF = {"f8": float, "i8": int, "b1": bool}


class Scalars:
    """A record of named numbers: ``fields`` are ``(name, kind, default)`` with
    kind ``"f8"``, ``"i8"`` or ``"b1"``.

    ``Scalars(...).new(**values)`` is the Python record (defaults for the
    rest); :meth:`pack` gives the one-element structured array compiled code
    takes, :meth:`unpack` copies such an array back into a Python record.
    """

    def __init__(self, name: str, fields):
        self.name = name
        self.fields = tuple(fields)
        self.names = tuple(f[0] for f in self.fields)
        self.dtype = np.dtype([(n, _NUMPY_OF[k]) for n, k, _ in self.fields])
        self._kinds = tuple(_PYTHON_OF[k] for _, k, _ in self.fields)
        defaults = {n: _PYTHON_OF[k](d) for n, k, d in self.fields}
        names = self.names

        def __init__(self, **values):
            for n in names:
                object.__setattr__(self, n, defaults[n])
            for n, value in values.items():
                setattr(self, n, value)

        def __repr__(self):
            return f"{name}({', '.join(f'{n}={getattr(self, n)!r}' for n in names)})"

        self.python = type(name, (), {"__slots__": names, "__init__": __init__,
                                      "__repr__": __repr__, "record": self})

    def new(self, **values):
        return self.python(**values)

    def values(self, record) -> tuple:
        """The fields of a Python record as plain Python numbers, in order."""
        return tuple(kind(getattr(record, n)) for n, kind in zip(self.names, self._kinds))

    def pack(self, record, out=None) -> np.ndarray:
        """A Python record as a one-element structured array (``out`` reused)."""
        if out is None:
            out = np.zeros(1, self.dtype)
        out[0] = tuple(getattr(record, n) for n in self.names)
        return out

    def unpack(self, array, record) -> None:
        """Copy ``array[0]`` into the Python ``record``."""
        for n, kind, value in zip(self.names, self._kinds, array[0].item()):
            setattr(record, n, kind(value))

    def copy(self, record):
        new = self.python.__new__(self.python)
        for n in self.names:
            object.__setattr__(new, n, getattr(record, n))
        return new


# -- arrays records ------------------------------------------------------------------

#: The kinds of field of an :class:`Arrays` record (their numba types are
#: :data:`hfdi.core.numba_types.KINDS`).
ARRAY_KINDS = ("vector", "matrix", "int32 vector", "int64 vector")


class Arrays:
    """A record of named arrays (or, for the functions a run calls, compiled
    functions): ``fields`` are ``(name, kind)`` with a kind of
    :data:`ARRAY_KINDS` or ``"function NAME"`` (a compiled function of the
    signature ``NAME`` of :mod:`hfdi.core.numba_types`). ``.python`` is the
    named tuple Python code takes; :meth:`compiled` the struct compiled code
    takes (a numba ``StructRef`` of the type :attr:`type`, holding the same
    arrays). Nothing here needs numba until a struct is made."""

    def __init__(self, name: str, fields):
        self.name = name
        self.fields = tuple(fields)
        self.names = tuple(n for n, _ in self.fields)
        self.python = namedtuple(name, self.names)

    def new(self, **values):
        return self.python(**values)

    @property
    def type(self):
        """The numba type of the compiled struct (imports numba)."""
        from .numba_types import struct_type
        return struct_type(self)

    def compiled(self, value):
        """The struct holding the arrays (functions) of the named tuple ``value``."""
        from .numba_types import build
        return build(self, tuple(value))
