"""Small test problems shared by the tests."""
from pathlib import Path

import numpy as np
import pytest

import hfdi


def schemes_quick(*quick, among=None):
    """Parameters over the schemes ``among`` (default every registered one)
    with all but the ``quick`` ones in the slow tier: the quick tier keeps a
    representative of each kind of stage, ``make test`` runs them all."""
    return [pytest.param(s, marks=() if s in quick else pytest.mark.slow)
            for s in (among if among is not None else hfdi.SCHEMES)]


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


def pleiades(python=False):
    """The Pleiades problem (Hairer, Nørsett & Wanner, *Solving ODEs I*, II.10):
    seven bodies of masses 1 … 7 in a plane under gravity (G = 1) on
    [0, 3], with close encounters. ``u = (x1, y1, …, x7, y7)``,
    ``V = −Σ_{i<j} m_i m_j / r_ij``: an :class:`~hfdi.models.symbolic.EnergyModel`
    (compiled), or with ``python=True`` a :class:`hfdi.System` of hand-written
    numpy functions (every pair at once, no loop over bodies; the Python path)."""
    masses = np.arange(1.0, 8.0)
    x0 = np.column_stack([[3, 3, -1, -3, 2, -2, 2], [3, -3, 2, 0, 0, -4, 4]]).ravel()
    v0 = np.column_stack([[0, 0, 0, 0, 0, 1.75, -1.5], [0, 0, 0, -1.25, 1, 0, 0]]).ravel()
    start = {"initial_displacement": x0.astype(float), "initial_velocity": v0.astype(float),
             "name": "pleiades"}
    if not python:
        import sympy
        from hfdi.models.symbolic import EnergyModel
        xy = sympy.symbols("x1:8 y1:8")
        x, y = xy[:7], xy[7:]
        V = -sum(masses[a] * masses[b] / sympy.sqrt((x[b] - x[a]) ** 2 + (y[b] - y[a]) ** 2)
                 for a in range(7) for b in range(a + 1, 7))
        coordinates = [c for pair in zip(x, y) for c in pair]
        return EnergyModel(coordinates, V, mass=np.repeat(masses, 2), **start)
    i, j = np.triu_indices(7, 1)
    mm = masses[i] * masses[j]
    eye = np.eye(2)

    def pairs(u):
        x = u.reshape(7, 2)
        d = x[j] - x[i]                                   # (21, 2)
        r2 = np.einsum("pk,pk->p", d, d)
        return d, r2

    def assemble(blocks):
        """(21, 2, 2) pair blocks H of V_ij(x_j − x_i) into the (14, 14) matrix."""
        K = np.zeros((7, 2, 7, 2))
        np.add.at(K, (i, slice(None), i), blocks.transpose(0, 2, 1))
        np.add.at(K, (j, slice(None), j), blocks.transpose(0, 2, 1))
        np.add.at(K, (i, slice(None), j), -blocks.transpose(0, 2, 1))
        np.add.at(K, (j, slice(None), i), -blocks.transpose(0, 2, 1))
        return K.reshape(14, 14)

    def force(u):
        d, r2 = pairs(u)
        g = (mm / r2 ** 1.5)[:, None] * d                 # ∂V_ij/∂x_j
        f = np.zeros((7, 2))
        np.add.at(f, j, g)
        np.add.at(f, i, -g)
        return f.ravel()

    def stiffness(u):
        d, r2 = pairs(u)
        H = (mm / r2 ** 1.5)[:, None, None] * eye - \
            (3.0 * mm / r2 ** 2.5)[:, None, None] * np.einsum("pk,pl->pkl", d, d)
        return assemble(H)

    def stiffness_derivative(u, w):
        d, r2 = pairs(u)
        dw = w.reshape(7, 2)[j] - w.reshape(7, 2)[i]
        s = np.einsum("pk,pk->p", d, dw)
        H = (-3.0 * mm * s / r2 ** 2.5)[:, None, None] * eye \
            - (3.0 * mm / r2 ** 2.5)[:, None, None] * (np.einsum("pk,pl->pkl", dw, d)
                                                       + np.einsum("pk,pl->pkl", d, dw)) \
            + (15.0 * mm * s / r2 ** 3.5)[:, None, None] * np.einsum("pk,pl->pkl", d, d)
        return assemble(H)

    def energy(u):
        _, r2 = pairs(u)
        return float(-np.sum(mm / np.sqrt(r2)))

    return hfdi.System(mass=np.repeat(masses, 2), internal_force=force, stiffness=stiffness,
                       stiffness_derivative=stiffness_derivative, potential_energy=energy,
                       **start)


def dumbbell_states(rng, n):
    """``n`` random dumbbell configurations ``(n, 4)``: the first particle
    anywhere in [-5, 5]², the bond of length 0.8–1.3 in any direction (the
    repulsive wall and the attractive tail of the bond potential, Eq. 44)."""
    x1 = rng.uniform(-5, 5, (n, 2))
    angle = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(0.8, 1.3, n)
    return np.column_stack([x1, x1 + r[:, None] * np.column_stack([np.cos(angle),
                                                                  np.sin(angle)])])


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


def run_in_ecos(fmu_path, t_end, reads, cwd):
    """Run the FMU in Ecos (``ecospy``, a C++ co-simulation engine with FMI 2.0
    and 3.0 imports) in steps of 0.01 to ``t_end``, in a subprocess (so that a
    crash of the host shows as such): ``(time reached, values)``, the values of
    ``reads``, ``(kind, name)`` pairs with kind ``"real"`` or ``"integer"``.
    Skips the test where Ecos (or Debian's libtbb12) is missing."""
    import subprocess
    import sys
    import textwrap
    try:
        import ecospy  # noqa: F401
    except (ImportError, OSError) as exc:
        pytest.skip(f"Ecos is not available here: {exc}")
    values = ", ".join(f"repr(sim.get_{kind}('a::{name}'))" for kind, name in reads)
    script = textwrap.dedent(f"""
        from ecospy import EcosSimulation, EcosSimulationStructure
        structure = EcosSimulationStructure()
        structure.add_model("a", {str(fmu_path)!r})
        sim = EcosSimulation(structure=structure, step_size=0.01)
        sim.init()
        sim.step_until({float(t_end)!r})
        print(repr(sim.get_time()), {values})
        sim.terminate()
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=600, cwd=cwd)
    assert done.returncode == 0, done.stderr[-2000:]
    t, *got = map(float, done.stdout.split()[-1 - len(reads):])
    return t, got
