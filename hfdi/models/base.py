"""What the benchmark models share: methods that call their kernels, and a
load of hat pulses (docs/models.md, "One physics per model")."""
from __future__ import annotations

import functools
import inspect

import numpy as np

from ..system import SecondOrderSystem
from .kernels import compiled_kernels
from .loads import hat_load, hat_load_params

__all__ = ["KernelModel", "length_scale"]


def _read_only(value):
    """``value``, an array made a read-only copy of its own (a view's base would
    stay writeable)."""
    if isinstance(value, np.ndarray):
        value = value.copy()
        value.flags.writeable = False
    return value


class length_scale:                                  # noqa: N801 - used as a decorator
    """``u_scale`` computed from the model's live parameters (``rest_length``,
    ``h``, ``gap``), unless one is assigned, as on any model."""

    def __init__(self, default):
        self.default = default
        self.__doc__ = default.__doc__

    def __get__(self, model, kind=None):
        if model is None:
            return self
        given = model.__dict__.get("u_scale")
        return self.default(model) if given is None else given

    def __set__(self, model, value):
        model.__dict__["u_scale"] = value


@functools.lru_cache(maxsize=None)
def _parameter_names(cls) -> frozenset:
    """The model's parameters: the names the constructors of ``cls`` and of
    its bases take (a subclass's own ``__init__`` passes theirs on), and its
    ``PARAMETER_ATTRIBUTES``."""
    names = set()
    for klass in cls.__mro__:
        init = vars(klass).get("__init__")
        if init is None:
            continue
        try:
            signature = inspect.signature(init)
        except (TypeError, ValueError):
            continue
        names.update(name for name, p in signature.parameters.items()
                     if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))
    return frozenset(names.union(getattr(cls, "PARAMETER_ATTRIBUTES", ())) - {"self"})


def _same(old, new) -> bool:
    try:
        return bool(np.array_equal(old, new))
    except Exception:       # noqa: BLE001 - values that do not compare are changes
        return False


class KernelModel(SecondOrderSystem):
    """A model whose ``f``, ``K``, ``T[w]`` and ``V`` are the kernels
    :attr:`KERNELS` on the data :meth:`params`, and whose load is the hat
    pulses of :meth:`load_params` (none by default). No exact load rate: the
    paper's quotient is exact for the pulses, linear between their kinks
    (:attr:`load_linear_between_breakpoints`)."""

    #: ``(force, stiffness, stiffness_derivative, potential_energy)``, the kernels.
    KERNELS: tuple = ()
    #: Construction parameters that other data are derived from when the model
    #: is built (its mass matrix, the kernels' geometry): set by the
    #: constructor only, so that the model never runs with a value it no
    #: longer shows (the derived data themselves, ``mass`` among them, may be
    #: replaced, as a subclass does; Integrator.model_changed checks M and C).
    #: Their arrays are read-only.
    FIXED_PARAMETERS: tuple = ()
    load_rate = None
    damping = None
    #: Counts the changes of the model's parameters (the names its
    #: constructors take and :attr:`PARAMETER_ATTRIBUTES`, ``m.sigma = 0.8``):
    #: an integrator seeing it move calls its ``model_changed()`` before its
    #: next step, so that both speeds follow the change at once, with ``f``,
    #: ``a`` and ``V`` recomputed (the compiled kernels read the parameters as
    #: data handed to them). Other attributes (a subclass's counters, caches)
    #: are not the model's physics; a value assigned again is no change.
    parameter_version = 0
    #: Attributes the kernels' data are built from whose names the
    #: constructor does not take (``stiffness_value`` for ``stiffness``).
    PARAMETER_ATTRIBUTES: tuple = ()

    def __setattr__(self, name, value):
        if name in self.FIXED_PARAMETERS:
            if name in self.__dict__:
                raise AttributeError(
                    f"{self.name} {name} is fixed once the model is built (the mass matrix "
                    f"or the kernels' data are derived from it): build a new model, "
                    f"hfdi.models.get({self.name!r}, {name}=...)")
            value = _read_only(value)
        elif isinstance(getattr(type(self), name, None), property) and \
                getattr(type(self), name).fset is None:
            raise AttributeError(
                f"{self.name} {name} is derived from the model's parameters and cannot be "
                f"assigned: build a model with other parameters, hfdi.models.get({self.name!r}, "
                f"...)")
        missing = object()
        old = self.__dict__.get(name, missing)
        super().__setattr__(name, value)
        if name in _parameter_names(type(self)) and (old is missing or not _same(old, value)):
            super().__setattr__("parameter_version", self.parameter_version + 1)

    def __setstate__(self, state):
        """A copy or an unpickled model keeps its fixed parameters read-only."""
        self.__dict__.update({name: _read_only(value) if name in self.FIXED_PARAMETERS
                              else value for name, value in state.items()})

    def load_params(self) -> np.ndarray:
        """The load's data (:func:`~hfdi.models.loads.hat_load`)."""
        return hat_load_params(self.n_dof)

    def internal_force(self, u):
        return self.KERNELS[0](np.asarray(u, dtype=float), self.params())

    def stiffness(self, u):
        return self.KERNELS[1](np.asarray(u, dtype=float), self.params())

    def stiffness_derivative(self, u, w):
        return self.KERNELS[2](np.asarray(u, dtype=float), np.asarray(w, dtype=float),
                               self.params())

    def potential_energy(self, u):
        return self.KERNELS[3](np.asarray(u, dtype=float), self.params())

    def compiled_kernels(self):
        """The kernels compiled, with the load (imports numba)."""
        return compiled_kernels(*self.KERNELS, self.params(), load_params=self.load_params())

    def load(self, t):
        return hat_load(float(t), self.load_params())

    @property
    def load_linear_between_breakpoints(self) -> bool:
        """The hat pulses are linear between their kinks (unless a subclass
        replaces the load or its breakpoints)."""
        kind = type(self)
        return kind.load is KernelModel.load and \
            kind.load_breakpoints is KernelModel.load_breakpoints

    def load_breakpoints(self):
        """The kinks of the hat pulses: ``0``, ``t1`` and ``2 t1`` of each."""
        pulses = self.load_params()
        return tuple(sorted({x for t1 in map(float, pulses[4::3]) for x in (0.0, t1, 2.0 * t1)}))

    def _given(self, params, shape, default_positions, positions=None):
        """``params`` with the positions (default: the initial ones) and the
        initial velocities where they are not the defaults the parameters
        give (the straight chain of the current ``h``, say), so that
        ``get(name, **model.parameters())`` builds the model as it is."""
        positions = self.initial_displacement if positions is None else positions
        if not np.array_equal(np.ravel(positions), np.ravel(default_positions)):
            params["positions"] = tuple(map(tuple, np.reshape(positions, shape).tolist()))
        if np.any(self.initial_velocity):
            params["v0"] = tuple(self.initial_velocity.tolist())
        return params
