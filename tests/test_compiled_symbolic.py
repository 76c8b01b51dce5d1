"""Compiled kernels generated from an EnergyModel's sympy expressions
(hfdi.compiled.symbolic): against the model's Python f, K, T and V, the same
runs on both paths, parameters, the disk cache, and the fallback when an
expression has no compiled form."""
from pathlib import Path

import numpy as np
import pytest
import sympy

import hfdi
from hfdi.compiled import CompiledKernels, kernels_of
from hfdi.models import EnergyModel, elastic_pendulum, spring_chain

numba = pytest.importorskip("numba")

# every model's kernels are generated and compiled once per session (about a
# second each): not in the quick loop
pytestmark = pytest.mark.slow


def _dense(a):
    return a.toarray() if hasattr(a, "toarray") else np.asarray(a)


def _relative(a, b):
    scale = np.abs(b).max()
    return float(np.abs(a - b).max() / scale) if scale else float(np.abs(a - b).max())


def _assert_kernels_match(kernels, p, model, u, w, rtol):
    """The kernels (data ``p``) against the model's Python methods at ``u``, ``T[w]``."""
    assert _relative(kernels.force(u, p), model.internal_force(u)) < rtol
    assert _relative(kernels.stiffness(u, p), model.stiffness(u)) < rtol
    assert _relative(kernels.stiffness_derivative(u, w, p),
                     model.stiffness_derivative(u, w)) < rtol
    assert kernels.potential_energy(u, p) == pytest.approx(model.potential_energy(u), rel=rtol)


def _models():
    """A bar on a hinge with a transcendental energy and dense mass and damping,
    beside the two ready-made models (the chain sparse in the Python path)."""
    x, y = sympy.symbols("x y")
    k, g, c = sympy.symbols("k g c", positive=True)
    energy = k * (sympy.sqrt(x ** 2 + y ** 2) - 1) ** 2 / 2 + g * y + c * sympy.cos(x) ** 3
    bar = EnergyModel((x, y), energy, [[2.0, 0.3], [0.3, 1.5]],
                      parameters={k: 40.0, g: 9.81, c: 0.7},
                      damping=[[0.2, -0.05], [-0.05, 0.1]],
                      load=lambda t: np.array([np.sin(2.0 * t), 0.0]),
                      initial_displacement=[0.4, -0.9], name="bar")
    return {"pendulum": elastic_pendulum(), "chain": spring_chain(n_masses=6), "bar": bar}


MODELS = _models()


@pytest.mark.parametrize("name", list(MODELS))
def test_generated_kernels_reproduce_the_model(name):
    model = MODELS[name]
    kernels, why = kernels_of(model)
    assert isinstance(kernels, CompiledKernels), why
    rng = np.random.default_rng(11)
    for _ in range(5):
        u = model.initial_displacement + 0.2 * rng.standard_normal(model.n_dof)
        w = rng.standard_normal(model.n_dof)
        p = kernels.params
        assert _relative(kernels.force(u, p), model.internal_force(u)) < 1e-14
        assert _relative(kernels.stiffness(u, p), _dense(model.stiffness(u))) < 1e-14
        assert _relative(kernels.stiffness_derivative(u, w, p),
                         _dense(model.stiffness_derivative(u, w))) < 1e-14
        V = model.potential_energy(u)
        assert abs(kernels.potential_energy(u, p) - V) <= 1e-14 * max(abs(V), 1.0)


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
@pytest.mark.parametrize("name", list(MODELS))
def test_both_paths_take_the_same_run(name, scheme):
    model = MODELS[name]
    if name == "bar":               # a Python load: the steps need p(t) in the loop
        with pytest.raises(hfdi.compiled.CompiledUnavailable, match="no compiled load"):
            hfdi.Integrator(model, scheme, rtol=1e-6, compiled=True)
        return
    # Eq. 38 as the corrector's test: a run's steps then follow the kernels
    # alone. With the estimated-error test the step sizes of runs that start
    # at rest also follow err where it is 1e-5 … 1e-3 of the tolerance, the
    # level at which the two paths' rounding differs (the chain's Python
    # path is sparse), and the runs part after a few steps
    # (tests/test_one_implementation.py holds the speeds to each other there).
    runs = [hfdi.integrate(model, scheme, 1.5, rtol=1e-6, compiled=c, newton_test="correction")
            for c in (False, True)]
    python, compiled = runs
    assert python.success and compiled.success and python.stats.steps > 20
    for counter in ("steps", "rejected", "newton_iterations", "nfev", "njev", "ntev"):
        assert getattr(compiled.stats, counter) == getattr(python.stats, counter), counter
    # the generated code and lambdify's round some operations differently
    # (powers, sums in another order): f differs in the last bit, and under
    # error control the step sizes carry that from step to step (~1e-6
    # relative); the end states, on t_end for both, agree far closer
    np.testing.assert_allclose(compiled.t, python.t, rtol=1e-5, atol=0)
    assert _relative(compiled.u[-1], python.u[-1]) < 1e-10


