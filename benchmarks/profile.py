"""Cost per Newton iteration and where it goes: model, linear algebra, driver.

``python -m benchmarks profile [--problems a,b] [--schemes ...] [--target 3]
[--json FILE]`` integrates each problem to its ``T_o`` on the Python path
(``compiled=False``) and prints, per scheme, the wall time per Newton
iteration (best of ``--repeats`` plain runs) and the fractions of one run
under ``cProfile`` spent in

* **model evaluation** — the model's own methods (``internal_force``,
  ``stiffness``, ``stiffness_derivative``, ``load``, ...) as called by
  :class:`hfdi.evaluation.Evaluator`, i.e. functions defined in the model's
  module or in :mod:`hfdi.models`;
* **linear algebra** — :mod:`hfdi.linsolve` (the dense LAPACK solves and
  factorisations, the sparse, banded and block solvers), counted where it is
  entered from outside that package;
* **driver** — everything else: the evaluator's checks and the stepping code
  (:mod:`hfdi.stepping`, :mod:`hfdi.core`: predictor, residuals and tangents,
  corrector, error estimate, controller, energy balance).

Fractions are of the profiled run's total; cProfile's own overhead inflates
the many small calls of the driver somewhat, so the split is an estimate and
the per-iteration time is taken from the plain runs.

``--paths`` instead compares the Python path with the compiled path
(``compiled=True``: the compiled loop, docs/compiled.md) on the same runs:
µs per Newton iteration of each, best of ``--repeats`` runs made in turn,
and their ratio; with ``--rtol R`` the runs are error-controlled instead of
at ``--target``. The compiled run's time is split into the model's kernels,
the dense linear algebra and the rest (the compiled loop's own work) from its
evaluation counts and the unit costs of each kernel, of the library's dense
solve and of a product, timed in compiled loops (:func:`compiled_unit_costs`,
:func:`benchmarks.floor.unit_costs`). The floor is what one correction of the
scheme cannot avoid: the sum of the unit costs of the kernels it evaluates
and of its solve (:func:`benchmarks.floor.floor_us`), printed beside the
compiled µs per iteration.
"""
from __future__ import annotations

import cProfile
import inspect
import json
import math
import pstats
import sys
import time
from pathlib import Path

import hfdi
from validation import options as opt
from hfdi.files import write_output
from validation.experiments import SCHEME_ORDER, experiment, names

from .floor import correction_costs, floor_us, unit_costs
from validation.runs import integrate

__all__ = ["profile_run", "compare_paths", "compiled_unit_costs", "compiled_split", "main"]

_HFDI = Path(hfdi.__file__).resolve().parent


def _file(key) -> Path | None:
    filename = key[0]
    if filename.startswith("~") or filename.startswith("<"):
        return None
    return Path(filename).resolve()


def _classify(model):
    model_files = {Path(inspect.getfile(type(model))).resolve()}

    def is_model(key):
        path = _file(key)
        return path is not None and (path in model_files or path.parent == _HFDI / "models")

    def is_linalg(key):
        path = _file(key)
        return path is not None and path.parent == _HFDI / "linsolve"
    return is_model, is_linalg


def _entered_time(stats, inside) -> float:
    """Cumulative time of the functions ``inside`` as entered from outside the set."""
    total = 0.0
    for key, (_, _, _, _, callers) in stats.items():
        if not inside(key):
            continue
        for caller, (_, _, _, ct) in callers.items():
            if not inside(caller):
                total += ct
    return total


def profile_run(problem: str, scheme: str, target: float = 3.0, repeats: int = 5,
                t_end: float | None = None) -> dict:
    """Time one run of ``problem`` and split a profiled one into model / linear algebra / driver.

    Returns
    -------
    dict
        ``steps``, ``newton_iterations`` (with first-step trials, as ``nlu``
        counts them), ``wall_s`` (best of ``repeats``), ``ms_per_iteration``
        and ``fractions`` (``model``, ``linear_algebra``, ``driver``; they sum to 1).
    """
    def run():
        model = experiment(problem).model()
        end = experiment(problem).observation_time if t_end is None else t_end
        start = time.perf_counter()
        result = integrate(model, scheme, end, target)
        return model, result, time.perf_counter() - start

    best = math.inf
    for _ in range(max(1, int(repeats))):
        model, result, wall = run()
        best = min(best, wall)
    iterations = int(result.stats.nlu) or int(result.stats.newton_iterations)

    profiler = cProfile.Profile()
    profiler.enable()
    model, _, _ = run()
    profiler.disable()
    stats = pstats.Stats(profiler).stats
    total = sum(tt for (_, _, tt, _, _) in stats.values())
    is_model, is_linalg = _classify(model)
    model_time = _entered_time(stats, is_model)
    linalg_time = _entered_time(stats, is_linalg)
    fractions = {"model": model_time / total, "linear_algebra": linalg_time / total}
    fractions["driver"] = 1.0 - fractions["model"] - fractions["linear_algebra"]
    return {"problem": problem, "scheme": scheme, "target": float(target),
            "steps": int(result.stats.steps), "newton_iterations": iterations,
            "wall_s": best, "ms_per_iteration": 1e3 * best / max(iterations, 1),
            "status": result.status.name, "fractions": fractions}


