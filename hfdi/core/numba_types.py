"""The numba side of the records (imports numba): the types of their fields,
the signatures of the compiled functions a run calls, and the structs.

Nothing of :mod:`hfdi` imports this module until compiled code is made, so
that the library runs its Python steps where numba is missing (an FMU in a
host with numpy and scipy only).
"""
from __future__ import annotations

from numba import njit, types
from numba.experimental import structref
from numba.extending import intrinsic

from .jit import JIT_OPTIONS, entry
from .state import DATA, FUNCTIONS, VECTORS, Stage

__all__ = ["VECTOR", "MATRIX", "INT32_VECTOR", "INT64_VECTOR", "FORCE", "STIFFNESS",
           "STIFFNESS_DERIVATIVE", "POTENTIAL_ENERGY", "LOAD", "STAGE", "STAGE_FUNCTION",
           "Struct", "struct_type", "build", "function_struct_of"]

VECTOR = types.float64[::1]
MATRIX = types.float64[:, ::1]
INT32_VECTOR = types.int32[::1]
INT64_VECTOR = types.int64[::1]

#: ``force(u, params) -> f (N,)``
FORCE = VECTOR(VECTOR, VECTOR)
#: ``stiffness(u, params) -> K (N, N)``
STIFFNESS = MATRIX(VECTOR, VECTOR)
#: ``stiffness_derivative(u, w, params) -> T(u)[w] (N, N)``
STIFFNESS_DERIVATIVE = MATRIX(VECTOR, VECTOR, VECTOR)
#: ``potential_energy(u, params) -> V``
POTENTIAL_ENERGY = types.float64(VECTOR, VECTOR)
#: ``load(t, load_params) -> p (N,)`` (also the load rate's)
LOAD = VECTOR(types.float64, VECTOR)
STAGE = types.NamedUniTuple(types.float64, len(Stage._fields), Stage)
# numba names a named tuple by its class's name alone, and interns a function
# type by its signature's name: the stage function's type of a copy of these
# sources imported under another name (an FMU's) was the library's, holding
# the library's Stage, and the copy's cached loop then named the library's
# module (a C host without it could not load it). The package in the name
# keeps them apart (as Struct's names below).
STAGE.name = f"{__name__.split('.')[0]}.{STAGE.name}"
#: ``stage(h, index, scheme_params) -> Stage``
STAGE_FUNCTION = STAGE(types.float64, types.int64, VECTOR)

KINDS = {"vector": VECTOR, "matrix": MATRIX, "int32 vector": INT32_VECTOR,
         "int64 vector": INT64_VECTOR}
SIGNATURES = {"FORCE": FORCE, "STIFFNESS": STIFFNESS,
              "STIFFNESS_DERIVATIVE": STIFFNESS_DERIVATIVE, "POTENTIAL_ENERGY": POTENTIAL_ENERGY,
              "LOAD": LOAD, "STAGE_FUNCTION": STAGE_FUNCTION}


def field_type(kind):
    """The numba type of a field of ``kind`` (hfdi.core.records.Arrays), or
    ``kind`` itself when it is a numba type (records of compiled code only)."""
    if not isinstance(kind, str):
        return kind
    if kind.startswith("function "):
        return types.FunctionType(SIGNATURES[kind.split()[1]])
    return KINDS[kind]


class Struct(types.StructRef):
    """Base of the numba types of the records' structs (each a module-level
    class registered with ``structref.register``, so that cached code can name it)."""

    def __init__(self, fields):
        super().__init__(fields)
        # numba interns types by name, and a struct's name is its class's
        # (not its module's) and fields: the package in the name keeps a copy
        # of these sources imported under another name (an FMU's) from
        # sharing the library's types, whose cached code then named the
        # copy's module and failed to load in a process without it
        self.name = f"{type(self).__module__.split('.')[0]}.{self.name}"

    def preprocess_fields(self, fields):
        return tuple((n, types.unliteral(t)) for n, t in fields)


@structref.register
class FunctionsType(Struct):
    pass


class CompiledFunctions(structref.StructRefProxy):
    __slots__ = ()


@structref.register
class DataType(Struct):
    pass


class CompiledData(structref.StructRefProxy):
    __slots__ = ()


@structref.register
class VectorsType(Struct):
    pass


class CompiledVectors(structref.StructRefProxy):
    __slots__ = ()


