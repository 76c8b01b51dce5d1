"""Validation of the hfdi integrators: the paper's tables and figures, reference
solutions and error norms. Uses only the public API of :mod:`hfdi`."""
