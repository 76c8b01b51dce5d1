"""Cost of driving an FMU through fmpy against calling the library in-process.

``python -m benchmarks cosim [PROBLEM]``: the same run, with the same communication
points, once through :meth:`hfdi.Integrator.advance` in this process and once
through the FMU's ``fmi2DoStep`` (fmpy's low-level ``FMU2Slave``), reading the
state outputs after every communication step in both. Set-up (extraction,
instantiation, initialisation) is outside the timed part; each side is timed
``repeats`` times and the best is kept.
"""
from __future__ import annotations

import json
import math
import shutil
import tempfile
import time

import numpy as np

import hfdi
from validation import options as opt
from hfdi.files import write_output
from validation.experiments import SCHEME_ORDER, experiment

__all__ = ["benchmark", "main"]


def benchmark(problem="dumbbell", scheme="hfdi", target_iterations=3.0, internal_per_step=10,
              t_end=None, repeats=5, fmu=None, compiled=False, communication_step=None,
              inputs=False) -> dict:
    """Time in-process ``advance`` and FMU ``doStep`` over the same communication points.

    The communication step is ``communication_step``, or else
    ``internal_per_step`` times the mean internal step of a pilot run. With
    ``compiled`` both sides take their internal steps in the compiled driver
    (``Integrator(compiled=True)`` and the FMU's parameter ``compiled``); the
    FMU is extracted once, and an untimed first instance compiles (or loads)
    its bundled kernels. With ``inputs`` the force on the first DOF changes at
    every communication point (``fmi2SetReal`` of ``F[1]``; in process a
    :class:`hfdi.HeldLoad` and ``load_changed``). Returns a dict with both best times, their ratio (FMU
    over in-process), doSteps per second through the FMU, the communication
    step and the internal steps.
    """
    from fmpy import extract

    from fmu.build import build
    from fmu.master import Unit

    model = hfdi.models.get(problem)
    t_end = float(experiment(problem).long_time if t_end is None else t_end)
    if communication_step is None:
        pilot = hfdi.Integrator(model, scheme, target_iterations=target_iterations)
        pilot.advance(t_end)
        communication_step = internal_per_step * t_end / pilot.statistics.steps
    n_steps = max(1, math.ceil(t_end / communication_step - 1e-9))
    h = t_end / n_steps
    names = [f"u[{i + 1}]" for i in range(model.n_dof)] + \
            [f"v[{i + 1}]" for i in range(model.n_dof)]

    forces = [10.0 * math.sin(0.01 * k) for k in range(n_steps)]

    def in_process():
        held = np.zeros(model.n_dof)
        itg = hfdi.Integrator(model, scheme, target_iterations=target_iterations,
                              compiled=compiled,
                              extra_load=hfdi.HeldLoad(lambda: held) if inputs else None)
        started = time.perf_counter()
        t = 0.0
        for k in range(n_steps):
            if inputs:
                held[0] = forces[k]
                itg.load_changed()
            itg.advance(t + h)
            t = t + h
            state = itg.state
            state.u.tolist(), state.v.tolist()     # what a master reads
        return time.perf_counter() - started, itg.statistics.steps

    with tempfile.TemporaryDirectory() as tmp:
        path = fmu or build(problem, tmp)
        unzipped = extract(str(path))
        parameters = {"scheme": scheme, "target_iterations": target_iterations,
                      "compiled": bool(compiled)}

        def via_fmu():
            with Unit(path, "bench", unzip_dir=unzipped) as unit:
                unit.initialize(parameters, stop_time=t_end)
                refs = [unit.vr(name) for name in names]
                force_ref = [unit.vr("F[1]")]
                get_real, set_real, do_step = unit.fmu.getReal, unit.fmu.setReal, unit.fmu.doStep
                started = time.perf_counter()
                t = 0.0
                for k in range(n_steps):
                    if inputs:
                        set_real(force_ref, [forces[k]])
                    do_step(currentCommunicationPoint=t, communicationStepSize=h)
                    t = t + h
                    get_real(refs)
                elapsed = time.perf_counter() - started
                steps = int(unit.get(["internal_steps"])[0])
            return elapsed, steps

        started = time.perf_counter()
        with Unit(path, "warm-up", unzip_dir=unzipped) as unit:
            unit.initialize(parameters, stop_time=t_end)
        first_instance_s = time.perf_counter() - started
        own, other = [], []
        for _ in range(repeats):              # interleaved: a drift of load hits both
            own.append(in_process())
            other.append(via_fmu())
        shutil.rmtree(unzipped, ignore_errors=True)
    best_own, best_fmu = min(x[0] for x in own), min(x[0] for x in other)
    return {"problem": problem, "scheme": scheme, "target_iterations": target_iterations,
            "compiled": bool(compiled), "t_end": t_end, "communication_steps": n_steps,
            "communication_step": h, "internal_steps_in_process": own[0][1],
            "internal_steps_fmu": other[0][1],
            "internal_per_communication_step": own[0][1] / n_steps,
            "in_process_s": best_own, "fmu_s": best_fmu, "ratio": best_fmu / best_own,
            "do_steps_per_s": n_steps / best_fmu, "first_instance_s": first_instance_s,
            "repeats": repeats, "inputs": bool(inputs)}


