"""The records of an integrator's run (:mod:`hfdi.core.state`), made from its
model, scheme and controller: what the stepping code reads and writes."""
from __future__ import annotations

import functools
import math

import numpy as np

from .controller import ErrorControl, core_kind
from .core.state import CONFIG, CUSTOM, DATA, MAX_STAGES, VECTORS
from .evaluation import DENSE_BELOW
from .linsolve.dense import work_ints
from .linsolve.sparse import General
from .stepping.global_error import PROPAGATOR_STAGES

__all__ = ["config", "data", "vectors", "row_arrays"]


def config(ev, controller, scheme, *, exact_rate, derived_rate, tol, floor, max_iterations,
           estimated, energy_limit, max_steps, t_bound, global_error=True):
    """:data:`CONFIG` of a run of the model ``ev`` (an Evaluator)."""
    settings = controller.settings() if core_kind(controller) != CUSTOM else \
        {"controller": CUSTOM}
    # the scheme's error constant of v holds with the model's p' (or HFDI's
    # derived one, O(h²)); the part the paper's quotient adds (O(h³), zero for
    # a load linear between its breakpoints) the estimate takes on its own
    # (stepping.attempt._load_rate_error)
    values = dict(
        n=ev.n, stages=scheme.n_stages, order=scheme.order,
        velocity_gain=scheme.velocity_gain, keeps_force=scheme.keeps_force,
        velocity_defect=scheme.velocity_defect, velocity_order=scheme.order,
        lagged_acceleration=scheme.lagged_acceleration,
        acceleration_lag=scheme.acceleration_lag,
        m_kind=ev.mass_kind, c_kind=ev.damping_kind, sparse=ev.n >= DENSE_BELOW,
        exact_rate=exact_rate, derived_rate=derived_rate, tol=tol, floor=floor,
        max_iterations=max_iterations,
        estimated=estimated, energy_limit=math.inf if energy_limit is None else energy_limit,
        max_steps=max_steps, t_bound=math.inf if t_bound is None else t_bound,
        global_error=global_error,
        mass_floor=ev.mass_floor(), damping_rate=ev.damping_rate())
    values.update(settings)         # ErrorControl(order=p) overrides the scheme's order
    return CONFIG.new(**values)


def _parts(matrix):
    """A mass or damping matrix as (diagonal, full) of :data:`DATA`."""
    empty_vector, empty_matrix = np.zeros(0), np.zeros((0, 0))
    if matrix is None:
        return empty_vector, empty_matrix
    if isinstance(matrix, np.ndarray) and matrix.ndim == 1:
        return np.ascontiguousarray(matrix, dtype=float), empty_matrix
    if isinstance(matrix, np.ndarray):
        return empty_vector, np.ascontiguousarray(matrix, dtype=float)
    return empty_vector, matrix                 # sparse: Python only


def data(ev, controller, scheme, breakpoints):
    """:data:`DATA` of a run: M and C, the error control's tolerances, the
    breakpoints and the scheme's parameters (the model's kernel data is set
    when the run goes compiled)."""
    n = ev.n
    Md, Mf = _parts(ev.mass)
    Cd, Cf = _parts(ev.damping)
    error = getattr(controller, "error", controller)
    rtol, atol, first_atol = np.zeros(2 * n), np.zeros(2 * n), np.zeros(2 * n)
    if isinstance(error, ErrorControl):
        rtol[:] = error.rtol
        atol[:] = error.atol
        first_atol[:] = error.first_atol(n)
    empty = np.zeros(0)
    return DATA.new(Md=Md, Mf=Mf, Cd=Cd, Cf=Cf, params=empty, load_params=empty, held=empty,
                    rtol=rtol, atol=atol, first_atol=first_atol,
                    breakpoints=np.ascontiguousarray(breakpoints, dtype=float),
                    scheme_params=np.ascontiguousarray(scheme.params(), dtype=float))


def vectors(ev, rows):
    """``(VECTORS, state_block)``: the work arrays of the stepping code, with room
    for ``rows`` rows; ``u, v, a, f, p`` are the rows of ``state_block`` (5, N),
    whose address a native host reads the state at (:mod:`hfdi.compiled.native`).

    The arrays of one shape are the rows of one workspace, laid out once per
    N (:func:`_layout`): a run's fixed cost was 86 allocations here."""
    n = ev.n
    shapes, fields = _layout(n)
    spaces = [np.zeros(shape, kind) for kind, shape in shapes]
    values = {name: spaces[space][row] for name, space, row in fields}
    values["ints"][:] = values["b_ints"][:] = work_ints()
    values["sparse"] = np.zeros(0) if n < DENSE_BELOW else General(ev.bands)
    values.update(row_arrays(n, rows))
    return VECTORS.python._make(map(values.__getitem__, VECTORS.names)), spaces[0][:5]


@functools.lru_cache(maxsize=16)
def _layout(n):
    """The workspaces of :func:`vectors`, ``(dtype, (rows, *shape))`` each, and
    where each work array lies, ``(name, workspace, row)``; the state
    block's five vectors are the first rows of the first."""
    dense = n < DENSE_BELOW
    m = n if dense else 0
    kinds = {name: (np.float64, (n,)) for name in ("u", "v", "a", "f", "p")}
    for name, kind in VECTORS.fields:
        if name.startswith("row_") or name == "sparse" or name in kinds:
            continue
        if name in ("error", "ratio", "global_error", "g_z"):
            kinds[name] = (np.float64, (2 * n,))
        elif name == "g_stages":
            kinds[name] = (np.float64, (PROPAGATOR_STAGES, 2 * n))
        elif name in ("pivots", "b_pivots", "g_pivots", "mass_pivots"):
            kinds[name] = (np.int32, (m,))
        elif name in ("ints", "b_ints"):
            kinds[name] = (np.int32, work_ints().shape)
        elif name == "stage_iterations":
            kinds[name] = (np.int64, (MAX_STAGES,))
        elif kind == "matrix":
            kinds[name] = (np.float64, (m, m))
        else:
            kinds[name] = (np.float64, (n,))
    spaces, fields = {}, []
    for name, kind in kinds.items():
        rows = spaces.setdefault(kind, [])
        fields.append((name, list(spaces).index(kind), len(rows)))
        rows.append(name)
    shapes = tuple((dtype, (len(rows), *shape)) for (dtype, shape), rows in spaces.items())
    return shapes, tuple(fields)


def row_arrays(n, rows):
    """The ``row_*`` arrays of :data:`VECTORS` with room for ``rows`` rows."""
    return dict(row_t=np.zeros(rows), row_h=np.zeros(rows),
                row_iterations=np.zeros(rows, np.int64), row_increment=np.zeros(rows),
                row_energy=np.zeros(rows), row_work=np.zeros(rows),
                row_u=np.zeros((rows, n)), row_v=np.zeros((rows, n)),
                row_a=np.zeros((rows, n)), row_global=np.zeros((rows, 2 * n)))
