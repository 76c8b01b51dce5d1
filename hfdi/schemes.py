"""The three implicit one-step schemes: Newmark, Bathe and HFDI.

A scheme is a small immutable object. For a step from a known
:class:`~hfdi.evaluation.State` it hands out one nonlinear problem per stage
(one for Newmark and HFDI, two sub-steps for Bathe). A stage problem gives the
residual and its exact tangent at a trial displacement, and the end-of-stage
state once the corrector has converged. Schemes keep no state between steps;
everything a step needs is passed in.

Equations: paper Eqs. 3–5 (Newmark), 6–10 (Bathe), 15–21 and Table 1 (HFDI),
as restated in the project's algorithm notes.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import checks
from .evaluation import Evaluator, State
from .linalg import Factorization, SingularMatrixError, combine

__all__ = ["Scheme", "Newmark", "Bathe", "HFDI", "get_scheme", "SCHEMES"]


class Scheme:
    """Base class of the one-step schemes.

    Attributes
    ----------
    name : str
    order : int
        Order of accuracy on smooth problems.
    stage_fractions : tuple of float
        Where each stage's unknown lies in the step, as a fraction of ``h``.
    """

    name = "scheme"
    order = 0
    stage_fractions: tuple = (1.0,)

    @property
    def n_stages(self) -> int:
        return len(self.stage_fractions)

    def stage(self, ev: Evaluator, start: State, t_end: float, index: int, done: list):
        """The nonlinear problem of stage ``index`` of the step ``start.t → t_end``.

        ``done`` holds the end states of the stages already solved in this step.
        """
        raise NotImplementedError

    def __repr__(self):
        return f"{type(self).__name__}()"


class _InertiaStage:
    """A stage whose velocity and acceleration are affine in the unknown ``u``.

    ``a(u) = c_a u + a_0`` and ``v(u) = c_v u + v_0``, so the residual of the
    equation of motion at the stage time is
    ``R(u) = c_a M u + c_v C u + f(u) − (p + ...)`` with tangent
    ``c_a M + c_v C + K(u)``. Newmark (Eq. 5) and both Bathe sub-steps
    (Eqs. 9 and 10) are of this form.
    """

    __slots__ = ("ev", "t", "ca", "cv", "a0", "v0", "p", "rhs")

    def __init__(self, ev: Evaluator, t, ca, cv, a0, v0):
        self.ev, self.t, self.ca, self.cv, self.a0, self.v0 = ev, t, ca, cv, a0, v0
        self.p = ev.load(t)
        self.rhs = self.p - ev.mass_times(a0) - ev.damping_times(v0)

    def residual_and_jacobian(self, u):
        ev = self.ev
        f = ev.force(u)
        residual = self.ca * ev.mass_times(u) + f - self.rhs
        if ev.damping is not None:
            residual += self.cv * ev.damping_times(u)
        tangent = combine((self.ca, ev.mass), (self.cv, ev.damping), (1.0, ev.stiffness(u)))
        return residual, tangent

    def finish(self, u):
        return State(self.t, u, self.cv * u + self.v0, self.ca * u + self.a0, None, self.p)


def _newmark_stage(ev, start: State, t, h, gamma, beta):
    """Newmark's relations (3)–(4) over ``h`` from ``start``, as an :class:`_InertiaStage`."""
    ca = 1.0 / (beta * h * h)
    cv = gamma / (beta * h)
    a0 = -ca * start.u - start.v / (beta * h) - (0.5 / beta - 1.0) * start.a
    v0 = -cv * start.u + (1.0 - gamma / beta) * start.v + h * (1.0 - 0.5 * gamma / beta) * start.a
    return _InertiaStage(ev, t, ca, cv, a0, v0)


