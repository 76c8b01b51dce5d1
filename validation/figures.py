"""The paper's figures of Section 5 for one benchmark problem, as PNG files.

Every figure of a problem draws on one :class:`ProblemRuns`, which integrates
each (scheme, target, end time) once and computes the IDA reference once, so
the error figures, the trajectories, the energy and the step-size plots of a
problem share their runs. The files are named after the paper's figure they
correspond to (``dumbbell_fig09_eps_u.png``); where the paper shows a kind of
figure for one problem only (the error norms of Figs. 9–10 and 20–21, the step
sizes of Figs. 11 and 22) the other problems get the same kind of figure under
the number of the paper's, and :attr:`FigureSpec.paper` says so.

Outputs are written atomically (a temporary file in the target directory, then
``os.replace``), so an interrupted run never leaves a truncated PNG that a
resumed one would take as done.
"""
from __future__ import annotations

import io
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import matplotlib

# A headless backend, chosen before pyplot is imported: the figures are only
# ever written to files, often on machines without a display.
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402


from hfdi.files import write_output  # noqa: E402
from .experiments import (EXPERIMENTS, FIGURE_SUBJECTS, SCHEME_COLOURS,  # noqa: E402
                          SCHEME_ORDER, Quantity, SchemeStyle)
from .runs import ProblemRuns, run_label, scheme_title  # noqa: E402

__all__ = ["figure_png", "save_figure", "FigureSpec", "figure_specs", "write_figures",
           "eps_figure", "kinetic_energy"]

#: Marker of each scheme's runs (by its place in hfdi.SCHEMES; "x" for another name).
_MARKERS = SchemeStyle(("s", "^", "o", "v", "D", "P", "*"), "x")


class _Style(dict):
    """Colour (one per scheme in every figure) and marker of each scheme's runs;
    any scheme name has one (:class:`~validation.experiments.SchemeStyle`)."""

    def __missing__(self, scheme):
        return {"color": SCHEME_COLOURS[scheme], "marker": _MARKERS[scheme]}


_STYLE = _Style()
_REFERENCE_STYLE = {"color": "black", "linestyle": "-", "linewidth": 0.8}
_TARGET_COLORS = ("tab:green", "tab:blue", "tab:purple", "tab:red", "tab:brown", "tab:olive",
                  "tab:cyan", "tab:pink")


# -- output helpers ---------------------------------------------------------------

def figure_png(fig) -> bytes:
    """``fig`` rendered as PNG (the bytes :func:`save_figure` writes); closes it."""
    try:
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=110)
    finally:
        plt.close(fig)
    return buffer.getvalue()


def save_figure(fig, path) -> Path:
    """Render ``fig`` as PNG into ``path`` atomically and close it."""
    return write_output(path, figure_png(fig))


# -- labels -------------------------------------------------------------------------

def _unit(unit: str) -> str:
    return f" [{unit}]" if unit else ""


def _time_label() -> str:
    return "t [s]"


def kinetic_energy(model, v) -> np.ndarray:
    """``T = ½ vᵀ M v`` at each row of ``v`` (n, N), for a 1-D, dense or sparse ``M``."""
    v = np.atleast_2d(np.asarray(v, dtype=float))
    mass = model.mass
    if sp.issparse(mass):
        mv = np.asarray((mass @ v.T).T)
    else:
        mass = np.asarray(mass, dtype=float)
        mv = mass * v if mass.ndim == 1 else v @ mass.T
    return 0.5 * np.einsum("ni,ni->n", v, mv)


# -- the runs of one problem --------------------------------------------------------------

# -- figure makers --------------------------------------------------------------------------

def _figure(width=7.0, height=4.5, **kw):
    fig, ax = plt.subplots(figsize=(width, height), **kw)
    return fig, ax


