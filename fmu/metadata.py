"""Units and labels of the registry's models, for the FMU's model description.

hfdi's model protocol carries no units: the equations are the same in any
consistent unit system. An FMU must name a unit for every Real variable, so
the builder resolves, per model, a small table:

``dofs``
    A pattern ``[[unit, label], ...]`` repeated over the degrees of freedom.
    In a label, ``{k}`` is the 1-based number of the repetition (a particle, a
    node) and ``{k0}`` the 0-based one.
``parameters``
    ``{name: [unit, description]}`` for the model's constructor parameters.
``quantities``
    ``{name: [unit, description, component labels or None]}`` for the
    quantities of interest returned by ``quantities(t, u, v)``.
``stop_time``
    The end of the FMU's default experiment (1 when the model names none).

Each model declares its table as the ``fmi_metadata`` attribute of its class
(the models of :mod:`hfdi.models` do): the units are facts of the model, kept
beside its equations. A model without one gets :func:`generic` (SI
translational units assumed, and said so in the descriptions). The resolved
table is embedded in the FMU's generated slave module, so the FMU never needs
this file at run time.
"""
from __future__ import annotations

import copy

__all__ = ["generic", "resolve"]

def generic() -> dict:
    """The table assumed for a model that declares none: translational DOFs in SI units."""
    return {"dofs": [["m", "degree of freedom {k} (unit assumed, the model declares none)"]],
            "parameters": {}, "quantities": {}, "stop_time": 1.0}


def resolve(name: str, model_class=None) -> dict:
    """The table for the registered model ``name``.

    Parameters
    ----------
    name : str
        Registry name.
    model_class : type, optional
        The registered class; its ``fmi_metadata`` attribute is the table.

    Returns
    -------
    dict
        A deep copy with the keys ``dofs``, ``parameters``, ``quantities`` and
        ``stop_time``, made only of lists, dicts, strings, floats and None so
        that its ``repr`` is a Python literal.
    """
    table = getattr(model_class, "fmi_metadata", None) if model_class is not None else None
    if not isinstance(table, dict):
        table = generic()
    out = generic()
    out.update(copy.deepcopy(table))
    out["stop_time"] = float(out["stop_time"])
    out["dofs"] = [list(item) for item in out["dofs"]] or generic()["dofs"]
    out["parameters"] = {str(k): list(v) for k, v in out["parameters"].items()}
    out["quantities"] = {str(k): [v[0], v[1], None if len(v) < 3 or v[2] is None
                                  else [str(c) for c in v[2]]]
                         for k, v in out["quantities"].items()}
    return out
