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

The table is looked up in this order: a ``fmi_metadata`` attribute on the
model class (same layout, for models that want to declare their own), then
:data:`KNOWN` below, then :func:`generic` (SI translational units assumed, and
said so in the descriptions). The resolved table is embedded in the FMU's
generated slave module, so the FMU never needs this file at run time.
"""
from __future__ import annotations

import copy

__all__ = ["KNOWN", "generic", "resolve"]

_PAIRS = ("12", "13", "14", "23", "24", "34")

#: Tables of the models the project registers.
KNOWN: dict = {
    "dumbbell": {
        "dofs": [["m", "x of particle {k}"], ["m", "y of particle {k}"]],
        "parameters": {
            "A": ["J", "bond strength A of V(r) = A[(sigma/r)^5 - (sigma/r)^3] (paper Eq. 44)"],
            "sigma": ["m", "length parameter sigma of the bond potential (rest length "
                           "sigma*(5/3)^(1/2))"],
        },
        "quantities": {
            "u": ["m", "positions", None],
            "stretch": ["1", "relative bond stretch (r - r0)/r0", None],
        },
    },
    "tetrahedra": {
        "dofs": [["m", "x of particle {k}"], ["m", "y of particle {k}"],
                 ["m", "z of particle {k}"]],
        "parameters": {
            "k_stiff": ["N/m", "stiffness k of the spring between particles 1 and 2 (Eq. 45)"],
            "k_soft": ["N/m", "stiffness k of the five other springs (Eq. 45)"],
            "load_amplitude": ["N", "peak of the hat-shaped x force on particle 1"],
            "load_time": ["s", "time of the peak of the hat load (it ends at twice this)"],
        },
        "quantities": {
            "u": ["m", "positions", None],
            "f": ["N", "interaction forces f^ij of the six springs (Eq. 46)",
                  [f"pair {p} {c}" for p in _PAIRS for c in "xyz"]],
        },
    },
    "articulated": {
        "dofs": [["m", "x of mass {k}"], ["m", "y of mass {k}"]],
        "parameters": {
            "k_e": ["N/m", "axial stiffness of the two links (Eq. 47)"],
            "k_f": ["N.m/rad", "rotational stiffness of the hinge spring (Eq. 48)"],
            "h": ["m", "rest length of each link"],
            "load_amplitude": ["N", "peak of the hat-shaped y force on mass 1"],
            "load_time": ["s", "time of the peak of the hat load (it ends at twice this)"],
        },
        "quantities": {
            "u": ["m", "positions", None],
            "delta_alpha": ["rad", "hinge angle alpha12 - alpha23", None],
        },
    },
    "toss_rule": {
        "dofs": [["m", "axial u of node {k0}"],
                 ["m", "transverse v of node {k0}"],
                 ["rad", "rotation alpha of node {k0}"]],
        "parameters": {
            "n_elements": ["1", "number of beam elements (fixes the number of DOFs)"],
            "length": ["m", "length of the rule"],
            "width": ["m", "width of the cross-section"],
            "thickness": ["m", "thickness of the cross-section"],
            "E": ["Pa", "Young's modulus"],
            "nu": ["1", "Poisson's ratio"],
            "shear_factor": ["1", "shear correction factor"],
            "rho": ["kg/m3", "density"],
            "force_amplitude": ["N", "peak of the +y hat force at the left end"],
            "moment_amplitude": ["N.m", "peak of the hat moment at the left end"],
            "load_time": ["s", "time of the peak of both hat loads"],
        },
        "quantities": {
            "u": ["m", "nodal displacements and rotations", None],
            "alpha_mv": ["rad", "mean of the elements' rotations alpha_o (Eq. 55)", None],
            "m_c": ["N.m", "bending moment EJ chi at the centre (Eq. 55)", None],
            "alpha_t_mv": ["rad/s", "mean rotation rate over the elements", None],
            "N_c": ["N", "axial force EA epsilon at the centre", None],
        },
    },
}


def generic() -> dict:
    """The table assumed for a model that declares none: translational DOFs in SI units."""
    return {"dofs": [["m", "degree of freedom {k} (unit assumed, the model declares none)"]],
            "parameters": {}, "quantities": {}}


def resolve(name: str, model_class=None) -> dict:
    """The table for the registered model ``name``.

    Parameters
    ----------
    name : str
        Registry name.
    model_class : type, optional
        The registered class; its ``fmi_metadata`` attribute wins when present.

    Returns
    -------
    dict
        A deep copy with the keys ``dofs``, ``parameters`` and ``quantities``,
        made only of lists, dicts, strings and None so that its ``repr`` is a
        Python literal.
    """
    table = getattr(model_class, "fmi_metadata", None) if model_class is not None else None
    if not isinstance(table, dict):
        table = KNOWN.get(name) or generic()
    out = generic()
    out.update(copy.deepcopy(table))
    out["dofs"] = [list(item) for item in out["dofs"]] or generic()["dofs"]
    out["parameters"] = {str(k): list(v) for k, v in out["parameters"].items()}
    out["quantities"] = {str(k): [v[0], v[1], None if len(v) < 3 or v[2] is None
                                  else [str(c) for c in v[2]]]
                         for k, v in out["quantities"].items()}
    return out
