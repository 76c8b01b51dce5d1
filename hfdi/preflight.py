"""What is checked before a run: the model at the initial state, its tangent
against differences of its force, its load rate against differences of its
load, and the first trial step."""
from __future__ import annotations

import functools
import math

import numpy as np

from .evaluation import ModelError, NonFiniteError, State, brief
from .schemes import HFDI
from .system import load_rate_error

__all__ = ["initial_state", "check_stiffness_of", "check_load_rate", "default_first_step"]

_EPS = float(np.finfo(float).eps)
_SQRT_EPS = math.sqrt(_EPS)


def initial_state(ev, scheme, t0, u0, v0, check_stiffness, floor, t_bound, breakpoints):
    """The initial :class:`State`, ``K(u0)``, ``T(u0)[v0]`` (HFDI only, else
    ``None``) and ``V(u0)``, every function the run will use checked once: a
    wrong shape, a NaN or an exception is a :class:`ModelError` naming it."""
    name = getattr(ev.system, "name", type(ev.system).__name__)
    where = f"at the initial state (t0 = {t0:g}, u0 = {brief(u0)}, v0 = {brief(v0)})"

    def call(function, fun, *args):
        try:
            return fun(*args)
        except ModelError as exc:
            raise ModelError(f"model {name!r}: {exc} {where}") from None
        except NonFiniteError as exc:
            raise ModelError(f"model {name!r}: {exc}, the initial state (t0 = {t0:g}); "
                             f"the run cannot start there") from None
        except NotImplementedError as exc:
            raise ModelError(f"model {name!r}: scheme {scheme.name!r} needs "
                             f"{function}, which raised NotImplementedError"
                             f"{': ' + str(exc) if str(exc) else ''}") from exc
        except Exception as exc:
            raise ModelError(f"model {name!r}: {function} raised {type(exc).__name__}: "
                             f"{exc} {where}") from exc

    f = call("internal_force", ev.force, u0)
    p = call("load", ev.load, t0)
    K = call("stiffness", ev.stiffness, u0)
    T = None
    if check_stiffness:
        check_stiffness_of(ev, u0, K, call, name, floor)
        if not np.any(u0):
            check_stiffness_off_rest(ev, u0, name, floor)
    if scheme.name == "hfdi" or isinstance(scheme, HFDI):
        T = call("stiffness_derivative", ev.stiffness_derivative, u0, v0)
        if scheme.load_rate == "exact" or (scheme.load_rate == "auto"
                                                 and ev.has_load_rate):
            call("load_rate", ev.load_rate, t0)
            if check_stiffness:
                check_load_rate(ev, call, name, t0, t_bound, breakpoints)
    potential = call("potential_energy", ev.potential_energy, u0)
    if math.isinf(potential):
        raise ModelError(f"model {name!r}: potential_energy is {potential} {where}; the "
                         f"energy balance (Eq. 40) cannot start there")
    a = ev.acceleration(t0, u0, v0, f, p)
    if not np.all(np.isfinite(a)):
        raise ModelError(f"model {name!r}: the initial acceleration "
                         f"M⁻¹(p − f − C v0) is not finite ({brief(a)}) {where}")
    return State(t0, u0.copy(), v0.copy(), a, f, p), K, T, potential


#: Where :func:`check_stiffness_off_rest` checks ``K`` again: this share of
#: ``u_scale`` away from a start at rest, along the fixed direction.
OFF_REST = 0.05


def check_stiffness_off_rest(ev, u0, name, floor):
    """``K`` against ``f`` once more, :data:`OFF_REST` of ``u_scale`` away from a
    start at rest: there the terms of ``f`` above the linear one vanish, and a
    ``K`` right at ``u0`` but wrong elsewhere (``f = u + u³`` with ``K = 1``)
    passed, and HFDI gave a wrong answer with ``SUCCESS``. A model that
    cannot be evaluated there is not checked there."""
    u = u0 + OFF_REST * floor * _direction(ev.n)
    where = f"at u = {brief(u)} ({OFF_REST:g} of u_scale = {floor:g} from the rest u0)"

    def call(function, fun, *args):
        try:
            return fun(*args)
        except Exception:
            raise _Unchecked from None

    try:
        K = call("stiffness", ev.stiffness, u)
        check_stiffness_of(ev, u, K, call, name, floor, where)
    except _Unchecked:
        pass


