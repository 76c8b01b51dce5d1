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
import tempfile
import time

import hfdi
from validation import options as opt
from hfdi.files import write_atomic
from validation.experiments import SCHEME_ORDER, experiment

__all__ = ["benchmark", "main"]


def benchmark(problem="dumbbell", scheme="hfdi", target_iterations=3.0, internal_per_step=10,
              t_end=None, repeats=5, fmu=None) -> dict:
    """Time in-process ``advance`` and FMU ``doStep`` over the same communication points.

    The communication step is ``internal_per_step`` times the mean internal
    step of a pilot run. Returns a dict with both best times, their ratio
    (FMU over in-process), the communication step and the internal steps.
    """
    from fmu.build import build
    from fmu.master import Unit

    model = hfdi.models.get(problem)
    t_end = float(experiment(problem).long_time if t_end is None else t_end)
    pilot = hfdi.Integrator(model, scheme, target_iterations=target_iterations)
    pilot.advance(t_end)
    comm = internal_per_step * t_end / pilot.statistics.steps
    n_steps = max(1, math.ceil(t_end / comm - 1e-9))
    h = t_end / n_steps
    names = [f"u[{i + 1}]" for i in range(model.n_dof)] + \
            [f"v[{i + 1}]" for i in range(model.n_dof)]

    def in_process():
        itg = hfdi.Integrator(model, scheme, target_iterations=target_iterations)
        started = time.perf_counter()
        t = 0.0
        for _ in range(n_steps):
            itg.advance(t + h)
            t = t + h
            state = itg.state
            state.u.tolist(), state.v.tolist()     # what a master reads
        return time.perf_counter() - started, itg.statistics.steps

    with tempfile.TemporaryDirectory() as tmp:
        path = fmu or build(problem, tmp)

        def via_fmu():
            with Unit(path, "bench") as unit:
                unit.initialize({"scheme": scheme, "target_iterations": target_iterations},
                                stop_time=t_end)
                refs = [unit.vr(name) for name in names]
                get_real, do_step = unit.fmu.getReal, unit.fmu.doStep
                started = time.perf_counter()
                t = 0.0
                for _ in range(n_steps):
                    do_step(currentCommunicationPoint=t, communicationStepSize=h)
                    t = t + h
                    get_real(refs)
                elapsed = time.perf_counter() - started
                steps = int(unit.get(["internal_steps"])[0])
            return elapsed, steps

        own = [in_process() for _ in range(repeats)]
        other = [via_fmu() for _ in range(repeats)]
    best_own, best_fmu = min(x[0] for x in own), min(x[0] for x in other)
    return {"problem": problem, "scheme": scheme, "target_iterations": target_iterations,
            "t_end": t_end, "communication_steps": n_steps, "communication_step": h,
            "internal_steps_in_process": own[0][1], "internal_steps_fmu": other[0][1],
            "internal_per_communication_step": own[0][1] / n_steps,
            "in_process_s": best_own, "fmu_s": best_fmu, "ratio": best_fmu / best_own,
            "repeats": repeats}


def main(argv=None) -> int:
    """``python -m benchmarks cosim [PROBLEM] [--scheme S] [--repeats N] [--json FILE]``."""
    parser = opt.Parser(prog="python -m benchmarks cosim",
                        description="Time the FMU through fmpy against in-process advance, "
                                    "communication step ≈ 10 internal steps.")
    parser.add_argument("problem", nargs="?", default="dumbbell",
                        type=lambda text: opt.problems(text)[0])
    parser.add_argument("--scheme", choices=SCHEME_ORDER, default="hfdi")
    parser.add_argument("--repeats", type=opt.positive_integer, default=5)
    parser.add_argument("--json", metavar="FILE", type=opt.output_file)
    args = parser.parse_args(argv)
    result = benchmark(args.problem, args.scheme, repeats=args.repeats)
    repeats = args.repeats
    print(f"{args.problem}, {args.scheme}: {result['communication_steps']} communication "
          f"steps of {result['communication_step']:.4g} s, "
          f"{result['internal_per_communication_step']:.1f} internal steps each "
          f"(in-process {result['internal_steps_in_process']}, "
          f"FMU {result['internal_steps_fmu']})")
    print(f"  in-process advance  {result['in_process_s']:.4f} s (best of {repeats})")
    print(f"  FMU through fmpy    {result['fmu_s']:.4f} s (best of {repeats})")
    print(f"  ratio FMU / in-process = {result['ratio']:.3f}")
    if args.json:
        write_atomic(args.json, json.dumps(result, indent=1))
    return 0
