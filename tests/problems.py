"""Small test problems shared by the tests."""
from pathlib import Path

import numpy as np

import hfdi


def coupled_duffing(damping=0.05, load=None, load_rate=None, c=1.0):
    """Two masses, linear springs and a quartic coupling:
    ``V = ½ a u1² + ½ b u2² + ¼ c (u1 − u2)⁴``; smooth and nonlinear."""
    a, b = 1.0, 2.0

    def force(u):
        d = u[0] - u[1]
        return np.array([a * u[0] + c * d ** 3, b * u[1] - c * d ** 3])

    def stiffness(u):
        d2 = 3 * c * (u[0] - u[1]) ** 2
        return np.array([[a + d2, -d2], [-d2, b + d2]])

    def stiffness_derivative(u, w):
        s = 6 * c * (u[0] - u[1]) * (w[0] - w[1])
        return s * np.array([[1.0, -1.0], [-1.0, 1.0]])

    def energy(u):
        return 0.5 * a * u[0] ** 2 + 0.5 * b * u[1] ** 2 + 0.25 * c * (u[0] - u[1]) ** 4

    return hfdi.System(mass=[1.0, 2.0], internal_force=force, stiffness=stiffness,
                       stiffness_derivative=stiffness_derivative,
                       damping=None if damping is None else damping * np.eye(2),
                       load=load, load_rate=load_rate, potential_energy=energy,
                       initial_displacement=[1.0, 0.0], initial_velocity=[0.0, 0.5],
                       name="coupled_duffing")


def reference_solution(system, t_end, rtol=1e-13):
    """The end state from scipy's DOP853 on the first-order form, at tight tolerance."""
    from scipy.integrate import solve_ivp
    M = np.diag(system.mass) if np.ndim(system.mass) == 1 else np.asarray(system.mass)
    C = np.zeros_like(M) if system.damping is None else np.asarray(system.damping)
    n = system.n_dof

    def rhs(t, y):
        u, v = y[:n], y[n:]
        return np.concatenate([v, np.linalg.solve(M, system.load(t) - system.internal_force(u)
                                                  - C @ v)])

    sol = solve_ivp(rhs, (0.0, t_end),
                    np.concatenate([system.initial_displacement, system.initial_velocity]),
                    method="DOP853", rtol=rtol, atol=rtol)
    return sol.y[:n, -1], sol.y[n:, -1]


ROBUSTNESS_DOC = Path(__file__).resolve().parents[1] / "docs" / "robustness.md"


def write_doc_table(name, table, path=ROBUSTNESS_DOC):
    """Replace the generated table ``name`` of ``docs/robustness.md``, the text
    between its ``<!-- BEGIN name table -->`` and ``<!-- END name table -->``
    markers; returns the path."""
    text = path.read_text(encoding="utf-8")
    begin, end = f"<!-- BEGIN {name} table -->", f"<!-- END {name} table -->"
    head, rest = text.split(begin)
    _, tail = rest.split(end)
    path.write_text(f"{head}{begin}\n{table}\n{end}{tail}", encoding="utf-8")
    return path


def sigint_as_in_a_terminal():
    """``preexec_fn`` of a child process that a test interrupts with SIGINT.

    A command started in the background by a non-interactive shell inherits
    SIGINT ignored, and Python then installs no ``KeyboardInterrupt`` handler:
    run that way, the suite's interrupted children would finish instead. The
    child gets the default disposition, as under a terminal's Ctrl-C.
    """
    import signal
    signal.signal(signal.SIGINT, signal.SIG_DFL)