class Newmark(Scheme):
    """Newmark's scheme, average acceleration by default (paper Eqs. 3–5).

    Parameters
    ----------
    gamma, beta : float
        Newmark parameters; ``gamma = 1/2, beta = 1/4`` is the trapezoidal rule,
        second order and unconditionally stable on linear problems.
    """

    name = "newmark"

    def __init__(self, gamma: float = 0.5, beta: float = 0.25):
        gamma = checks.real("Newmark gamma", gamma, low=0.0, high=1.0, high_closed=True)
        beta = checks.real("Newmark beta", beta, low=0.0, high=0.5, high_closed=True)
        self.gamma, self.beta = gamma, beta
        self.order = 2 if gamma == 0.5 else 1

    def stage(self, ev, start, t_end, index, done):
        return _newmark_stage(ev, start, t_end, t_end - start.t, self.gamma, self.beta)

    def __repr__(self):
        return f"Newmark(gamma={self.gamma}, beta={self.beta})"


class Bathe(Scheme):
    """Bathe's two sub-step scheme (paper Eqs. 6–10).

    The first sub-step, of length ``gamma·h``, is the trapezoidal rule; the
    second is the three-point backward formula with the coefficients of Eq. 8.

    Parameters
    ----------
    gamma : float
        Sub-step ratio in (0, 1); 1/2 gives two equal sub-steps.
    """

    name = "bathe"
    order = 2

    def __init__(self, gamma: float = 0.5):
        gamma = checks.real("Bathe gamma", gamma, low=0.0, high=1.0)
        self.gamma = gamma
        self.stage_fractions = (gamma, 1.0)

    def stage(self, ev, start, t_end, index, done):
        h = t_end - start.t
        g = self.gamma
        if index == 0:
            return _newmark_stage(ev, start, start.t + g * h, g * h, 0.5, 0.25)
        mid = done[0]
        # Eq. 8: v = c1 u_n + c2 û + c3 u,  a = c1 v_n + c2 v̂ + c3 v
        c1 = (1.0 - g) / (g * h)
        c2 = -1.0 / ((1.0 - g) * g * h)
        c3 = (2.0 - g) / ((1.0 - g) * h)
        v0 = c1 * start.u + c2 * mid.u
        a0 = c1 * start.v + c2 * mid.v + c3 * v0
        return _InertiaStage(ev, t_end, c3 * c3, c3, a0, v0)

    def __repr__(self):
        return f"Bathe(gamma={self.gamma})"


class _BlockTangent:
    """HFDI tangent ``S B⁻¹ S + R`` solved as the sparse block system
    ``[[B, −S], [S, R]] [y; Δu] = [0; b]`` when ``B`` is sparse but not diagonal,
    so that ``B⁻¹`` (a dense matrix) is never formed."""

    def __init__(self, B, S, R):
        self.n = B.shape[0]
        self.matrix = sp.bmat([[B, -S], [S, R]], format="csc")

    def solve(self, b):
        try:
            lu = spla.splu(self.matrix)
        except RuntimeError as exc:
            raise SingularMatrixError(str(exc)) from None
        return lu.solve(np.concatenate([np.zeros(self.n), b]))[self.n:]