def _finish(fig, ax=None, legend=True):
    if ax is not None and legend:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def eps_figure(records, quantity: str, title: str, time_unit="s"):
    """``ε`` of ``quantity`` against ``Δt_mv`` on log–log axes, one line per scheme.

    Runs stopped early (``div``) are drawn as crosses and left out of the lines;
    runs without a finite, positive ``ε`` are left out.

    Parameters
    ----------
    records : list of RunRecord
        Table runs carrying ``eps``.
    quantity : str
        A key of the records' ``eps``.
    title : str
    time_unit : str
        Unit of ``Δt_mv`` on the axis label.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _figure()
    problem = EXPERIMENTS.get(records[0].problem) if records else None
    symbol = (problem.quantity(quantity) if problem else Quantity(quantity, "", "")).symbol
    for scheme in SCHEME_ORDER:
        rows = [r for r in records if r.scheme == scheme
                and math.isfinite(r.eps.get(quantity, math.nan)) and r.eps[quantity] > 0
                and r.mean_step > 0]
        if not rows:
            continue
        style = _STYLE[scheme]
        good = sorted((r for r in rows if not r.diverged), key=lambda r: r.mean_step)
        bad = [r for r in rows if r.diverged]
        name = scheme_title(scheme)
        if good:
            ax.loglog([r.mean_step for r in good], [r.eps[quantity] for r in good], "-",
                      marker=style["marker"], color=style["color"], label=name)
            for r in good:
                ax.annotate(("2·" if scheme == "bathe" else "") + f"{r.target:g}",
                            (r.mean_step, r.eps[quantity]), textcoords="offset points",
                            xytext=(4, 3), fontsize=6, color=style["color"])
        if bad:
            ax.loglog([r.mean_step for r in bad], [r.eps[quantity] for r in bad], "x",
                      color=style["color"], label=f"{name} (div, ε up to the stop)")
    ax.set_xlabel(rf"mean step $\Delta t_{{mv}}$ [{time_unit}]")
    ax.set_ylabel(rf"$\varepsilon_{{{symbol}}}$ [-]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    return _finish(fig, ax)


def _time_series(ctx: ProblemRuns, runs, extract, ylabel, title, reference=True,
                 markersize=3):
    fig, ax = _figure()
    if reference:
        t, z = extract(ctx, None)
        ax.plot(t, z, label="reference (IDA, rtol 1e-12)", zorder=1, **_REFERENCE_STYLE)
    for scheme, target in runs:
        result = ctx.run(scheme, target)
        t, z = extract(ctx, result)
        style = _STYLE[scheme]
        ax.plot(t, z, linestyle="--", linewidth=0.7, marker=style["marker"], color=style["color"],
                markersize=markersize, label=run_label(scheme, target, result.stats.mean_step),
                zorder=2)
    ax.set_xlabel(_time_label())
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    return _finish(fig, ax)


def _body_path(ctx: ProblemRuns, runs, ix, iy, title):
    """Displacement components ``ix`` against ``iy``: the reference's path solid,
    each run's step states as markers."""
    fig, ax = _figure()
    t = ctx.plot_times()
    u = ctx.reference().at(t)[0]
    ax.plot(u[:, ix], u[:, iy], label="reference (IDA, rtol 1e-12)", zorder=1,
            **_REFERENCE_STYLE)
    for scheme, target in runs:
        result = ctx.run(scheme, target)
        style = _STYLE[scheme]
        ax.plot(result.u[:, ix], result.u[:, iy], linestyle="none", marker=style["marker"],
                markersize=3, markerfacecolor="none", color=style["color"],
                label=run_label(scheme, target, result.stats.mean_step), zorder=2)
    length = _unit(ctx.experiment.length_unit)
    ax.set_xlabel("x" + length)
    ax.set_ylabel("y" + length)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    return _finish(fig, ax)


