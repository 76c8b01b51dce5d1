"""The compiled path allocates, per step, only what the model's kernels allocate.

The loop's work arrays are made once per run (hfdi.run_records), not per
step: some forty allocations per step before, at about 50 ns each. numba's runtime counts every array it allocates
when ``NUMBA_NRT_STATS=1`` is set before numba is imported, hence a
subprocess. Over a run of ordinary steps, the allocations must be those of
the kernel calls that the evaluation counters report, each kernel at what one
call of it allocates measured alone (called from compiled code, as the
driver calls it), and a constant per call of the driver (its own work
arrays). The version before the work arrays fails by 20 to 60 allocations
per step.
"""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("numba")
#: one worker counts every case (one subprocess for all, --dist loadgroup)
pytestmark = pytest.mark.xdist_group("allocations")

ROOT = Path(__file__).resolve().parents[1]

#: (problem, scheme, mode, t1, t2): the run is counted over (t1, t2], past the
#: load breakpoints, whose steps the Python driver takes; long enough for
#: 100 steps or more per call of the driver under the paper's rule too.
CASES = [(problem, scheme, mode, t1, t2 if mode == "error" else t2_paper)
         for problem, t1, t2, t2_paper in [("dumbbell", 0.1, 1.0, 10.0),
                                           ("tetrahedra", 2.5, 20.0, 50.0),
                                           ("articulated", 0.06, 0.5, 1.5),
                                           ("toss_rule", 0.012, 0.05, 0.1)]
         for scheme in ("newmark", "bathe", "hfdi", "generalized_alpha")
         for mode in ("error", "iterations")]
#: Allocations allowed per call of the compiled loop
PER_CALL = 64

SCRIPT = textwrap.dedent("""
    import json, sys
    import hfdi
    from hfdi.controller import ErrorControl
    from numba import njit
    from numba.core.runtime import rtsys
    from hfdi.compiled.loads import hat_load

    def allocated():
        return rtsys.get_allocation_stats().alloc

    @njit
    def calls(kernel, args, n):
        for _ in range(n):
            kernel(*args)

    def per_call(kernel, *args):
        # called from compiled code, as the driver calls it (a call from
        # Python allocates more, to box the arguments and the result); the
        # difference of two counts cancels the cost of entering calls()
        counts = []
        for n in (0, 20, 40):
            before = allocated()
            calls(kernel, args, n)
            counts.append(allocated() - before)
        return (counts[2] - counts[1]) / 20

    driver_calls = [0]

    def counted_calls(itg):
        loop = itg._advance_compiled

        def counting(*args):
            driver_calls[0] += 1
            return loop(*args)
        itg._advance_compiled = counting

    results = []
    for problem, scheme, mode, t1, t2 in json.loads(sys.argv[1]):
        model = hfdi.models.get(problem)
        # the per-step rule: the subject is what a step allocates, not the accuracy
        options = dict(controller=ErrorControl(1e-6, per_step=True)) if mode == "error" \
            else dict(target_iterations=3.0)
        itg = hfdi.Integrator(model, scheme, compiled=True, **options)
        counted_calls(itg)
        itg.advance(t1)
        k = model.compiled_kernels()
        load = k.load if k.load is not None else hat_load
        u, w, t = itg.state.u, itg.state.v, itg.t
        kernels = {
            "nfev": per_call(k.force, u, k.params),
            "njev": per_call(k.stiffness, u, k.params),
            "ntev": per_call(k.stiffness_derivative, u, w, k.params),
            "npev": per_call(k.potential_energy, u, k.params),
            "load": per_call(load, t, k.load_params),
        }
        st = itg.statistics
        before = {name: getattr(st, name) for name in ("steps", "nfev", "njev", "ntev", "npev")}
        driver_calls[0] = 0
        start = allocated()
        itg.advance(t2)
        allocations = allocated() - start
        st = itg.statistics
        counts = {name: getattr(st, name) - before[name] for name in before}
        # the load at the step's end, and at Bathe's mid-step or generalized-α's
        # t_{n+1-α_f} (HFDI's rate is the paper's quotient, exact for these
        # loads, linear between their breakpoints)
        counts["load"] = counts["steps"] * (2 if scheme in ("bathe", "generalized_alpha")
                                            else 1)
        expected = sum(counts[name] * kernels[name] for name in kernels)
        results.append(dict(case=[problem, scheme, mode], allocations=allocations,
                            expected=expected, steps=counts["steps"],
                            driver_calls=driver_calls[0],
                            status=itg.status.name, kernels=kernels))
    print(json.dumps(results))
""")


@pytest.fixture(scope="session")
def counted(request):
    """The counts of the cases this session runs, in one subprocess."""
    name = test_a_step_allocates_only_what_its_kernels_allocate.__name__
    selected = [item.callspec.params["case"] for item in request.session.items
                if getattr(item, "originalname", None) == name]
    env = dict(os.environ, NUMBA_NRT_STATS="1", PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(selected)], env=env,
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    return {tuple(r["case"]): r for r in json.loads(done.stdout.splitlines()[-1])}


#: counted in a subprocess (NUMBA_NRT_STATS is read at import): the slow tier
@pytest.mark.slow
@pytest.mark.parametrize("case", CASES,
                         ids=["-".join(map(str, c[:3])) for c in CASES])
def test_a_step_allocates_only_what_its_kernels_allocate(counted, case):
    result = counted[tuple(case[:3])]
    assert result["status"] == "RUNNING", result
    calls = result["driver_calls"]
    # a run of ordinary steps, more of them per call than PER_CALL: one
    # allocation more per step would exceed the allowance
    assert calls >= 1 and result["steps"] >= 100 * calls, result
    extra = result["allocations"] - result["expected"]
    # no fewer than the kernels' own (the counts are right), and no more than
    # a constant per call of the driver
    assert 0 <= extra <= PER_CALL * calls, result
