"""The core's records (hfdi.core.state) around integrator states, so that
tests call the core's functions (predictor, error estimate) on the states a
run produced, as plain Python."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def records(current, previous=None, new=None):
    """``(run, vec)`` for the step from ``current`` (with the history
    ``previous`` or none) to ``new``: the fields the predictor and the error
    estimate read, plus their work arrays."""
    n = current.u.shape[0]
    run = SimpleNamespace(t=current.t, has_previous=previous is not None,
                          t_previous=previous.t if previous is not None else current.t)
    vec = SimpleNamespace(u=current.u, v=current.v, a=current.a,
                          error=np.zeros(2 * n),
                          **{name: np.zeros(n) for name in ("tmp", "work", "rhs", "residual",
                                                            "kv", "vd")})
    if previous is not None:
        vec.u_previous, vec.v_previous, vec.a_previous = previous.u, previous.v, previous.a
    if new is not None:
        vec.u_new, vec.v_new = new.u, new.v
    return run, vec


def predict(current, previous, s):
    """The predictor (Eqs. 36–37) ``s`` after ``current``."""
    from hfdi.core.estimate import predict as core_predict
    run, vec = records(current, previous)
    out = np.empty_like(current.u)
    core_predict(run, vec, s, out)
    return out


def local_error(current, previous, new, h, order, acceleration=None, defect=0.0):
    """The error estimate of the step from ``current`` to ``new`` (2N: u, v),
    with the states' accelerations or ``acceleration(state)``, and ``defect``
    the scheme's ``CONFIG.velocity_defect``."""
    from hfdi.core.estimate import local_error as core_local_error
    run, vec = records(current, previous, new)
    accelerate = acceleration or (lambda state: state.a)
    core_local_error(run, vec, h, order, defect, accelerate(current),
                     accelerate(previous) if previous is not None else current.a)
    return vec.error.copy()