#: The most communication steps of one run (each is a doStep through fmpy).
MAX_COMMUNICATION_STEPS = 10_000_000


def main(argv=None) -> int:
    """``python -m benchmarks cosim [PROBLEM] [--scheme S] [--communication-step H]
    [--paths] [--repeats N] [--json FILE]``."""
    parser = opt.Parser(prog="python -m benchmarks cosim",
                        description="Time the FMU through fmpy against in-process advance, "
                                    "communication step ≈ 10 internal steps or as given.")
    parser.add_argument("problem", nargs="?", default="dumbbell",
                        type=opt.single(opt.problems, "problem"))
    parser.add_argument("--scheme", choices=SCHEME_ORDER, default="hfdi")
    parser.add_argument("--communication-step", metavar="H", type=opt.positive,
                        help="communication step in s (default: about 10 internal steps)")
    parser.add_argument("--t-end", metavar="T", type=opt.positive,
                        help="end of the run (default: the problem's long time)")
    parser.add_argument("--paths", action="store_true",
                        help="the Python path and the compiled driver, one after the other")
    parser.add_argument("--inputs", action="store_true",
                        help="change the force F[1] at every communication point")
    parser.add_argument("--repeats", type=opt.repeats, default=5)
    parser.add_argument("--json", metavar="FILE", type=opt.output_file)
    args = parser.parse_args(argv)
    longest = opt.longest_run(args.problem)
    t_end = experiment(args.problem).long_time if args.t_end is None else args.t_end
    if t_end > longest:
        parser.error(f"argument --t-end: at most {longest:g} s for {args.problem} "
                     f"({opt.LONGEST_RUN:g} times its longest observation time), got {t_end:g}")
    if args.communication_step is not None \
            and t_end / args.communication_step > MAX_COMMUNICATION_STEPS:
        parser.error(f"argument --communication-step: at least "
                     f"{t_end / MAX_COMMUNICATION_STEPS:.3g} s for --t-end {t_end:g} (at most "
                     f"{MAX_COMMUNICATION_STEPS:,} communication steps), got "
                     f"{args.communication_step:g}")
    results = []
    for compiled in ((False, True) if args.paths else (False,)):
        result = benchmark(args.problem, args.scheme, repeats=args.repeats, compiled=compiled,
                           communication_step=args.communication_step, t_end=args.t_end,
                           inputs=args.inputs)
        results.append(result)
        repeats = args.repeats
        print(f"{args.problem}, {args.scheme}, {'compiled driver' if compiled else 'Python path'}"
              f"{', F[1] changed at every point' if args.inputs else ''}"
              f": {result['communication_steps']} communication steps of "
              f"{result['communication_step']:.4g} s, "
              f"{result['internal_per_communication_step']:.1f} internal steps each "
              f"(in-process {result['internal_steps_in_process']}, "
              f"FMU {result['internal_steps_fmu']})")
        print(f"  in-process advance  {result['in_process_s']:.4f} s (best of {repeats})")
        print(f"  FMU through fmpy    {result['fmu_s']:.4f} s (best of {repeats}): "
              f"{result['do_steps_per_s']:.0f} doSteps/s; first instance "
              f"{result['first_instance_s']:.2f} s")
        print(f"  ratio FMU / in-process = {result['ratio']:.3f}")
    if args.paths:
        print(f"  doSteps/s, compiled over Python path: "
              f"{results[1]['do_steps_per_s'] / results[0]['do_steps_per_s']:.2f}x")
    if args.json:
        write_output(args.json, json.dumps(results if args.paths else results[0], indent=1))
    return 0
