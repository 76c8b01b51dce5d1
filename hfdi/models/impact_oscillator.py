"""A mass on a spring that strikes a stop: the registry's model with events.

``m u'' + k u = 0`` while ``u > −gap``; at ``u = −gap`` (moving down) the
mass rebounds, ``v → −e v`` (Newton's coefficient of restitution ``e``).
The model declares its two event functions and the reset
(docs/user-models.md, "Events"): ``impact`` (``u + gap``, falling) with the
rebound, and ``turning`` (``v``, falling: a highest point). Between impacts
the motion is the spring's, so every event time is known in closed form
(:func:`exact_events`); the FMUs built of it return early at its events
(fmu/README.md).
"""
from __future__ import annotations

import math

import numpy as np

from .. import checks
from .base import KernelModel, length_scale
from .kernels import kernel

__all__ = ["ImpactOscillator", "impact_oscillator", "exact_events"]


class ImpactOscillator(KernelModel):
    """One DOF, ``u`` the displacement from the spring's rest position.

    Parameters
    ----------
    mass, stiffness : float
        ``m`` and ``k`` (defaults 1 and (2π)²: a period of 1).
    gap : float
        Distance from the rest position down to the stop, ``> 0``.
    restitution : float
        ``e`` in ``[0, 1]``.
    u0, v0 : float
        Initial displacement (``> −gap``) and velocity.
    """

    name = "impact_oscillator"
    fmi_metadata = {
        "dofs": [["m", "displacement of the mass"]],
        "parameters": {
            "mass": ["kg", "mass m"],
            "stiffness": ["N/m", "spring stiffness k"],
            "gap": ["m", "distance from the rest position down to the stop"],
            "restitution": ["1", "coefficient of restitution e at the stop"],
            "u0": ["m", "initial displacement"],
            "v0": ["m/s", "initial velocity"],
        },
        "quantities": {},
        "stop_time": 3.0,
    }

    #: the constructor's ``stiffness``, under a name of its own (``stiffness``
    #: is the method)
    PARAMETER_ATTRIBUTES = ("stiffness_value",)

    def __init__(self, mass=1.0, stiffness=4.0 * math.pi ** 2, gap=0.08, restitution=0.7,
                 u0=0.0, v0=1.0):
        mass = checks.positive("impact_oscillator mass", mass)
        self.stiffness_value = checks.positive("impact_oscillator stiffness", stiffness)
        self.gap = checks.positive("impact_oscillator gap", gap)
        self.restitution = checks.real("impact_oscillator restitution", restitution)
        if not 0.0 <= self.restitution <= 1.0:
            raise ValueError(f"impact_oscillator restitution must lie in [0, 1], got "
                             f"{restitution!r}")
        u0 = checks.real("impact_oscillator u0", u0)
        if not u0 > -self.gap:
            raise ValueError(f"impact_oscillator u0 must be above the stop (> -gap = "
                             f"{-self.gap!r}), got {u0!r}")
        self.n_dof = 1
        self.mass = np.array([mass])
        self.initial_displacement = np.array([u0])
        self.initial_velocity = np.array([checks.real("impact_oscillator v0", v0)])

    @length_scale
    def u_scale(self) -> float:
        """The gap: the model's length scale (the default atol's)."""
        return self.gap

    @property
    def mass_value(self) -> float:
        """The parameter ``mass``: the mass matrix's one entry (an assigned
        ``mass`` is the model's, its parameters and its exact events too)."""
        return float(np.asarray(self.mass, dtype=float).ravel()[0])

    def parameters(self):
        return {"mass": self.mass_value, "stiffness": self.stiffness_value, "gap": self.gap,
                "restitution": self.restitution, "u0": float(self.initial_displacement[0]),
                "v0": float(self.initial_velocity[0])}

    def params(self):
        """The kernels' data ``(k,)``."""
        return np.array((self.stiffness_value,))

    def quantities(self, t, u, v):
        return {"u": np.atleast_2d(u)}

    # -- the declared events ------------------------------------------------------
    @property
    def events(self):
        """``(impact, turning)``: the event functions the integrator watches
        unless told otherwise (``events=``)."""
        return (self.impact, self.turning)

    def impact(self, t, u, v):
        """Distance above the stop; its falling zeros are the impacts."""
        return u[0] + self.gap

    impact.direction = -1

    def turning(self, t, u, v):
        """The velocity; its falling zeros are the highest points."""
        return v[0]

    turning.direction = -1

    def on_event(self, t, u, v, which):
        """At an impact (``which`` 0) the rebound ``v → −e v``, at the stop."""
        if which != 0:
            return None
        return np.array([-self.gap]), -self.restitution * v


@kernel
def impact_oscillator_force(u, params):
    return params[0] * u


@kernel
def impact_oscillator_stiffness(u, params):
    out = np.empty((1, 1))
    out[0, 0] = params[0]
    return out


@kernel
def impact_oscillator_stiffness_derivative(u, w, params):
    return np.zeros((1, 1))


@kernel
def impact_oscillator_potential_energy(u, params):
    return 0.5 * params[0] * u[0] * u[0]


ImpactOscillator.KERNELS = (impact_oscillator_force, impact_oscillator_stiffness,
                            impact_oscillator_stiffness_derivative,
                            impact_oscillator_potential_energy)


def impact_oscillator(**params) -> ImpactOscillator:
    """The impact oscillator; keyword arguments as :class:`ImpactOscillator`."""
    return ImpactOscillator(**params)


def exact_events(model: ImpactOscillator, t_end: float):
    """The exact times of the model's impacts and highest points up to ``t_end``.

    Between impacts ``u(τ) = U cos(ωτ) + (V/ω) sin(ωτ)`` from the last event's
    state ``(U, V)``; the next highest point is where the phase reaches 0 (mod
    2π) going forwards, the next impact where ``u`` returns to ``−gap``.

    Returns
    -------
    (ndarray, ndarray)
        Impact times and highest-point times, increasing.
    """
    omega = math.sqrt(model.stiffness_value / model.mass_value)
    gap, e = model.gap, model.restitution
    t, u, v = 0.0, float(model.initial_displacement[0]), float(model.initial_velocity[0])
    impacts, tops = [], []
    while True:
        # u = R cos(ωτ − φ): the top at ωτ = φ (mod 2π), the stop where cos(ωτ − φ) = −gap/R
        R = math.hypot(u, v / omega)
        phi = math.atan2(v / omega, u)
        top = (phi % (2.0 * math.pi)) / omega
        if R <= gap:                               # never reaches the stop again
            while t + top <= t_end:
                tops.append(t + top)
                top += 2.0 * math.pi / omega
            break
        # the first τ > 0 with ωτ − φ = ±acos(−gap/R) (mod 2π), moving down
        alpha = math.acos(-gap / R)                 # the down-going crossing: ωτ − φ = α
        hit = ((alpha + phi) % (2.0 * math.pi)) / omega
        if hit <= 1e-15 * max(1.0, t) / omega:     # at the stop now: the next round
            hit += 2.0 * math.pi / omega
        if 0.0 < top < hit and t + top <= t_end:
            tops.append(t + top)
        if t + hit > t_end:
            break
        t += hit
        impacts.append(t)
        speed = R * omega * math.sin(alpha)         # |v| at the stop
        u, v = -gap, e * speed
    return np.array(impacts), np.array(tops)
