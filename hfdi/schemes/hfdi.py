"""The paper's scheme (Section 2.3, Table 1): quadratic velocity and force on
the step, third order and L-stable. Its stage is its own kind
(:func:`hfdi.stepping.stages.hfdi_setup`): Eq. 21 in ``u`` alone."""
from __future__ import annotations

from ..core.state import HFDI as HFDI_STAGE
from ..core.state import Stage
from .base import Scheme, stage_function

__all__ = ["HFDI"]


@stage_function
def hfdi_stage(h, index, params):
    return Stage(HFDI_STAGE, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0,
                 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


#: The values of ``HFDI(load_rate=...)``.
LOAD_RATES = ("auto", "exact", "derived", "difference")


class HFDI(Scheme):
    """The paper's scheme (Section 2.3, Table 1).

    Parameters
    ----------
    load_rate : {"auto", "exact", "derived", "difference"}
        How ``p'(t_{n+1})`` in ``g_t`` (Eq. 16) is obtained. ``"exact"`` uses
        the model's ``load_rate``; ``"derived"`` the slope at ``t_{n+1}`` of
        the quadratic through the load at ``t_{n+1}`` and two times a tenth
        and a fifth of the step before it (two more load evaluations per
        attempt; third order under any smooth load); ``"difference"`` the
        paper's ``(p(t_{n+1}) − p(t_n))/h``, which makes the scheme second
        order on problems with a time-varying load. ``"auto"`` (default):
        the exact rate when the model provides one; else the derived rate
        under error control, whose steps land on the load's breakpoints, and
        the paper's quotient in the other modes (the iteration-count mode's
        tables are the paper's; fixed steps step over a kink off their grid,
        which the derived rate's samples near the step's end would amplify)
        (docs/algorithm.md, "Load rate").
    """

    name = "hfdi"
    #: Third order with the exact or the derived load rate, or a constant
    #: load; with the paper's quotient of a varying load the scheme is second
    #: order (2.05 measured), while the error controller's step rule still takes 3.
    order = 3
    #: Eq. 19: v_D = B⁻¹(M u + q0 + …) with B ≈ 2h/3 M and q0 = −M(u_n + h/3 v_n)
    velocity_gain = 3.0
    #: ``v``'s local error is ``−h⁴ v⁗/72`` (as ``u``'s is ``−h⁴ u⁗/72``;
    #: measured −0.01386 at h = 0.005 on an oscillator from its exact state)
    velocity_error_constant = -1.0 / 72.0
    keeps_force = True
    stage = staticmethod(hfdi_stage)

    def __init__(self, load_rate: str = "auto"):
        if load_rate not in LOAD_RATES:
            allowed = ", ".join(map(repr, LOAD_RATES))
            raise ValueError(f"HFDI load_rate must be one of {allowed}, got {load_rate!r}")
        self.load_rate = load_rate

    def exact_rate(self, has_rate: bool) -> bool:
        """Whether the step takes the model's ``p'`` (it ``has_rate``)."""
        return self.load_rate == "exact" or (self.load_rate == "auto" and has_rate)

    def derived_rate(self, has_rate: bool, lands_on_breakpoints: bool) -> bool:
        """Whether the step differentiates the load itself (by default where
        the steps land on the load's breakpoints, under error control, and the
        model ``has_rate`` neither exact nor exactly the quotient)."""
        return self.load_rate == "derived" or (self.load_rate == "auto" and not has_rate
                                               and lands_on_breakpoints)

    def __repr__(self):
        return f"HFDI(load_rate={self.load_rate!r})"
