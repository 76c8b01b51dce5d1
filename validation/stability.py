"""The paper's Section 3 figures: spectral radius (Fig. 1), period elongation and
amplitude decay (Fig. 2) of the schemes, from :func:`hfdi.spectral.spectral_properties`:
the paper's three by default, any scheme of :data:`hfdi.SCHEMES` when asked
(``hfdi-validate stability --schemes``).
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from hfdi.spectral import spectral_properties

from hfdi.files import write_output
from .experiments import PAPER_SCHEMES, SCHEME_COLOURS, SchemeStyle
from .figures import figure_png, plt
from .runs import Progress, scheme_title

__all__ = ["DEFAULT_RATIOS", "FIGURE_NAMES", "stability_rows", "format_stability_table",
           "spectral_radius_figure", "accuracy_figure", "write_stability"]

#: Δt/T of the printed table.
DEFAULT_RATIOS = (0.01, 0.05, 0.1, 0.2, 0.5, 1.0, 10.0)
FIGURE_NAMES = {"radius": "stability_fig01_spectral_radius.png",
                "accuracy": "stability_fig02_period_elongation_amplitude_decay.png"}
#: Δt/T of the curves: Fig. 1 over six decades (the schemes' high-frequency
#: limits show from Δt/T ≈ 10), Fig. 2 over the range where a step still
#: resolves the period.
_RADIUS_RATIOS = np.logspace(-3, 3, 361)
_ACCURACY_RATIOS = np.linspace(0.0025, 0.5, 200)


def stability_rows(ratios=DEFAULT_RATIOS, schemes=PAPER_SCHEMES) -> list:
    """ρ, PE and AD of each scheme at each ``Δt/T``.

    Returns
    -------
    list of dict
        Keys ``scheme``, ``ratio``, ``spectral_radius``, ``period_elongation``
        and ``amplitude_decay`` (percent; NaN where the amplification matrix
        has no complex pair).
    """
    rows = []
    for scheme in schemes:
        props = spectral_properties(scheme, ratios)
        for k, ratio in enumerate(props.ratio):
            rows.append({"scheme": scheme, "ratio": float(ratio),
                         "spectral_radius": float(props.spectral_radius[k]),
                         "period_elongation": float(props.period_elongation[k]),
                         "amplitude_decay": float(props.amplitude_decay[k])})
    return rows


def _cell(value, digits):
    if value is None or not math.isfinite(value):
        return "-"
    # Round-off leaves Newmark's AD at ±1e-13: print it as the 0 it is.
    text = f"{value:.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def format_stability_table(rows, markdown=False) -> str:
    """The rows of :func:`stability_rows` as a plain-text (or Markdown) table.

    ρ with 6 decimals, PE and AD in percent with 4.
    """
    head = ("scheme", "Δt/T", "ρ", "PE [%]", "AD [%]")
    body = [(scheme_title(r["scheme"]), f"{r['ratio']:g}", _cell(r["spectral_radius"], 6),
             _cell(r["period_elongation"], 4), _cell(r["amplitude_decay"], 4)) for r in rows]
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(cells) + " |" for cells in body]
        return "\n".join(lines)
    widths = [max(len(c[i]) for c in [head, *body]) for i in range(len(head))]
    fmt = [f"{{:<{widths[0]}}}"] + [f"{{:>{w}}}" for w in widths[1:]]
    return "\n".join("  ".join(f.format(c) for f, c in zip(fmt, cells)) for cells in [head, *body])


#: Line style of each scheme's curves (its colour is :data:`SCHEME_COLOURS`').
_LINES = SchemeStyle(("-", "--", "-.", ":"), "-")


def _style(scheme):
    return SCHEME_COLOURS[scheme], _LINES[scheme]


def spectral_radius_figure(schemes=PAPER_SCHEMES):
    """Spectral radius ``ρ(A)`` against ``Δt/T`` on a log x axis (paper Fig. 1)."""
    fig, ax = plt.subplots(figsize=(7.0, 4.5))
    for scheme in schemes:
        props = spectral_properties(scheme, _RADIUS_RATIOS)
        color, style = _style(scheme)
        ax.semilogx(props.ratio, props.spectral_radius, style, color=color,
                    label=scheme_title(scheme))
    ax.set_xlabel(r"$\Delta t / T$ [-]")
    ax.set_ylabel(r"spectral radius $\rho(\mathbf{A})$ [-]")
    ax.set_ylim(-0.02, 1.08)
    ax.set_title("Spectral radii of the approximation operators (paper Fig. 1)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def accuracy_figure(schemes=PAPER_SCHEMES):
    """Period elongation and amplitude decay in percent against ``Δt/T`` (paper Fig. 2)."""
    fig, (ax_pe, ax_ad) = plt.subplots(1, 2, figsize=(10.0, 4.2))
    for scheme in schemes:
        props = spectral_properties(scheme, _ACCURACY_RATIOS)
        color, style = _style(scheme)
        ax_pe.plot(props.ratio, props.period_elongation, style, color=color,
                   label=scheme_title(scheme))
        ax_ad.plot(props.ratio, props.amplitude_decay, style, color=color,
                   label=scheme_title(scheme))
    ax_pe.set_ylabel("period elongation PE [%]")
    ax_ad.set_ylabel("amplitude decay AD [%]")
    for ax in (ax_pe, ax_ad):
        ax.set_xlabel(r"$\Delta t / T$ [-]")
        ax.set_xlim(0.0, _ACCURACY_RATIOS[-1])
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Percentage period elongations and amplitude decays (paper Fig. 2)",
                 fontsize=10)
    fig.tight_layout()
    return fig


def write_stability(out, ratios=DEFAULT_RATIOS, skip_existing=False, progress=None,
                    json_path=None, exists=None, write=None, rows=None,
                    schemes=PAPER_SCHEMES) -> dict:
    """Write the two PNGs into ``out`` and return the table.

    Parameters
    ----------
    out : str or Path
        Directory of the PNGs.
    ratios : sequence of float
        ``Δt/T`` of the table.
    skip_existing : bool
        Leave existing outputs alone (to resume an interrupted run).
    progress : Progress, optional
    json_path : str or Path, optional
        Also write the table's rows there as JSON (read back, not recomputed,
        when it exists and ``skip_existing``).
    exists : callable, optional
        ``exists(path)``: whether an output counts as existing (default
        ``path.exists()``).
    write : callable, optional
        ``write(path, data)``; default: written atomically (``out`` created).
    rows : list of dict, optional
        The table's rows as the caller already read them from ``json_path``
        (with ``skip_existing``): neither recomputed nor written. ``exists``,
        ``write`` and ``rows`` let a worker that cannot see ``out`` make what
        its caller did not find there.
    schemes : sequence of str
        The schemes of the figures and the table (default the paper's three).

    Returns
    -------
    dict
        ``rows`` (see :func:`stability_rows`), ``figures`` (name → path),
        ``table`` (the plain-text table) and ``written`` (the paths written by
        this call).
    """
    progress = progress or Progress(enabled=False)
    out = Path(out)
    if write is None:
        out.mkdir(parents=True, exist_ok=True)
        write = write_output
    exists = exists or Path.exists
    figures, written = {}, []
    schemes = tuple(schemes)
    for key, make in (("radius", spectral_radius_figure), ("accuracy", accuracy_figure)):
        path = out / FIGURE_NAMES[key]
        figures[key] = path
        if skip_existing and exists(path):
            progress.say(f"figure {path}: exists, skipped")
            continue
        start = time.perf_counter()
        write(path, figure_png(make(schemes)))
        written.append(path)
        progress.say(f"figure {path} ({time.perf_counter() - start:.1f} s)")
    if json_path is not None and skip_existing and (rows is not None or exists(Path(json_path))):
        if rows is None:
            rows = json.loads(Path(json_path).read_text())["rows"]
        progress.say(f"stability table {json_path}: exists, skipped")
    if rows is None:
        rows = stability_rows(ratios, schemes)
        if json_path is not None:
            write(Path(json_path), json.dumps({"ratios": list(map(float, ratios)),
                                               "rows": rows}, indent=1))
            written.append(Path(json_path))
            progress.say(f"stability table {json_path}")
    return {"rows": rows, "figures": figures, "table": format_stability_table(rows),
            "written": written}
