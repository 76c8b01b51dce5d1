"""HFDI: an adaptive predictor–corrector time integrator for ``M u'' + C u' + f(u) = p(t)``.

Implements the Newmark (average acceleration), Bathe (two sub-steps) and HFDI
schemes with the 4th-order extrapolation predictor, the Newton corrector and
the iteration-count step-size rule of "A predictor–corrector time integration
algorithm for dynamic analysis of nonlinear systems" (2020).
"""
from . import models, spectral
from .controller import (DEFAULT_RTOL, Combined, Controller, ErrorControl, FixedStep,
                         IterationCount, IterationCountController)
from .dense import Solution
from .evaluation import ModelError, State
from .integrator import Integrator, IntegratorState, Result, Statistics, Status, integrate
from .schemes import HFDI, SCHEMES, Bathe, Newmark, Scheme, get_scheme
from .system import (DerivativeCheck, HeldLoad, LinearSystem, SecondOrderSystem, System,
                     check_derivatives)

__version__ = "0.1.0"

__all__ = [
    "integrate", "Integrator", "IntegratorState", "Result", "Statistics", "Status", "State",
    "Scheme", "Newmark", "Bathe", "HFDI", "SCHEMES", "get_scheme",
    "Controller", "ErrorControl", "IterationCount", "Combined", "FixedStep",
    "IterationCountController", "DEFAULT_RTOL", "Solution",
    "SecondOrderSystem", "System", "LinearSystem", "HeldLoad", "check_derivatives", "DerivativeCheck",
    "ModelError", "models", "spectral",
]