_CLASSES = {}
_TYPES = {}


def register(record, type_class, proxy_class):
    """The struct of ``record`` (an :class:`~hfdi.core.records.Arrays`) is of
    ``type_class``, boxed as ``proxy_class`` (both module-level)."""
    structref.define_boxing(type_class, proxy_class)
    _CLASSES[record.name] = type_class


register(FUNCTIONS, FunctionsType, CompiledFunctions)
register(DATA, DataType, CompiledData)
register(VECTORS, VectorsType, CompiledVectors)


def struct_type(record):
    """The numba type of ``record``'s struct."""
    made = _TYPES.get(record.name)
    if made is None:
        fields = [(name, field_type(kind)) for name, kind in record.fields]
        made = _TYPES[record.name] = _CLASSES[record.name](fields)
    return made


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
        for i, (name, kind) in enumerate(inst_type.field_dict.items()):
            value = context.cast(builder, builder.extract_value(tup, i), tuple_type[i], kind)
            context.nrt.incref(builder, kind, value)
            setattr(data, name, value)
        return context.get_dummy_value()

    return types.none(instance, values), codegen


def _build(struct_type_, values):
    """A new struct of ``struct_type_`` holding ``values`` (one per field)."""
    instance = structref.new(struct_type_)
    _fill(instance, values)
    return instance


_build_cached = entry(_build)


def build(record, values):
    """The struct of ``record`` holding ``values`` (arrays; one per field)."""
    return _build_cached(struct_type(record), values)


def _new_functions(force, stiffness, stiffness_derivative, potential_energy, load, load_rate,
                   stage):
    functions = structref.new(_FUNCTIONS_TYPE)
    functions.force = force
    functions.stiffness = stiffness
    functions.stiffness_derivative = stiffness_derivative
    functions.potential_energy = potential_energy
    functions.load = load
    functions.load_rate = load_rate
    functions.stage = stage
    return functions


_FUNCTIONS_TYPE = struct_type(FUNCTIONS)
#: FUNCTIONS' struct from dispatchers compiled for their signatures, declared
#: with the signature so that numba takes each dispatcher as a first-class
#: function (an address). Not cached on disk: numba's index of it would pickle
#: the dispatchers of the first call, and loading it would compile those again
#: (0.1 s to compile it, once per process).
_new_functions_compiled = njit(**JIT_OPTIONS)(_new_functions)
_NEW_FUNCTIONS = _FUNCTIONS_TYPE(*(field_type(kind) for _, kind in FUNCTIONS.fields))


#: The structs made so far, by their dispatchers: a struct only holds the
#: functions' addresses and is never written after it is made, so runs of the
#: same kernels share one (making it takes about 0.5 ms, a third of the fixed
#: cost of ``integrate``). Bounded: a process making models without end keeps
#: the newest.
_FUNCTION_STRUCTS: dict = {}
_FUNCTION_STRUCTS_KEPT = 64


def function_struct_of(functions):
    """FUNCTIONS' struct of the named tuple ``functions`` of numba dispatchers
    (each compiled for its signature first: loaded from the disk cache, or
    compiled)."""
    # entries of the library (hfdi.core.jit.entry) stand for their dispatchers
    functions = tuple(getattr(function, "dispatcher", function) for function in functions)
    made = _FUNCTION_STRUCTS.get(functions)
    if made is None:
        made = _make_function_struct(functions)
        if len(_FUNCTION_STRUCTS) >= _FUNCTION_STRUCTS_KEPT:
            _FUNCTION_STRUCTS.pop(next(iter(_FUNCTION_STRUCTS)))
        _FUNCTION_STRUCTS[functions] = made
    return made


def _make_function_struct(functions):
    for (name, kind), dispatcher in zip(FUNCTIONS.fields, functions):
        signature = field_type(kind).signature
        if signature.args not in dispatcher.overloads:
            dispatcher.compile(signature.args)
    if _NEW_FUNCTIONS.args not in _new_functions_compiled.overloads:
        _new_functions_compiled.compile(_NEW_FUNCTIONS)
    # the overload of the declared signature itself: each dispatcher unboxed as a
    # first-class function (a call through the dispatcher would compile another)
    return _new_functions_compiled.overloads[_NEW_FUNCTIONS.args].entry_point(*functions)
