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
- :data:`FUNCTIONS` holds the compiled functions a run calls (the model's
  kernels, the scheme's stage table) as first-class functions, so that the
  compiled core is compiled once for all models and schemes.

Nothing here knows what the fields mean: :mod:`hfdi.core.state` declares them.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import types
from numba.experimental import structref
from numba.extending import intrinsic

from .jit import entry

__all__ = ["Scalars", "Arrays", "VECTOR", "MATRIX", "INT32_VECTOR", "INT64_VECTOR"]

VECTOR = types.float64[::1]
MATRIX = types.float64[:, ::1]
INT32_VECTOR = types.int32[::1]
INT64_VECTOR = types.int64[::1]

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

@intrinsic
def _fill(typingctx, instance, values):
    """Store the tuple ``values`` into the fields of the struct ``instance``, in order."""
    if not isinstance(instance, types.StructRef) or not isinstance(values, types.BaseTuple) \
            or len(values) != len(instance.field_dict):
        return None

    def codegen(context, builder, signature, args):
        inst_type, tuple_type = signature.args
        inst, tup = args
        data = structref._Utils(context, builder, inst_type).get_data_struct(inst)
        for i, (name, field_type) in enumerate(inst_type.field_dict.items()):
            value = context.cast(builder, builder.extract_value(tup, i), tuple_type[i],
                                 field_type)
            context.nrt.incref(builder, field_type, value)
            setattr(data, name, value)
        return context.get_dummy_value()

    return types.none(instance, values), codegen


@entry
def _build(struct_type, values):
    """A new struct of ``struct_type`` holding ``values`` (one per field)."""
    instance = structref.new(struct_type)
    _fill(instance, values)
    return instance


class Struct(types.StructRef):
    """Base of the numba types of :class:`Arrays` records (each a module-level
    class registered with ``structref.register``, so that cached code can name it)."""

    def preprocess_fields(self, fields):
        return tuple((n, types.unliteral(t)) for n, t in fields)


class Arrays:
    """A record of named arrays (or, for the functions a run calls, compiled
    functions): ``fields`` are ``(name, numba type)``. ``.python`` is the
    named tuple Python code takes; :meth:`compiled` the struct compiled code
    takes, of ``type_class`` (a registered subclass of :class:`Struct`) boxed
    as ``proxy_class`` (a ``structref.StructRefProxy``); both module-level."""

    def __init__(self, name: str, type_class, proxy_class, fields):
        self.name = name
        self.fields = tuple(fields)
        self.names = tuple(n for n, _ in self.fields)
        self.python = namedtuple(name, self.names)
        structref.define_boxing(type_class, proxy_class)
        self.type = type_class(list(self.fields))

    def new(self, **values):
        return self.python(**values)

    def compiled(self, value):
        """The struct holding the arrays (functions) of the named tuple ``value``."""
        return _build(self.type, tuple(value))