def compare_paths(problem: str, scheme: str, target=3.0, rtol=None, repeats: int = 3,
                  t_end: float | None = None) -> dict:
    """Wall time per Newton iteration of the Python path and of the compiled
    path on the same run, best of ``repeats`` runs of each made in turn.

    Returns
    -------
    dict
        ``steps``, ``newton_iterations`` (Python path), ``compiled_steps``,
        ``compiled_newton_iterations``, ``python_us``, ``compiled_us`` (µs
        per iteration of each path's own run), ``speedup`` (their ratio),
        ``same_counts`` (steps and Newton corrections equal on both paths),
        ``unit_costs_us`` (:func:`compiled_unit_costs` at the compiled run's
        end state), ``compiled_split`` (:func:`compiled_split`), ``floor_us``
        (:func:`benchmarks.floor.floor_us`: µs per correction in the kernels
        and the solve it cannot avoid) and ``floor_iterations_per_step`` (the
        compiled run's corrections per step: the floor per step is
        ``floor_us`` times it).
    """
    end = experiment(problem).observation_time if t_end is None else t_end
    if rtol is not None:
        target = None
    best = {False: math.inf, True: math.inf}
    counts, results = {}, {}
    # untimed: the first compiled run of a process loads (or compiles) the
    # compiled code, which a single timed repeat would otherwise count
    integrate(experiment(problem).model(), scheme, min(end, 1e-3), target, rtol=rtol,
              compiled=True)
    for _ in range(max(1, int(repeats))):
        for compiled in (False, True):
            model = experiment(problem).model()
            start = time.perf_counter()
            result = integrate(model, scheme, end, target, rtol=rtol, compiled=compiled)
            best[compiled] = min(best[compiled], time.perf_counter() - start)
            counts[compiled] = (int(result.stats.steps), int(result.stats.newton_iterations))
            results[compiled] = result
    steps, iterations = counts[False]
    model = experiment(problem).model()
    costs = compiled_unit_costs(model, results[True].u[-1])
    split = compiled_split({"scheme": scheme}, results[True], costs, best[True])
    # the floor: the kernels and the solve one correction cannot avoid
    floor = floor_us(model, scheme, costs)
    floor_per_step = counts[True][1] / max(counts[True][0], 1)
    return {"problem": problem, "scheme": scheme, "target": target, "rtol": rtol,
            "unit_costs_us": costs, "compiled_split": split,
            "steps": steps, "newton_iterations": iterations,
            "compiled_steps": counts[True][0], "compiled_newton_iterations": counts[True][1],
            "python_us": 1e6 * best[False] / max(iterations, 1),
            "compiled_us": 1e6 * best[True] / max(counts[True][1], 1),
            "speedup": (best[False] / max(iterations, 1)) / (best[True] / max(counts[True][1], 1)),
            "floor_us": floor, "floor_iterations_per_step": floor_per_step,
            "same_counts": counts[False] == counts[True]}


def compiled_unit_costs(model, u, repeats: int = 3, calls: int = 2000) -> dict:
    """µs per call, in compiled loops, of the model's kernels at ``u`` (``f``, ``K``,
    ``T[w]``, ``V``) and of the dense linear algebra of one Newton correction
    (the library's solve, :func:`hfdi.linsolve.dense.solve`, with an (N, N)
    matrix symmetric when ``K`` is, and an (N, N) product, HFDI's ``S B⁻¹ S``);
    best of ``repeats``: :func:`benchmarks.floor.unit_costs`."""
    return unit_costs(model, u, repeats, calls)