def _quantity_extractor(name, column=None, reduce=None):
    """``(ctx, result or None) -> (t, z)``: a quantity of the run, or of the reference."""
    def extract(ctx, result):
        if result is None:
            t, z = ctx.reference_quantity(name)
        else:
            t = result.t
            z = ctx.model.quantities(t, result.u, result.v)[name]
        if reduce is not None:
            z = reduce(z)
        elif column is not None:
            z = z[:, column]
        return t, z
    return extract


def _configurations(ctx: ProblemRuns, runs, bodies, title, n_snapshots=11):
    """One panel per run: body positions at the run's step times nearest to a
    sequence of times, the reference at exactly those times drawn solid.

    ``bodies(u)`` maps (n, N) displacements to (n, n_bodies, 2) positions. A
    motion much longer in y than in x (the dumbbell flies along y) is drawn
    turned by 90° (y across the page, x down) and the panels stacked, so that
    at equal scales each panel still fills the page.
    """
    ref = ctx.reference()
    t_fine = ctx.plot_times()
    xy_fine = bodies(ref.at(t_fine)[0])
    wanted = np.linspace(0.0, ctx.t_end, n_snapshots)
    # Common limits, so that the panels compare at a glance; runs that fly
    # off widen them only up to twice the reference's extent.
    lo, hi = xy_fine.min(axis=(0, 1)), xy_fine.max(axis=(0, 1))
    pad = 0.05 * max(float(np.max(hi - lo)), 1e-12)
    lo, hi = lo - pad, hi + pad
    span = hi - lo
    for scheme, target in runs:
        xy = bodies(ctx.run(scheme, target).u)
        lo = np.maximum(np.minimum(lo, xy.min(axis=(0, 1)) - pad), lo - span / 2)
        hi = np.minimum(np.maximum(hi, xy.max(axis=(0, 1)) + pad), hi + span / 2)
    tall = (hi[1] - lo[1]) > 2.5 * (hi[0] - lo[0])
    across, up = (1, 0) if tall else (0, 1)
    if tall:
        fig, axes = plt.subplots(len(runs), 1, figsize=(10.0, 2.4 * len(runs) + 0.8),
                                 squeeze=False)
        axes = axes[:, 0]
    else:
        fig, axes = plt.subplots(1, len(runs), figsize=(3.8 * len(runs), 5.0), squeeze=False)
        axes = axes[0]
    length = _unit(ctx.experiment.length_unit)
    names = ("x", "y")
    for ax, (scheme, target) in zip(axes, runs):
        result = ctx.run(scheme, target)
        style = _STYLE[scheme]
        for b in range(xy_fine.shape[1]):
            ax.plot(xy_fine[:, b, across], xy_fine[:, b, up], color="0.6", linewidth=0.5,
                    zorder=0)
        reached = wanted[wanted <= result.t[-1]]
        idx = np.unique(np.abs(result.t[None, :] - reached[:, None]).argmin(axis=1))
        xy_run = bodies(result.u[idx])
        xy_ref = bodies(ref.at(result.t[idx])[0])
        for k in range(idx.size):
            ax.plot(xy_ref[k, :, across], xy_ref[k, :, up], marker="o", markersize=3,
                    label="reference (IDA)" if k == 0 else None, zorder=1,
                    **_REFERENCE_STYLE)
            ax.plot(xy_run[k, :, across], xy_run[k, :, up], linestyle="--", linewidth=1.0,
                    marker=style["marker"], markersize=4, markerfacecolor="none",
                    color=style["color"], label="run" if k == 0 else None, zorder=2)
        ax.set_title(run_label(scheme, target, result.stats.mean_step), fontsize=8)
        ax.set_xlim(lo[across], hi[across])
        # Rotated, not mirrored, when y runs across: x then points down, so
        # the bodies keep their sense of rotation.
        ax.set_ylim(*((hi[up], lo[up]) if tall else (lo[up], hi[up])))
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(names[across] + length)
        ax.set_ylabel(names[up] + length)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(title + ("\ndrawn turned by 90° (y across, x down)" if tall else ""),
                 fontsize=10)
    fig.tight_layout()
    return fig


