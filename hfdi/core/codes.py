"""Codes the core returns instead of raising: why an attempt failed, why a
run stopped, why a call of the loop returned. The messages are made from them
once, in Python (:mod:`hfdi.messages`)."""
from __future__ import annotations

# -- the outcome of an attempt (RUN.a_outcome) ------------------------------------------
OK = 0
RESIDUAL_NOT_FINITE = 1
TANGENT_SINGULAR = 2
CORRECTION_NOT_FINITE = 3
NO_CONVERGENCE = 4
END_NOT_FINITE = 5
FORCE_NOT_FINITE = 6
STIFFNESS_NOT_FINITE = 7
DERIVATIVE_NOT_FINITE = 8
STEP_MATRIX_SINGULAR = 9
LOAD_NOT_FINITE = 10
LOAD_RATE_NOT_FINITE = 11
# a kernel's value of another shape than (N,) or (N, N): a mistake in the model
# that no step cures; the run stops with MODEL_ERROR
FORCE_SHAPE = 20
STIFFNESS_SHAPE = 21
DERIVATIVE_SHAPE = 22
LOAD_SHAPE = 23
LOAD_RATE_SHAPE = 24

#: Outcomes that are a model's value of a wrong shape.
SHAPE_FAULTS = (FORCE_SHAPE, STIFFNESS_SHAPE, DERIVATIVE_SHAPE, LOAD_SHAPE, LOAD_RATE_SHAPE)

# -- how a run ended (RUN.status; hfdi.Status names them) --------------------------------
SUCCESS = 0
RUNNING = 1
STEP_BELOW_MINIMUM = -1
HALVINGS_EXHAUSTED = -2
MAX_STEPS = -3
NEWTON_FAILED = -4
ENERGY_GROWTH = -5
FIRST_STEP_FAILED = -6
MODEL_ERROR = -7
OVERFLOW = -8
TOLERANCE_NOT_MET = -9         # integrate(error="global") missed its tolerance

# -- which guard stopped a run (RUN.stop), for its message ---------------------------------
STOP_NONE = 0
STOP_BELOW_RESOLUTION = 1       # a step below the spacing of floating-point times
STOP_MIN_STEP = 2               # the step proposed after a rejection is below min_step
STOP_HALVINGS = 3               # max_halvings rejections in a row
STOP_FIXED_FAILED = 4           # the fixed step's corrector failed
STOP_FIRST_STEP = 5             # no first step found
STOP_MAX_STEPS = 6
STOP_SHORT_NOT_FINITE = 7       # a short step's state is not finite
STOP_SHORT_FAILED = 8           # a short step past a stiff component failed
STOP_ENERGY = 9                 # energy_limit
STOP_OVERFLOW = 10              # a step's energy balance beyond floating point
STOP_POTENTIAL_LOST = 11        # V NaN where it was known at the start
STOP_MODEL_SHAPE = 12           # a model's value of a wrong shape (RUN.a_outcome says which)
STOP_MODEL_FAULT = 13           # the model failed where no retry helps (RUN.a_outcome)

# -- why a call of the loop returned ------------------------------------------------
REACHED = 0                     # t_stop reached (or the run finished at t_bound)
STOPPED = 1                     # the run failed (RUN.status < 0)
ROWS_FULL = 2                   # the row buffer is full: call again