class _Unchecked(ModelError):
    """The model cannot be evaluated where an optional check would look."""


@functools.lru_cache(maxsize=16)
def _direction(n):
    w = np.sin(np.arange(1, n + 1) * 2.399963229728653)  # golden angle: no zero
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=16)
def _even_direction(n):
    """A second fixed direction, every entry of size 0.5 to 1.5 (signs alternating)."""
    k = np.arange(1, n + 1)
    w = (-1.0) ** k * (1.0 + 0.5 * np.sin(k * 2.399963229728653))
    w.flags.writeable = False
    return w


def check_stiffness_of(ev, u0, K, call, name, floor, where="at u0"):
    """``K(u0)`` against central differences of ``f`` along two directions
    (docs/user-models.md, "Writing your own model").

    First ``d_i = s·√ε·max(|u0_i|, 1e-3·U) w_i`` (``U = max(max|u0|,
    u_scale)``, ``w`` a fixed direction): each degree of freedom moved by
    its own size. Where those sizes differ, then ``d_i = s·√ε·m·w'_i``
    (``m`` the smallest of those sizes) with entries of ``w'`` of one size:
    moved by 1e-3 of the others, a degree of
    freedom at 0 hid a wrong column of ``K`` under the threshold (``K_01``
    left out of a 2-DOF chain started at ``u0 = (1, 0)`` passed, and HFDI
    erred by 1.85e-3 with SUCCESS at a fixed step, or stalled under error
    control). Each at scales ``s`` = 1, 1e2, 1e4, 1e6; the mismatches at
    ``d`` and ``2d`` are Richardson-combined, ``(8 m(d) − m(2d))/6``. Row
    ``i`` counts at a scale where the rounding of ``f`` is below 1e-4 of its
    terms ``Σ_j |K_ij d_j|``, and its error is the smallest over the scales
    that count; above 0.1 % of its terms it is refused. Beyond the first
    scale a failing evaluation only drops that scale.
    """
    size_u = max(float(np.abs(u0).max()), floor)
    own = np.maximum(np.abs(u0), 1e-3 * size_u)
    _check_stiffness_along(ev, u0, K, call, name, where, _SQRT_EPS * own * _direction(ev.n))
    if own.min() < own.max():
        # every degree of freedom by the smallest size: by the largest, a force
        # that varies on a length below it (a degree of freedom in nm beside
        # one in m) was refused though its K was right
        _check_stiffness_along(ev, u0, K, call, name, where,
                               _SQRT_EPS * own.min() * _even_direction(ev.n))


