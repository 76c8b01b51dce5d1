"""Cost per Newton iteration and where it goes: model, linear algebra, driver.

``python -m benchmarks profile [--problems a,b] [--schemes ...] [--target 3]
[--json FILE]`` integrates each problem to its ``T_o`` and prints, per
scheme, the wall time per Newton iteration (best of ``--repeats`` plain runs)
and the fractions of one run under ``cProfile`` spent in

* **model evaluation** — the model's own methods (``internal_force``,
  ``stiffness``, ``stiffness_derivative``, ``load``, ...) as called by
  :class:`hfdi.evaluation.Evaluator`, i.e. functions defined in the model's
  module or in :mod:`hfdi.models`;
* **linear algebra** — :mod:`hfdi.linalg` (factorisations, solves, band
  storage, ``combine``) and the ``solve``/``band`` methods of the tangents in
  :mod:`hfdi.schemes`, counted where they are entered from outside that set;
* **driver** — everything else: the evaluator's checks, predictor,
  corrector, controller, energy balance and the schemes' inline numpy
  arithmetic.

Fractions are of the profiled run's total; cProfile's own overhead inflates
the many small calls of the driver somewhat, so the split is an estimate and
the per-iteration time is taken from the plain runs.

``--paths`` instead compares the Python path with the compiled attempt
(``compiled=True``, docs/compiled.md) on the same runs: µs per Newton
iteration of each, best of ``--repeats`` runs made in turn, and their ratio;
with ``--rtol R`` the runs are error-controlled instead of at ``--target``.
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
from hfdi.files import write_atomic
from validation.experiments import SCHEME_ORDER, experiment, names
from validation.runs import integrate

__all__ = ["profile_run", "compare_paths", "main"]

_HFDI = Path(hfdi.__file__).resolve().parent
_LINALG_METHODS = {"solve", "band", "solve_band"}


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
        if path is None:
            return False
        return path == _HFDI / "linalg.py" or (path == _HFDI / "schemes.py"
                                               and key[2] in _LINALG_METHODS)
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
    attempt on the same run, best of ``repeats`` runs of each made in turn.

    Returns
    -------
    dict
        ``steps``, ``newton_iterations`` (Python path), ``compiled_steps``,
        ``compiled_newton_iterations``, ``python_us``, ``compiled_us`` (µs
        per iteration of each path's own run), ``speedup`` (their ratio) and
        ``same_counts`` (steps and Newton corrections equal on both paths).
    """
    end = experiment(problem).observation_time if t_end is None else t_end
    if rtol is not None:
        target = None
    best = {False: math.inf, True: math.inf}
    counts = {}
    for _ in range(max(1, int(repeats))):
        for compiled in (False, True):
            model = experiment(problem).model()
            start = time.perf_counter()
            result = integrate(model, scheme, end, target, rtol=rtol, compiled=compiled)
            best[compiled] = min(best[compiled], time.perf_counter() - start)
            counts[compiled] = (int(result.stats.steps), int(result.stats.newton_iterations))
    steps, iterations = counts[False]
    return {"problem": problem, "scheme": scheme, "target": target, "rtol": rtol,
            "steps": steps, "newton_iterations": iterations,
            "compiled_steps": counts[True][0], "compiled_newton_iterations": counts[True][1],
            "python_us": 1e6 * best[False] / max(iterations, 1),
            "compiled_us": 1e6 * best[True] / max(counts[True][1], 1),
            "speedup": (best[False] / max(iterations, 1)) / (best[True] / max(counts[True][1], 1)),
            "same_counts": counts[False] == counts[True]}


def _print_paths(args) -> list:
    rows = []
    print(f"{'problem':12s} {'scheme':8s} {'steps':>6s} {'its':>6s} {'python µs/it':>13s} "
          f"{'compiled µs/it':>15s} {'ratio':>6s}")
    for problem in args.problems or names():
        for scheme in args.schemes:
            row = compare_paths(problem, scheme, args.target, args.rtol, args.repeats,
                                args.t_end)
            rows.append(row)
            note = "" if row["same_counts"] else (
                f"  (compiled: {row['compiled_steps']} steps, "
                f"{row['compiled_newton_iterations']} its)")
            print(f"{problem:12s} {scheme:8s} {row['steps']:6d} {row['newton_iterations']:6d} "
                  f"{row['python_us']:13.1f} {row['compiled_us']:15.1f} "
                  f"{row['speedup']:6.2f}{note}", flush=True)
    return rows


def main(argv=None) -> int:
    parser = opt.Parser(prog="python -m benchmarks profile",
                        description="Cost per Newton iteration and its split.")
    parser.add_argument("--problems", default=None, type=opt.problems)
    parser.add_argument("--schemes", default=list(SCHEME_ORDER), type=opt.schemes)
    parser.add_argument("--target", type=lambda s: opt.targets(s)[0], default=3.0,
                        help="N̄ (default 3)")
    parser.add_argument("--repeats", type=opt.positive_integer, default=5,
                        help="plain runs, best kept (5)")
    parser.add_argument("--t-end", type=opt.positive, default=None, help="default: T_o")
    parser.add_argument("--json", default=None, metavar="FILE", type=opt.output_file)
    parser.add_argument("--paths", action="store_true",
                        help="compare the Python path with the compiled attempt")
    parser.add_argument("--rtol", type=lambda s: opt.rtols(s)[0], default=None,
                        help="with --paths: error-controlled runs at this rtol")
    args = parser.parse_args(argv)
    if args.paths:
        rows = _print_paths(args)
        if args.json:
            write_atomic(Path(args.json), json.dumps(rows, indent=1))
        return 0
    rows = []
    print(f"{'problem':12s} {'scheme':8s} {'steps':>6s} {'its':>6s} {'ms':>8s} "
          f"{'ms/it':>7s}  model  linalg  driver")
    for problem in args.problems or names():
        for scheme in args.schemes:
            row = profile_run(problem, scheme, args.target, args.repeats, args.t_end)
            rows.append(row)
            f = row["fractions"]
            print(f"{problem:12s} {scheme:8s} {row['steps']:6d} {row['newton_iterations']:6d} "
                  f"{1e3 * row['wall_s']:8.1f} {row['ms_per_iteration']:7.3f}  "
                  f"{f['model']:5.2f}  {f['linear_algebra']:6.2f}  {f['driver']:6.2f}",
                  flush=True)
    if args.json:
        write_atomic(Path(args.json), json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
