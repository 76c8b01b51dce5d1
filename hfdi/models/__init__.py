"""The paper's benchmark models, a model with events, and a registry to get them by name."""
from __future__ import annotations

import inspect

from .articulated import Articulated, articulated
from .dumbbell import Dumbbell, dumbbell
from .impact_oscillator import ImpactOscillator, impact_oscillator
from .loads import hat
from .tetrahedra import Tetrahedra, tetrahedra
from .toss_rule import TossRule, toss_rule

__all__ = ["Dumbbell", "dumbbell", "Tetrahedra", "tetrahedra", "Articulated", "articulated",
           "TossRule", "toss_rule", "ImpactOscillator", "impact_oscillator", "EnergyModel", "elastic_pendulum", "spring_chain",
           "hat", "get", "available", "describe", "register"]

_REGISTRY: dict = {}

#: Loaded on first use: they import sympy, which neither the paper's models
#: nor an FMU host needs (``import hfdi`` stays light).
_SYMBOLIC = ("EnergyModel", "elastic_pendulum", "spring_chain")


def __getattr__(name):
    if name in _SYMBOLIC:
        from . import symbolic
        return getattr(symbolic, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register(name: str, cls) -> None:
    """Make a model class available by ``name`` to :func:`get`."""
    _REGISTRY[name] = cls


def available() -> list:
    """Names of the registered models."""
    return sorted(_REGISTRY)


def _lookup(name):
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown model {name!r}; available: {', '.join(available())}") from None


def get(name: str, **params):
    """A model by name, with its parameters as keyword arguments.

    Raises
    ------
    ValueError
        For an unknown model name or parameter (listing the allowed ones), or
        a parameter value the model refuses.
    """
    cls = _lookup(name)
    allowed = describe(name)
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise ValueError(f"model {name!r} has no parameter(s) {', '.join(unknown)}; "
                         f"its parameters are: {', '.join(allowed)}")
    return cls(**params)


def describe(name: str) -> dict:
    """The parameters of a registered model and their defaults."""
    sig = inspect.signature(_lookup(name).__init__)
    return {k: p.default for k, p in sig.parameters.items() if k != "self"}


register("dumbbell", Dumbbell)
register("tetrahedra", Tetrahedra)
register("articulated", Articulated)
register("toss_rule", TossRule)
register("impact_oscillator", ImpactOscillator)