class _HFDIStage:
    """The HFDI step residual ``F(u)`` of Eq. 21 and its exact tangent.

    With ``B = 2h/3 M + h²/6 C`` (Eq. 20 multiplied by M), ``v_D(u)`` solves
    ``B v_D = M (u − u_n − h/3 v_n) + h²/6 g(u)`` (Eq. 19) and
    ``F(u) = M v_D + C u − 2h/3 g(u) + h²/6 g_t(u, v_D) − M v_n − C u_n − h/3 g_n``.
    Its tangent is ``S B⁻¹ S + C + 2h/3 K − h²/6 T(u)[v_D]`` with
    ``S = M − h²/6 K``.
    """

    __slots__ = ("ev", "t", "h", "p", "pt", "B", "B_factor", "b_diag", "q0", "F0")

    def __init__(self, ev: Evaluator, start: State, t, use_exact_rate: bool):
        self.ev, self.t = ev, t
        h = self.h = t - start.t
        self.p = ev.load(t)
        # g_t at t_{n+1} needs p'(t_{n+1}); the paper takes the difference quotient (Section 4)
        self.pt = ev.load_rate(t) if use_exact_rate else (self.p - start.p) / h
        f_n = start.f if start.f is not None else ev.force(start.u)
        g_n = start.p - f_n
        self.B = combine((2.0 * h / 3.0, ev.mass), (h * h / 6.0, ev.damping))
        self.b_diag = self.B if self.B.ndim == 1 else None
        if self.b_diag is None:
            ev.nlu += 1
        self.B_factor = Factorization(self.B)
        self.q0 = -ev.mass_times(start.u + (h / 3.0) * start.v)
        self.F0 = -ev.mass_times(start.v) - ev.damping_times(start.u) - (h / 3.0) * g_n

    def _velocity(self, u, g):
        """``v_D(u)`` of Eq. 19."""
        h = self.h
        return self.B_factor.solve(self.ev.mass_times(u) + self.q0 + (h * h / 6.0) * g)

    def residual_and_jacobian(self, u):
        ev, h = self.ev, self.h
        c = h * h / 6.0
        g = self.p - ev.force(u)
        K = ev.stiffness(u)
        vD = self._velocity(u, g)
        gt = self.pt - K @ vD
        residual = ev.mass_times(vD) - (2.0 * h / 3.0) * g + c * gt + self.F0
        if ev.damping is not None:
            residual += ev.damping_times(u)
        S = combine((1.0, ev.mass), (-c, K))
        R = combine((1.0, ev.damping), (2.0 * h / 3.0, K), (-c, ev.stiffness_derivative(u, vD)))
        if self.b_diag is not None:
            b = self.b_diag
            if sp.issparse(S):
                scaled = S.copy()
                scaled.data /= b[scaled.indices]          # S B⁻¹, column scaling in place
                tangent = scaled @ S + R
            else:
                tangent = S @ (S / b[:, None]) + R
        elif sp.issparse(self.B):
            if not sp.issparse(S):
                S = sp.csr_matrix(S)
            tangent = _BlockTangent(self.B, S, sp.csr_matrix(R))
        else:
            S = S.toarray() if sp.issparse(S) else S
            R = R.toarray() if sp.issparse(R) else R
            tangent = S @ self.B_factor.solve(S) + R
        return residual, tangent

    def finish(self, u):
        ev = self.ev
        f = ev.force(u)
        v = self._velocity(u, self.p - f)
        a = ev.acceleration(self.t, u, v, f, self.p)   # Eq. 14
        return State(self.t, u, v, a, f, self.p)


class HFDI(Scheme):
    """The paper's scheme (Section 2.3, Table 1): quadratic velocity and force
    on the step, third order and L-stable.

    Parameters
    ----------
    load_rate : {"auto", "exact", "difference"}
        How ``p'(t_{n+1})`` in ``g_t`` (Eq. 16) is obtained. ``"difference"``
        is the paper's ``(p(t_{n+1}) − p(t_n))/h``, which makes the scheme
        second order on problems with a time-varying load; ``"exact"`` uses
        the model's ``load_rate``; ``"auto"`` (default) uses the exact rate
        when the model provides one.
    """

    name = "hfdi"
    order = 3

    def __init__(self, load_rate: str = "auto"):
        if load_rate not in ("auto", "exact", "difference"):
            raise ValueError(f"HFDI load_rate must be 'auto', 'exact' or 'difference', got {load_rate!r}")
        self.load_rate = load_rate

    def stage(self, ev, start, t_end, index, done):
        exact = self.load_rate == "exact" or (self.load_rate == "auto" and ev.has_load_rate)
        return _HFDIStage(ev, start, t_end, exact)

    def __repr__(self):
        return f"HFDI(load_rate={self.load_rate!r})"


SCHEMES = {"newmark": Newmark, "bathe": Bathe, "hfdi": HFDI}


def get_scheme(scheme) -> Scheme:
    """A scheme object from a name (``"newmark"``, ``"bathe"``, ``"hfdi"``) or an object."""
    if isinstance(scheme, Scheme):
        return scheme
    if isinstance(scheme, str) and scheme.lower() in SCHEMES:
        return SCHEMES[scheme.lower()]()
    raise ValueError(f"scheme must be one of {sorted(SCHEMES)} or a hfdi.Scheme, got {scheme!r}")