def _check_stiffness_along(ev, u0, K, call, name, where, base):
    """:func:`check_stiffness_of` along the step ``base`` (at scale 1)."""
    n = ev.n
    best = np.full(n, np.inf)
    best_scale = np.zeros(n)
    dense = type(K) is np.ndarray
    K_abs = np.abs(K) if dense else abs(K)
    for scale in (1.0, 1e2, 1e4, 1e6):
        steps, values = [], []
        try:
            for factor in (1.0, 2.0):
                d = (u0 + factor * scale * base) - u0        # the step as represented
                plus = call("internal_force", ev.force, u0 + d)
                minus = call("internal_force", ev.force, u0 - d)
                steps.append(d)
                values.append((plus, minus))
        except ModelError:
            if scale == 1.0:
                raise
            break
        (d1, d2), ((p1, q1), (p2, q2)) = steps, values
        if dense:
            Kd1, Kd2, terms = K @ d1, K @ d2, K_abs @ np.abs(d1)
        else:
            Kd1, Kd2 = np.asarray(K @ d1).ravel(), np.asarray(K @ d2).ravel()
            terms = np.asarray(K_abs @ np.abs(d1)).ravel()
        m1 = 0.5 * (p1 - q1) - Kd1
        m2 = 0.5 * (p2 - q2) - Kd2
        error = np.abs(8.0 * m1 - m2) / 6.0
        rounding = 16.0 * _EPS * (np.abs(p1) + np.abs(q1) + np.abs(p2) + np.abs(q2))
        counts = (terms > 0) & (rounding <= 1e-4 * terms)
        relative = np.full(n, np.inf)
        np.divide(error, terms, out=relative, where=counts)
        better = relative < best
        best[better], best_scale[better] = relative[better], scale
        if not ((terms > 0) & ~(best <= 1e-3)).any():
            break           # every row that can be judged has passed: no scale fails it
    judged = np.isfinite(best)
    if not judged.any():
        return
    worst = int(np.argmax(np.where(judged, best, -1.0)))
    if best[worst] > 1e-3:
        largest = float(np.abs(base).max()) * best_scale[worst]
        raise ModelError(
            f"model {name!r}: stiffness does not match internal_force {where}: in row "
            f"{worst}, K·d and the central differences of f (|d| ≤ {largest:.3g}, "
            f"Richardson-extrapolated; the best of the steps 1 … 1e6 times that) "
            f"differ by {best[worst]:.2%} of the size of the row's terms. K must be "
            f"∂f/∂u: HFDI uses it in its step equation, where a wrong K gives a wrong "
            f"answer (check the model with hfdi.check_derivatives; pass "
            f"check_stiffness=False only if f has a kink there)")


#: Where :func:`check_load_rate` checks ``p'`` inside the run's span besides
#: ``t0``: these shares of each of the first :data:`RATE_CHECK_INTERVALS`
#: intervals between the load's breakpoints (irrational, so as not to fall on
#: a round time). A rate wrong only away from the start (``p = t²`` with
#: ``p' = t``, both zero at ``t0 = 0``; a pulse that is over before the span's
#: middle) gave HFDI a wrong answer with SUCCESS, or stalled its steps.
RATE_CHECK_SHARES = (1.0 / math.e, 1.0 / math.sqrt(2.0))
RATE_CHECK_INTERVALS = 8
#: The relative mismatch of ``p'`` and the differences of ``p`` refused, as for ``K``.
RATE_MISMATCH = 1e-3


def check_load_rate(ev, call, name, t0, t_bound, breakpoints):
    """``p'(t0)`` against forward differences of ``p`` (:func:`load_rate_error`)
    at steps of ``10^-2 … 10^-13`` times the run's span (1 where it is not
    known) that end before the load's next breakpoint; where the run's end is
    known, also ``p'`` inside the span (:func:`interior_rate_mismatch`). A
    mismatch above 0.1 % is refused, as for ``K``."""
    scale = t_bound - t0 if t_bound is not None else 1.0
    # every breakpoint, the model's and the given ones, whether the mode
    # lands on them or not: a jump inside the differences hides a wrong rate
    points = breakpoints
    later = points[points > t0]
    horizon = float(later.min()) if later.size else math.inf
    mismatch = call("load", lambda: load_rate_error(ev.load, ev.load_rate, t0, scale,
                                                    horizon))
    at, steps = f"t0 = {t0:g}", f"the steps {scale * 1e-2:.3g} … {scale * 1e-13:.3g}"
    if not mismatch > RATE_MISMATCH and t_bound is not None and math.isfinite(scale) \
            and scale > 0:
        ends = np.unique(np.concatenate(([t0], points[(points > t0) & (points < t_bound)],
                                         [t_bound])))[:RATE_CHECK_INTERVALS + 1]
        inside = ((a + share * (b - a), a, b) for a, b in zip(ends[:-1], ends[1:])
                  for share in RATE_CHECK_SHARES)
        for t, a, b in inside:
            mismatch = interior_rate_mismatch(ev.load, ev.load_rate, t, a, b)
            if mismatch > RATE_MISMATCH:
                at, steps = f"t = {t:g}", "central differences"
                break
    if mismatch > RATE_MISMATCH:
        raise ModelError(
            f"model {name!r}: load_rate does not match load at {at}: p'(t) and "
            f"differences of p differ by {mismatch:.3g} of their size at the best of "
            f"{steps}. HFDI uses p' in its step equation, where a wrong rate gives a "
            f"wrong answer (check the model with hfdi.check_derivatives; "
            f"check_stiffness=False skips the checks of K and p')")