def test_kernels_read_the_parameters_of_the_model():
    stiff = elastic_pendulum().with_parameters(k=300.0)
    kernels, _ = kernels_of(stiff)
    u = np.array([0.3, -1.2])
    np.testing.assert_allclose(kernels.force(u, kernels.params), stiff.internal_force(u),
                               rtol=1e-14)
    assert not np.allclose(stiff.internal_force(u), elastic_pendulum().internal_force(u))


def test_generated_source_is_cached_by_its_text(tmp_path, monkeypatch):
    from hfdi.compiled import symbolic
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(symbolic, "_IMPORTED", {})
    model = elastic_pendulum()
    first = symbolic.energy_model_kernels(model)
    files = sorted((tmp_path / "kernels").glob("*.py"))
    assert len(files) == 1 and files[0].read_text() == symbolic.kernel_source(model)
    again = symbolic.energy_model_kernels(elastic_pendulum(k=10.0))     # same expressions
    assert again.force is first.force
    assert sorted((tmp_path / "kernels").glob("*.py")) == files


def test_kernels_of_a_copy_under_another_name_import_that_copy(tmp_path):
    """An FMU imports its bundled hfdi under another name, in hosts that may
    have no ``hfdi``: the generated kernels must import their signatures from
    the copy that generated them, never from a package named ``hfdi``."""
    import os
    import shutil
    import subprocess
    import sys
    copy = tmp_path / "bundle"
    shutil.copytree(os.path.dirname(hfdi.__file__), copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
    script = f"""
import importlib.util, sys
sys.modules["hfdi"] = None          # import hfdi fails from here on
spec = importlib.util.spec_from_file_location(
    "other_name", {str(copy / "__init__.py")!r}, submodule_search_locations=[{str(copy)!r}])
package = importlib.util.module_from_spec(spec)
sys.modules["other_name"] = package
spec.loader.exec_module(package)
from other_name.compiled.symbolic import energy_model_kernels
kernels = energy_model_kernels(package.models.spring_chain(3))
print(type(kernels.force).__name__, kernels.force.__module__)
"""
    env = dict(os.environ, HFDI_CACHE_DIR=str(tmp_path / "cache"))
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    kind, module = run.stdout.split()
    assert kind == "CPUDispatcher" and module.startswith("hfdi_energy_kernels_")
    source = next((tmp_path / "cache" / "kernels").glob("*.py")).read_text()
    assert "from other_name.compiled.signatures import" in source


def test_an_expression_without_a_compiled_form_is_refused_when_printed():
    from hfdi.compiled.symbolic import KernelSourceError, kernel_source
    x = sympy.Symbol("x")
    model = EnergyModel((x,), sympy.besselj(0, x) + x ** 2, [1.0], initial_displacement=[0.5])
    with pytest.raises(KernelSourceError, match="besselj"):
        kernel_source(model)


def test_a_model_whose_kernels_cannot_be_made_runs_on_the_python_path(monkeypatch):
    from hfdi.compiled import symbolic

    def refuse(model):
        raise symbolic.KernelSourceError("Unsupported by the printer: besselj")

    monkeypatch.setattr(symbolic, "kernel_source", refuse)
    model = elastic_pendulum()
    kernels, why = kernels_of(model)
    assert kernels is None and "besselj" in why
    assert not hfdi.Integrator(model, "hfdi", step=0.01, compiled=None).compiled
    with pytest.raises(hfdi.compiled.CompiledUnavailable, match="besselj"):
        hfdi.Integrator(model, "hfdi", step=0.01, compiled=True)


@pytest.mark.parametrize("scheme", ["newmark", "hfdi"])
def test_a_parameter_changed_mid_run_is_followed_by_the_compiled_path(scheme):
    """set_parameters between two advances: the compiled kernels read the new
    value as the Python model does (the same run on both paths), and a model
    without load runs in the compiled driver."""
    runs = []
    for compiled in (False, True):
        model = spring_chain(4)
        itg = hfdi.Integrator(model, scheme, rtol=1e-6, compiled=compiled)
        assert itg.compiled == compiled
        itg.advance(1.0)
        model.set_parameters(k=3.0 * model.parameters()["k"])
        itg.advance(2.0)
        runs.append(itg)
    python, compiled = runs
    assert compiled.statistics.steps == python.statistics.steps
    assert compiled.statistics.newton_iterations == python.statistics.newton_iterations
    # the rounding of generated code and lambdify differ (see above)
    assert _relative(compiled.state.u, python.state.u) < 1e-8
    unchanged = hfdi.Integrator(spring_chain(4), scheme, rtol=1e-6)
    unchanged.advance(2.0)
    assert np.abs(unchanged.state.u - compiled.state.u).max() > 1e-3


def _loaded_chain():
    x = sympy.symbols("x0:3")
    k, A, w, t = sympy.symbols("k A w t")
    energy = sum(k * (x[i] - (x[i - 1] if i else 0)) ** 2 / 2
                 + 40.0 * (x[i] - (x[i - 1] if i else 0)) ** 4 for i in range(3))
    load = [0, A * sympy.sin(w * t), A * sympy.exp(-t) * sympy.cos(2 * w * t)]
    return EnergyModel(x, energy, [1.0, 2.0, 1.5], parameters={k: 50.0, A: 3.0, w: 7.0},
                       time=t, load=load, initial_displacement=[0.1, 0.0, -0.1])


def test_a_load_of_expressions_has_its_exact_rate_and_compiled_kernels():
    model = _loaded_chain()
    times = np.linspace(0.0, 2.0, 9)
    for t in times:
        p = model.load(t)
        expected = [0.0, 3.0 * np.sin(7.0 * t), 3.0 * np.exp(-t) * np.cos(14.0 * t)]
        np.testing.assert_allclose(p, expected, rtol=1e-14, atol=1e-14)
        step = 1e-6
        difference = (model.load(t + step) - model.load(t - step)) / (2 * step)
        np.testing.assert_allclose(model.load_rate(t), difference, rtol=1e-7, atol=1e-7)
    kernels, why = kernels_of(model)
    assert kernels is not None, why
    for t in times:
        np.testing.assert_allclose(kernels.load(t, kernels.load_params), model.load(t),
                                   rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(kernels.load_rate(t, kernels.load_params),
                                   model.load_rate(t), rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("scheme", ["newmark", "bathe", "hfdi"])
def test_a_model_with_a_load_of_expressions_runs_whole_in_the_driver(scheme):
    """HFDI takes the exact (derived) rate on both paths; the same run, the
    same error against a tight reference of the Python path."""
    itg = hfdi.Integrator(_loaded_chain(), scheme, rtol=1e-6)
    assert itg.compiled
    fixed = [hfdi.integrate(_loaded_chain(), scheme, 1.0, step=0.01, compiled=c)
             for c in (False, True)]
    assert fixed[0].stats.newton_iterations == fixed[1].stats.newton_iterations
    assert _relative(fixed[1].u, fixed[0].u) < 1e-12
    runs = [hfdi.integrate(_loaded_chain(), scheme, 1.0, rtol=1e-4, compiled=c)
            for c in (False, True)]
    # the reference compiled: 15,493 steps, 0.4 s (17 s on the Python path,
    # whose runs the fixed-step comparison above ties to the compiled ones)
    reference = hfdi.integrate(_loaded_chain(), "hfdi", 1.0, rtol=1e-10, compiled=True)
    assert reference.success
    errors = [_relative(r.u[-1], reference.u[-1]) for r in runs]
    assert runs[0].stats.steps == pytest.approx(runs[1].stats.steps, rel=0.01)
    assert errors[1] < 1e-3 and errors[1] == pytest.approx(errors[0], rel=0.05)


def test_a_load_of_expressions_follows_the_parameters_on_both_paths():
    ends = []
    for compiled in (False, True):
        model = _loaded_chain()
        itg = hfdi.Integrator(model, "hfdi", step=0.01, compiled=compiled)
        itg.advance(0.5)
        model.set_parameters(A=-9.0)
        itg.advance(1.0)
        # the kernels, checked again after the change, still agree
        assert itg.compiled == compiled
        ends.append(itg.state.u)
    assert _relative(ends[1], ends[0]) < 1e-12
    model = _loaded_chain()
    itg = hfdi.Integrator(model, "hfdi", step=0.01)
    itg.advance(1.0)
    assert np.abs(itg.state.u - ends[1]).max() > 1e-3


def test_a_load_of_expressions_is_checked():
    x, t, z = sympy.symbols("x t z")
    with pytest.raises(ValueError, match="1 sympy expressions"):
        EnergyModel([x], x ** 2 / 2, [1.0], time=t, load=[sympy.sin(t), t])
    with pytest.raises(ValueError, match="unknown symbols z"):
        EnergyModel([x], x ** 2 / 2, [1.0], time=t, load=[z * t])
    with pytest.raises(ValueError, match="derived"):
        EnergyModel([x], x ** 2 / 2, [1.0], time=t, load=[sympy.sin(t)],
                    load_rate=lambda s: np.array([np.cos(s)]))
    with pytest.raises(ValueError, match="load"):
        EnergyModel([x], x ** 2 / 2, [1.0], time=t, load="sin(t)")


@pytest.mark.parametrize("case", ["floor power", "ceiling power", "Max of integers",
                                  "beyond int64"])
def test_integer_valued_expressions_compute_in_floats_as_on_the_python_path(case):
    """numba's math.floor and math.ceil are int64, and so are max and powers of
    them: printed as such, floor(n)**(-2) was 0 and ceiling(n)**5 wrapped
    around, while lambdify's numpy code computes in floats; an integer
    constant beyond int64 could not be compiled at all."""
    x, y = sympy.symbols("x y")
    n = sympy.Symbol("n", positive=True)
    # (x⁴ + y⁴) times the factor: common-subexpression elimination makes the
    # factor a temporary of its own, an integer power of an int64
    term = (x ** 4 + y ** 4) * {"floor power": 1 / (4 * sympy.floor(n) ** 2),
                                "ceiling power": sympy.ceiling(n) ** 5 * sympy.Float(1e-30),
                                "Max of integers": sympy.Max(1, sympy.floor(n)) ** 3 * 1e-20,
                                "beyond int64": sympy.Integer(10) ** 20 * n}[case]
    model = EnergyModel([x, y], (x ** 2 + y ** 2) / 2 + (x - y) ** 3 / 3 + term, [1.0, 1.0],
                        parameters={n: 1.0}, initial_displacement=[0.5, -0.2])
    kernels, why = kernels_of(model)
    assert kernels is not None, why
    rng = np.random.default_rng(3)
    for value in (1.0, 2.5, 3.7e6):
        model.set_parameters(n=value)
        p = model.compiled_params()
        for _ in range(3):
            _assert_kernels_match(kernels, p, model, rng.uniform(-2.0, 2.0, 2),
                                  rng.standard_normal(2), 1e-13)


def test_max_min_and_abs_kernels_match_the_python_path_on_and_off_the_kinks():
    """DiracDelta (from the derivatives) counts as 0 and Heaviside(0) is 1/2 on
    both paths: the kernels and the Python methods agree everywhere, and so
    do the runs."""
    from test_symbolic_models import _contact_model
    model = _contact_model(initial_displacement=[0.0, 0.1], initial_velocity=[1.0, -0.5])
    kernels, why = kernels_of(model)
    assert kernels is not None, why
    p = kernels.params
    for u in ([0.2, 0.0], [0.5, 0.3], [-0.1, -0.4], [0.2, -0.3], [0.7, 0.0]):
        _assert_kernels_match(kernels, p, model, np.array(u), np.array([0.3, -1.1]), 1e-14)
    runs = [hfdi.integrate(model, "hfdi", 2.0, rtol=1e-6, compiled=c) for c in (False, True)]
    assert runs[0].success and runs[1].success
    # the kernels agree with the methods to rounding (1e-14), not bit for bit:
    # near a kink that can turn one step's verdict
    assert abs(runs[1].stats.steps - runs[0].stats.steps) <= 0.01 * runs[0].stats.steps
    assert _relative(runs[1].u[-1], runs[0].u[-1]) < 1e-8


def _planted_model():
    x, y = sympy.symbols("x y")
    return EnergyModel([x, y], (x ** 2 + y ** 2) / 2 + (x - y) ** 4 / 4 + x ** 3 / 11,
                       [1.0, 1.0], initial_displacement=[0.3, 0.0])


def test_bytecode_found_beside_the_generated_source_is_never_run(tmp_path, monkeypatch):
    """Python's import takes a __pycache__/*.pyc whose header matches the
    source file's mtime and size, without comparing its code with the text:
    the kernels run the text generated, whatever the directory holds."""
    import importlib.util
    import marshal
    import struct
    from hfdi.compiled import symbolic
    from hfdi.files import write_atomic
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(symbolic, "_IMPORTED", {})
    model = _planted_model()
    source = symbolic.kernel_source(model)
    digest = __import__("hashlib").sha256(source.encode()).hexdigest()[:24]
    path = tmp_path / "kernels" / f"hfdi_energy_kernels_{digest}.py"
    write_atomic(path, source)
    marker = tmp_path / "foreign code ran"
    foreign = (f"open({str(marker)!r}, 'w').close()\n"
               + source.replace("    return f\n", "    f[0] += 1.0\n    return f\n", 1))
    stat = path.stat()
    pyc = Path(importlib.util.cache_from_source(str(path)))
    pyc.parent.mkdir(parents=True, exist_ok=True)
    pyc.write_bytes(importlib.util.MAGIC_NUMBER + struct.pack(
        "<III", 0, int(stat.st_mtime) & 0xFFFFFFFF, stat.st_size & 0xFFFFFFFF)
        + marshal.dumps(compile(foreign, str(path), "exec")))
    kernels = symbolic.energy_model_kernels(model)
    assert not marker.exists()
    u = np.array([0.4, -0.1])
    assert _relative(kernels.force(u, kernels.params), model.internal_force(u)) < 1e-14


def test_numba_caches_the_generated_kernels_for_a_later_process(tmp_path):
    """The kernels are run from the generated text with the file's name, so
    that numba caches their machine code beside it: a second process loads
    all four kernels from that cache instead of compiling them."""
    import os
    import subprocess
    import sys
    script = """
import sympy
from hfdi.compiled.symbolic import energy_model_kernels
from hfdi.models import EnergyModel
x, y = sympy.symbols("x y")
k = energy_model_kernels(EnergyModel([x, y], (x**2 + y**2) / 2 + (x - y)**4 / 4 + x**3 / 13,
                                     [1.0, 1.0]))
print(sum(len(getattr(k, n).stats.cache_hits)
          for n in ("force", "stiffness", "stiffness_derivative", "potential_energy")))
"""
    env = dict(os.environ, HFDI_CACHE_DIR=str(tmp_path))
    hits = []
    for _ in range(2):
        run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                             env=env, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        hits.append(int(run.stdout.split()[-1]))
    assert hits == [0, 4]


def test_kernels_are_not_cached_where_the_cache_is_not_trusted(tmp_path, monkeypatch):
    """The library's cache unusable (a file where its directory goes): the
    generated kernels are compiled and run, but cached nowhere — not beside
    their source, not in numba's user-wide directory, which the library does
    not check."""
    from hfdi.compiled import symbolic
    monkeypatch.setenv("HFDI_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(symbolic, "_IMPORTED", {})
    (tmp_path / "numba").touch()
    model = _planted_model()
    kernels, why = kernels_of(model)
    assert not why and type(kernels.force._cache).__name__ == "NullCache"
    assert not (tmp_path / "kernels" / "__pycache__").exists()
    assert hfdi.Integrator(_planted_model(), "newmark", step=0.01).compiled


def test_a_function_numba_cannot_compile_leaves_the_model_without_kernels():
    """math.factorial has no numba form for a float: no kernels, not a fault."""
    from hfdi.compiled import _Fault
    x, n = sympy.symbols("x n")
    model = EnergyModel([x], x ** 2 / 2 + sympy.factorial(n) * x ** 4, [1.0],
                        parameters={n: 3.0}, initial_displacement=[0.3])
    kernels, why = kernels_of(model)
    assert kernels is None and "factorial" in why and not isinstance(why, _Fault)