def compiled_split(row: dict, result, costs: dict, wall_s: float) -> dict:
    """Fractions of a compiled run's wall time in the model's kernels, in the
    dense linear algebra and in the rest (the driver: predictor, residuals and
    tangents' assembly, error estimate, controller, energy balance), estimated
    from the run's evaluation counts and the unit costs of
    :func:`compiled_unit_costs` (a product per correction for a scheme whose
    corrections form one, :func:`benchmarks.floor.correction_costs`)."""
    st = result.stats
    model = (st.nfev * costs["force"] + st.njev * costs["stiffness"]
             + st.ntev * costs["stiffness_derivative"] + st.npev * costs["potential_energy"])
    linalg = st.nlu * costs["solve"]
    if "product" in correction_costs(row["scheme"]):
        linalg += st.newton_iterations * costs["product"]      # S B⁻¹ S per correction
    total = 1e6 * wall_s
    return {"model": model / total, "linear_algebra": linalg / total,
            "driver": 1.0 - (model + linalg) / total}


def _print_paths(args) -> list:
    rows = []
    width = max([8] + [len(s) for s in args.schemes])
    print(f"{'problem':12s} {'scheme':{width}s} {'steps':>6s} {'its':>6s} {'python µs/it':>13s} "
          f"{'compiled µs/it':>15s} {'ratio':>6s} {'floor µs/it':>12s}  compiled: model  "
          f"linalg  driver")
    for problem in args.problems or names():
        for scheme in args.schemes:
            row = compare_paths(problem, scheme, args.target, args.rtol, args.repeats,
                                args.t_end)
            rows.append(row)
            note = "" if row["same_counts"] else (
                f"  (compiled: {row['compiled_steps']} steps, "
                f"{row['compiled_newton_iterations']} its)")
            f = row["compiled_split"]
            print(f"{problem:12s} {scheme:{width}s} {row['steps']:6d} "
                  f"{row['newton_iterations']:6d} "
                  f"{row['python_us']:13.1f} {row['compiled_us']:15.1f} "
                  f"{row['speedup']:6.2f} {row['floor_us']:12.2f}  {f['model']:15.2f}  "
                  f"{f['linear_algebra']:6.2f}  "
                  f"{f['driver']:6.2f}{note}", flush=True)
    return rows


def main(argv=None) -> int:
    parser = opt.Parser(prog="python -m benchmarks profile",
                        description="Cost per Newton iteration and its split.")
    parser.add_argument("--problems", default=None, type=opt.problems)
    parser.add_argument("--schemes", default=list(SCHEME_ORDER), type=opt.schemes,
                        help=f"comma-separated (default: all, {','.join(SCHEME_ORDER)})")
    parser.add_argument("--target", type=opt.single(opt.targets, "target"), default=3.0,
                        help="N̄ (default 3)")
    parser.add_argument("--repeats", type=opt.repeats, default=5,
                        help="plain runs, best kept (5)")
    parser.add_argument("--t-end", type=opt.positive, default=None, help="default: T_o")
    parser.add_argument("--json", default=None, metavar="FILE", type=opt.output_file)
    parser.add_argument("--paths", action="store_true",
                        help="compare the Python path with the compiled path; the floor: "
                             "µs per correction in the model's kernels and the library's "
                             "solve")
    parser.add_argument("--rtol", type=opt.single(opt.rtols, "rtol"), default=None,
                        help="with --paths: error-controlled runs at this rtol")
    args = parser.parse_args(argv)
    # a --t-end the library refuses, or far beyond the problem's times (1e300
    # ran zero steps and printed a time per iteration of them)
    opt.check_runs(args.problems or names(), args.schemes, [args.target], args.t_end,
                   [args.rtol] if args.rtol is not None else None)
    if args.paths:
        rows = _print_paths(args)
        if args.json:
            write_output(Path(args.json), json.dumps(rows, indent=1))
        return 0
    rows = []
    width = max([8] + [len(s) for s in args.schemes])
    print(f"{'problem':12s} {'scheme':{width}s} {'steps':>6s} {'its':>6s} {'ms':>8s} "
          f"{'ms/it':>7s}  model  linalg  driver")
    for problem in args.problems or names():
        for scheme in args.schemes:
            row = profile_run(problem, scheme, args.target, args.repeats, args.t_end)
            rows.append(row)
            f = row["fractions"]
            print(f"{problem:12s} {scheme:{width}s} {row['steps']:6d} "
                  f"{row['newton_iterations']:6d} "
                  f"{1e3 * row['wall_s']:8.1f} {row['ms_per_iteration']:7.3f}  "
                  f"{f['model']:5.2f}  {f['linear_algebra']:6.2f}  {f['driver']:6.2f}",
                  flush=True)
    if args.json:
        write_output(Path(args.json), json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