def interior_rate_mismatch(load, load_rate, t, a, b, accept=RATE_MISMATCH) -> float:
    """How far ``load_rate(t)`` is from central differences of ``load`` at a
    time ``t`` inside ``(a, b)``, an interval the load is smooth in: the
    relative distance of the vectors at the steps ``δ = (b − a)·10^-2 …
    10^-8 / √3`` (Richardson, ``(4 D(δ/2) − D(δ))/3``, error ``O(δ⁴)``) that
    are converged (within 1e-4 of their size of the next coarser step's) and
    whose rounding (of the whole vector ``p``, amplified by ``1/δ``) is below
    1e-4 of their size: the first such distance within ``accept`` (no finer
    step is taken), else the smallest. 0 where nothing can be judged: a load
    or rate that raises or is not finite there (a load defined up to a
    terminal event), a load that varies faster than every step, or rounding
    above it."""
    eps = np.finfo(float).eps
    best, coarser = math.inf, None
    try:
        rate = np.asarray(load_rate(t), dtype=float)
        if not np.all(np.isfinite(rate)):
            return 0.0
        for k in range(2, 9):
            # not a round fraction of the interval: a load periodic in a round
            # time (sin 2πt over a span of 1e7) would difference to zero
            delta = (b - a) * 10.0 ** -k / math.sqrt(3.0)
            if not (a < t - delta and t + delta < b and t - delta < t < t + delta):
                continue
            values = [np.asarray(load(t + s * delta), dtype=float)
                      for s in (-1.0, -0.5, 0.5, 1.0)]
            if not all(np.all(np.isfinite(v)) for v in values):
                return 0.0
            coarse = (values[3] - values[0]) / (2.0 * delta)
            fine = (values[2] - values[1]) / delta
            rounding = 16.0 * eps * max(float(np.abs(v).max()) for v in values) / delta
            difference = (4.0 * fine - coarse) / 3.0
            if coarser is not None:
                # converged against the differences' own size, not the rate's:
                # steps far longer than the load's period give differences
                # near zero that agree with each other and with nothing else
                settled = max(float(np.abs(coarser).max()), float(np.abs(difference).max()))
                size = max(float(np.abs(rate).max()), settled)
                if settled > 0.0 and rounding <= 1e-4 * settled and \
                        float(np.abs(coarser - difference).max()) <= 1e-4 * settled:
                    best = min(best, float(np.abs(rate - difference).max()) / size)
                    if best <= accept:
                        return best
            coarser = difference
    except Exception:       # noqa: BLE001 - not judged there; the run meets it if it gets there
        return 0.0
    return best if math.isfinite(best) else 0.0


def default_first_step(ev, K, t0, t_bound, min_step) -> float:
    """``1/ω`` with ``ω²`` bounded by Gershgorin's theorem on ``M⁻¹K(u0)``."""
    row_sums = np.asarray(abs(K).sum(axis=1)).ravel()
    m_diag = ev.mass_diagonal
    with np.errstate(divide="ignore", invalid="ignore"):
        omega2 = np.nanmax(np.where(m_diag > 0, row_sums / m_diag, 0.0))
    if omega2 > 0 and math.isfinite(omega2):
        h0 = 1.0 / math.sqrt(omega2)
    else:
        h0 = 1e-3 * (t_bound - t0 if t_bound is not None else 1.0)
    return max(h0, 10.0 * min_step)

