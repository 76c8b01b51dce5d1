"""Build a model's FMU, co-simulate it with fmpy and compare with the library in-process.

``python -m fmu demo [PROBLEM] [--out DIR]`` (the second half of ``make demo``).
"""
from __future__ import annotations

import time

import numpy as np

import hfdi

__all__ = ["run_demo"]


def run_demo(problem: str = "dumbbell", out_dir: str = "out/fmu", scheme: str = "hfdi",
             target_iterations: float = 3.0, points: int = 50) -> int:
    """Build the FMU of ``problem``, simulate it with ``fmpy.simulate_fmu`` over the
    model's default experiment (``stop_time`` of its
    :mod:`fmu.metadata` table, the paper's ``T_o``) with ``points`` communication steps, and print its end state
    beside :meth:`hfdi.Integrator.advance` called in-process at the same times."""
    from fmpy import simulate_fmu

    from . import metadata
    from .build import build

    model = hfdi.models.get(problem)
    t_end = metadata.resolve(problem, type(model))["stop_time"]
    started = time.perf_counter()
    path = build(problem, out_dir)
    print(f"built {path} in {time.perf_counter() - started:.1f} s")
    n = model.n_dof
    names = [f"u[{i + 1}]" for i in range(n)] + [f"v[{i + 1}]" for i in range(n)]
    started = time.perf_counter()
    result = simulate_fmu(str(path), stop_time=t_end, output_interval=t_end / points,
                          start_values={"scheme": scheme,
                                        "target_iterations": target_iterations},
                          output=names + ["internal_steps", "newton_iterations"])
    fmu_wall = time.perf_counter() - started

    itg = hfdi.Integrator(model, scheme, target_iterations=target_iterations)
    started = time.perf_counter()
    previous = 0.0
    for t in result["time"][1:]:
        itg.advance(previous + (float(t) - previous))   # the master's arithmetic for t + h
        previous = float(t)
    own_wall = time.perf_counter() - started

    end = result[-1]
    via_fmu = np.array([end[name] for name in names])
    in_process = np.concatenate([itg.state.u, itg.state.v])
    print(f"\n{problem}, {scheme}, N̄ = {target_iterations}: {points} communication steps "
          f"to t = {t_end:g}")
    print(f"  {'':8s}{'FMU (fmpy)':>22s}{'in-process':>22s}")
    for name, a, b in zip(names, via_fmu, in_process):
        print(f"  {name:8s}{a:22.15g}{b:22.15g}")
    print(f"  {'steps':8s}{int(end['internal_steps']):22d}{itg.statistics.steps:22d}")
    print(f"  {'Newton':8s}{int(end['newton_iterations']):22d}"
          f"{itg.statistics.newton_iterations:22d}")
    scale = np.maximum(np.abs(in_process), 1e-300)
    diff = float(np.max(np.abs(via_fmu - in_process) / scale))
    print(f"  largest relative difference {diff:.2e}; wall time FMU {fmu_wall:.2f} s "
          f"(with loading), in-process {own_wall:.2f} s")
    return 0 if diff <= 1e-12 else 1