def _energy_increments(ctx: ProblemRuns, runs, title):
    fig, ax = _figure()
    unit = _unit(ctx.experiment.energy_unit)
    for scheme, target in runs:
        result = ctx.run(scheme, target)
        style = _STYLE[scheme]
        ax.plot(result.t[1:], result.energy_increment[1:], linestyle="-", linewidth=0.7,
                marker=style["marker"], markersize=3, color=style["color"],
                label=run_label(scheme, target, result.stats.mean_step))
    ax.axhline(0.0, color="black", linewidth=0.5)
    ax.set_xlabel(_time_label())
    ax.set_ylabel(r"$\Delta E_n$ per step (Eq. 40)" + unit)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    return _finish(fig, ax)


def _symlog_if_spiky(ax, values, label):
    """A symmetric log y scale when a few values dwarf the rest (the articulated
    system's load phase against its free flight), so that both show."""
    v = np.abs(np.concatenate(values)) if values else np.zeros(0)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size and v.max() > 30.0 * np.percentile(v, 90):
        linthresh = 10.0 ** np.floor(np.log10(np.percentile(v, 50)))
        ax.set_yscale("symlog", linthresh=linthresh)
        label += f" (symlog, linear below {linthresh:.0e})"
    ax.set_ylabel(label)


def _long_energy(ctx: ProblemRuns, title, relative_to_kinetic=False):
    """``ΔE/W`` of long HFDI runs; with ``relative_to_kinetic`` also ``ΔE/T``."""
    panels = 2 if relative_to_kinetic else 1
    fig, axes = plt.subplots(panels, 1, figsize=(7.0, 3.2 * panels + 0.8), sharex=True,
                             squeeze=False)
    axes = axes[:, 0]
    drawn = [[] for _ in axes]
    for k, target in enumerate(ctx.long_targets()):
        result = ctx.run("hfdi", target, ctx.long_t_end)
        color = _TARGET_COLORS[k % len(_TARGET_COLORS)]
        label = rf"$\bar N$ = {target:.1f} ($\Delta t_{{mv}}$ = {result.stats.mean_step:.2g})"
        t, de = result.t[1:], result.energy_increment[1:]
        with np.errstate(divide="ignore", invalid="ignore"):
            w = result.total_energy[1:]
            drawn[0].append(np.where(w != 0.0, de / w, np.nan))
            if relative_to_kinetic:
                kin = kinetic_energy(ctx.model, result.v[1:])
                drawn[1].append(np.where(kin > 0, de / kin, np.nan))
        for ax, values in zip(axes, drawn):
            ax.plot(t, values[-1], linewidth=0.7, color=color, label=label)
    labels = [r"$\Delta E_n / W_n$ [-]", r"$\Delta E_n / T_n$ (kinetic) [-]"]
    for ax, values, label in zip(axes, drawn, labels):
        _symlog_if_spiky(ax, values, label)
        ax.axhline(0.0, color="black", linewidth=0.5)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    axes[-1].set_xlabel(_time_label())
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _step_sizes(ctx: ProblemRuns, title):
    fig, ax = _figure()
    for k, target in enumerate(ctx.table_targets("hfdi")):
        result = ctx.run("hfdi", target)
        color = _TARGET_COLORS[k % len(_TARGET_COLORS)]
        ax.semilogy(result.t[1:], result.step_size[1:], linewidth=0.8, marker=".",
                    markersize=2, color=color,
                    label=rf"$\bar N$ = {target:.1f} ({result.stats.steps} steps)")
    ax.set_xlabel(_time_label())
    ax.set_ylabel(r"step size $\Delta t_n$ [s]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    return _finish(fig, ax)


# -- the figures of each problem ------------------------------------------------------------

@dataclass
class FigureSpec:
    """One figure of a problem.

    Attributes
    ----------
    name : str
        File name, stating the paper's figure (``dumbbell_fig09_eps_u.png``).
    paper : str
        The paper's figure it reproduces, or of which it is the analogue.
    caption : str
        What it shows, for the report.
    make : callable
        ``make(ctx) -> matplotlib.figure.Figure``.
    """

    name: str
    paper: str
    caption: str
    make: Callable


def _analogue(number: int) -> str:
    return f"not in the paper; its analogue is paper Fig. {number} ({FIGURE_SUBJECTS[number]})"


def _runs_text(runs) -> str:
    return ", ".join(run_label(s, t, plain=True) for s, t in runs)


def _eps_specs(ctx: ProblemRuns) -> list:
    specs = []
    title_p = ctx.experiment.title
    names = list(ctx.experiment.eps_figures)
    for name in ctx.model.quantities(np.zeros(1), ctx.model.initial_displacement[None],
                                     ctx.model.initial_velocity[None]):
        if name not in names:
            names.append(name)
    for name in names:
        number = ctx.experiment.eps_figures.get(name, 9)
        own = name in ctx.experiment.eps_in_paper
        paper = f"paper Fig. {number}" if own else _analogue(number)
        words = ctx.experiment.quantity(name).words
        title = (f"{title_p}: error ε of the {words} against the mean step\n"
                 f"t = 0..{ctx.t_end:g} s ({'paper' if own else 'as paper'} Fig. {number})")
        caption = (f"{title_p}: error norm ε (Eq. 42) of the {words} against the mean step "
                   f"Δt_mv, log–log, one line per scheme over the table's targets (labels "
                   f"N̄; Bathe's Δt_mv spans both sub-steps); reference IDA rtol 1e-12.")
        specs.append(FigureSpec(
            f"{ctx.problem}_fig{number:02d}_eps_{name}.png", paper, caption,
            lambda c, name=name, title=title: eps_figure(c.records(), name, title)))
    return specs


def _step_spec(ctx: ProblemRuns) -> FigureSpec:
    number = ctx.experiment.step_figure
    own = ctx.experiment.step_in_paper
    title_p = ctx.experiment.title
    title = (f"{title_p}: adaptive step size of HFDI for several targets "
             f"({'paper' if own else 'cf. paper'} Fig. {number})")
    return FigureSpec(f"{ctx.problem}_fig{number:02d}_step_size.png",
                      f"paper Fig. {number}" if own else _analogue(number),
                      f"{title_p}: HFDI step size Δt_n against time for each table target "
                      "(log scale).", lambda c: _step_sizes(c, title))


def _dumbbell_specs(ctx):
    shown = ctx.experiment.shown_runs["trajectory"]
    energy = ctx.experiment.shown_runs["energy"]

    def bodies(u):
        return np.asarray(u).reshape(-1, 2, 2)

    return [
        FigureSpec("dumbbell_fig04_configurations.png", "paper Fig. 4",
                   "Dumbbell: both masses in the x–y plane (a long flight drawn turned by 90°, y "
                   "across and x down) "
                   "at the runs' step times nearest to "
                   f"t = 0, {ctx.t_end / 10:g}, …, {ctx.t_end:g}; reference (IDA) solid at the "
                   f"same times, its paths grey; runs {_runs_text(shown)}.",
                   lambda c: _configurations(c, shown, bodies, "Dumbbell: sequence of "
                                             "configurations; reference solid (paper Fig. 4)")),
        FigureSpec("dumbbell_fig05_stretch.png", "paper Fig. 5",
                   f"Dumbbell: stretch λ = (r − r₀)/r₀ against time; reference solid; runs "
                   f"{_runs_text(shown)}.",
                   lambda c: _time_series(c, shown, _quantity_extractor("stretch", 0),
                                          r"stretch $\lambda = (r - r_0)/r_0$ [-]",
                                          "Dumbbell: stretch; reference solid (paper Fig. 5)")),
        FigureSpec("dumbbell_fig06_energy_increment.png", "paper Fig. 6",
                   f"Dumbbell: energy increment ΔE_n of each step (Eq. 40); runs "
                   f"{_runs_text(energy)}.",
                   lambda c: _energy_increments(c, energy, "Dumbbell: increment of the total "
                                                "energy per step (paper Fig. 6)")),
        FigureSpec("dumbbell_fig07_energy_ratio_long.png", "paper Fig. 7",
                   f"Dumbbell: ΔE_n/W_n of HFDI over t = 0…{ctx.long_t_end:g} for several "
                   "targets (top), and ΔE_n/T_n relative to the kinetic energy (bottom): "
                   "W = V + T is dominated by the large negative constant part of the bond "
                   "potential V (W ≈ −1.86·10⁵ against T = 62.5), which makes ΔE/W look "
                   "tiny.",
                   lambda c: _long_energy(c, "Dumbbell: normalised energy increments of HFDI, "
                                          f"t = 0..{c.long_t_end:g} (paper Fig. 7)\n"
                                          "bottom: relative to the kinetic energy T, since "
                                          "W = V + T is dominated by a large negative V",
                                          relative_to_kinetic=True)),
    ]


def _tetrahedra_specs(ctx):
    shown = ctx.experiment.shown_runs["trajectory"]

    def f12(z):
        return np.linalg.norm(z[:, 0:3], axis=1)

    return [
        FigureSpec("tetrahedra_fig12_body1_xy.png", "paper Fig. 12",
                   "Tetrahedra: positions of body 1 in the x–y plane at every step; reference "
                   f"path solid; runs {_runs_text(shown)}.",
                   lambda c: _body_path(c, shown, 0, 1, "Tetrahedra: body 1 in the x–y plane, "
                                        f"t = 0..{c.t_end:g}; reference solid (paper Fig. 12)")),
        FigureSpec("tetrahedra_fig13_f12.png", "paper Fig. 13",
                   f"Tetrahedra: magnitude |f¹²| of the interaction force between bodies 1 and "
                   f"2 against time; reference solid; runs {_runs_text(shown)}.",
                   lambda c: _time_series(c, shown, _quantity_extractor("f", reduce=f12),
                                          r"$|\mathbf{f}^{12}|$",
                                          "Tetrahedra: interaction force f¹² (magnitude); "
                                          "reference solid (paper Fig. 13)")),
    ]


def _articulated_specs(ctx):
    config = ctx.experiment.shown_runs["configuration"]
    shown = ctx.experiment.shown_runs["trajectory"]
    energy = ctx.experiment.shown_runs["energy"]

    def bodies(u):
        return np.asarray(u).reshape(-1, 3, 2)

    return [
        FigureSpec("articulated_fig15_configurations.png", "paper Fig. 15",
                   "Articulated system: the three masses and both links at the runs' step "
                   f"times nearest to t = 0, {ctx.t_end / 10:g}, …, {ctx.t_end:g}; reference "
                   f"(IDA) solid at the same times; runs {_runs_text(config)}.",
                   lambda c: _configurations(c, config, bodies,
                                             "Articulated system: sequence of configurations; "
                                             "reference solid (paper Fig. 15)")),
        FigureSpec("articulated_fig16_delta_alpha.png", "paper Fig. 16",
                   f"Articulated system: relative angle Δα = α¹² − α²³ against time; reference "
                   f"solid; runs {_runs_text(shown)}.",
                   lambda c: _time_series(c, shown, _quantity_extractor("delta_alpha", 0),
                                          r"$\Delta\alpha = \alpha^{12} - \alpha^{23}$ [rad]",
                                          "Articulated system: relative angle; reference solid "
                                          "(paper Fig. 16)")),
        FigureSpec("articulated_fig17_energy_increment.png", "paper Fig. 17",
                   f"Articulated system: energy increment ΔE_n of each step (Eq. 40); runs "
                   f"{_runs_text(energy)}.",
                   lambda c: _energy_increments(c, energy, "Articulated system: increment of "
                                                "the total energy per step (paper Fig. 17)")),
        FigureSpec("articulated_fig18_energy_ratio_long.png", "paper Fig. 18",
                   f"Articulated system: ΔE_n/W_n of HFDI over t = 0…{ctx.long_t_end:g} for "
                   "several targets (W = 0 at the start, at rest: the first step is left out; "
                   "a symmetric log scale when the load phase dwarfs the free flight).",
                   lambda c: _long_energy(c, "Articulated system: normalised energy increments "
                                          f"of HFDI, t = 0..{c.long_t_end:g} (paper Fig. 18)")),
    ]


def _toss_rule_specs(ctx):
    shown = ctx.experiment.shown_runs["trajectory"]
    return [
        FigureSpec("toss_rule_fig23_alpha_t_mv.png", "paper Fig. 23",
                   "Toss rule: mean angular velocity α_t,mv against time; reference solid; "
                   f"runs {_runs_text(shown)} (the paper does not name its runs).",
                   lambda c: _time_series(c, shown, _quantity_extractor("alpha_t_mv", 0),
                                          r"$\alpha_{t,mv}$ [rad/s]",
                                          "Toss rule: mean angular velocity; reference solid "
                                          "(paper Fig. 23)")),
        FigureSpec("toss_rule_fig24_N_c.png", "paper Fig. 24",
                   "Toss rule: axial force N_c = EAε at the centre against time; reference "
                   f"solid; runs {_runs_text(shown)}.",
                   lambda c: _time_series(c, shown, _quantity_extractor("N_c", 0),
                                          r"$N_c = EA\varepsilon$ at the centre [N]",
                                          "Toss rule: central axial force; reference solid "
                                          "(paper Fig. 24)")),
    ]


_PROBLEM_SPECS = {"dumbbell": _dumbbell_specs, "tetrahedra": _tetrahedra_specs,
                  "articulated": _articulated_specs, "toss_rule": _toss_rule_specs}


def figure_specs(ctx: ProblemRuns) -> list:
    """Every figure of ``ctx``'s problem, in the paper's order; computes nothing."""
    specs = _eps_specs(ctx) + [_step_spec(ctx)] + _PROBLEM_SPECS.get(ctx.problem,
                                                                      lambda c: [])(ctx)
    return sorted(specs, key=lambda s: s.name)


def write_figures(ctx: ProblemRuns, out, skip_existing=False, exists=None, write=None) -> list:
    """Write every figure of ``ctx``'s problem into the directory ``out``.

    Parameters
    ----------
    ctx : ProblemRuns
    out : str or Path
    skip_existing : bool
        Leave a PNG that already exists alone (to resume an interrupted run).
    exists : callable, optional
        ``exists(path)``: whether a figure counts as existing (default
        ``path.exists()``); lets a worker that cannot see ``out`` skip what
        the caller found there.
    write : callable, optional
        ``write(path, png_bytes)``; default: written atomically into ``out``
        (created).

    Returns
    -------
    list of (FigureSpec, Path, str)
        The status is ``"written"`` or ``"skipped"``.
    """
    out = Path(out)
    if write is None:
        out.mkdir(parents=True, exist_ok=True)
        write = write_output
    exists = exists or Path.exists
    done = []
    for spec in figure_specs(ctx):
        path = out / spec.name
        if skip_existing and exists(path):
            ctx.progress.say(f"figure {path}: exists, skipped")
            done.append((spec, path, "skipped"))
            continue
        start = time.perf_counter()
        write(path, figure_png(spec.make(ctx)))
        ctx.progress.say(f"figure {path} ({time.perf_counter() - start:.1f} s)")
        done.append((spec, path, "written"))
    return done
