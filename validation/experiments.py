"""The experiments of the paper's Section 5, one record per benchmark.

This is the one place where the paper's facts live: the observation time
``T_o`` of each benchmark, the longer interval of its energy figures, its
target iteration counts per scheme, its table (steps, mean iterations N_mv,
mean step Δt_mv and CPU time t_T), the runs its figures draw and how
validation labels its quantities. The models of :mod:`hfdi.models` carry none
of it: a model is mechanics; an experiment is what the paper did with it.

A fifth benchmark is one model file in ``hfdi/models/`` (registered there)
and one :class:`Experiment` in :data:`EXPERIMENTS`; the tables, the error
figures, the step-size figure and the report follow from the record.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import hfdi

__all__ = ["Experiment", "Quantity", "EXPERIMENTS", "experiment", "names", "paper_row",
           "ENERGY_LIMIT", "SCHEME_ORDER", "PAPER_SCHEMES", "OTHER_SCHEME_TARGETS",
           "SchemeStyle", "SCHEME_COLOURS", "FIGURE_SUBJECTS"]

#: Every scheme of the library, in the order of its registry (:data:`hfdi.SCHEMES`):
#: the paper's three first, then the others. Outputs list schemes in this order,
#: and ``--schemes`` chooses from it.
SCHEME_ORDER = tuple(hfdi.SCHEMES)

#: The schemes of the paper's tables (:data:`hfdi.PAPER_SCHEMES`): the default
#: of every command that reproduces the paper.
PAPER_SCHEMES = tuple(hfdi.PAPER_SCHEMES)

#: Target iteration counts of a table run of a scheme the paper did not run
#: (generalized-α): the range 3 to 5 of the paper's Tables 2, 4 and 5. The
#: paper's own targets stay defined for its schemes only (``Experiment.targets``).
OTHER_SCHEME_TARGETS = (3.0, 3.5, 4.0, 4.5, 5.0)


class SchemeStyle(Mapping):
    """A style per scheme (a colour, a marker, a line), taken from the scheme's
    place in :data:`hfdi.SCHEMES` and never a ``KeyError``.

    ``values[i]`` styles the ``i``-th scheme of the registry (cycling when
    there are more schemes than values); a name the registry does not know
    gets ``fallback``. A scheme added to the library is drawn without an
    entry here.
    """

    def __init__(self, values, fallback):
        self.values = tuple(values)
        self.fallback = fallback
        if not self.values:
            raise ValueError("SchemeStyle needs at least one value")

    def __getitem__(self, scheme):
        if scheme in SCHEME_ORDER:
            return self.values[SCHEME_ORDER.index(scheme) % len(self.values)]
        return self.fallback

    def __iter__(self):
        return iter(SCHEME_ORDER)

    def __len__(self):
        return len(SCHEME_ORDER)


#: One colour per scheme, in every figure (paper's tables, stability, benchmarks):
#: Newmark blue, Bathe orange, HFDI green, generalized-α red.
SCHEME_COLOURS = SchemeStyle(("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple",
                              "tab:brown", "tab:pink", "tab:olive", "tab:cyan"), "tab:gray")

#: A run is reported "div" when a guard of the integrator stops it (step below
#: its minimum, halvings exhausted) or when its energy balance breaks down: the
#: spurious energy Σ ΔE (Eq. 40) exceeds this fraction of the run's energy
#: scale (see ``hfdi.Integrator``'s ``energy_limit``).
ENERGY_LIMIT = 0.5


@dataclass(frozen=True)
class Quantity:
    """How the figures and the report name a quantity of interest.

    Attributes
    ----------
    symbol : str
        Mathtext symbol (``r"\\lambda"``).
    unit : str
        Unit on axis labels; ``""`` when the model leaves it unnamed.
    words : str
        The quantity in words, for titles and captions.
    """

    symbol: str
    unit: str
    words: str


def _rows(targets, mean_step, steps, mean_iterations, cpu):
    return {t: (None if s is None else {"mean_step": d, "steps": s, "mean_iterations": n,
                                        "cpu_time": c})
            for t, d, s, n, c in zip(targets, mean_step, steps, mean_iterations, cpu)}


PAPER_TABLES = {
    "dumbbell": {  # Table 2, T_o = 2
        "newmark": _rows((3.0, 3.5, 4.0, 4.5, 5.0), (0.0058, 0.0097, 0.014, None, None),
                         (340, 205, 145, None, None), (3.068, 3.561, 4.124, None, None),
                         (0.947, 0.627, 0.489, None, None)),
        "bathe": _rows((3.0, 3.5, 4.0, 4.5, 5.0), (0.0081, 0.018, 0.028, 0.040, 0.069),
                       (246, 113, 73, 51, 29), (6.008, 6.982, 7.918, 8.882, 9.586),
                       (1.22, 0.622, 0.439, 0.334, 0.201)),
        "hfdi": _rows((3.0, 3.1, 3.2, 3.3, 3.5), (0.020, 0.027, 0.039, 0.045, 0.053),
                      (101, 76, 52, 45, 39), (2.960, 2.987, 2.981, 3.044, 3.282),
                      (0.317, 0.240, 0.164, 0.144, 0.131)),
    },
    "tetrahedra": {  # Table 3, T_o = 50
        "newmark": _rows((3.0, 3.5, 4.0, 4.5), (0.14, 0.18, 0.22, 0.16), (355, 284, 224, 309),
                         (3.014, 3.560, 4.058, 4.518), (3.882, 3.608, 3.196, 4.892)),
        "bathe": _rows((3.0, 3.5, 4.0, 4.5), (0.079, 0.20, 0.31, 0.46), (635, 253, 164, 108),
                       (6.024, 7.036, 8.067, 9.120), (13.51, 6.213, 4.576, 3.382)),
        "hfdi": _rows((3.0, 3.5, 4.0, 4.5), (0.20, 0.25, 0.29, 0.34), (252, 200, 170, 148),
                      (3.008, 3.535, 4.100, 4.635), (3.450, 3.180, 3.102, 3.030)),
    },
    "articulated": {  # Table 4, T_o = 0.5
        "newmark": _rows((3.0, 3.5, 4.0, 4.5, 5.0), (0.0012, 0.0017, 0.0025, 0.0028, None),
                         (410, 296, 200, 181, None), (3.083, 3.520, 4.050, 4.580, None),
                         (1.54, 1.23, 0.925, 0.923, None)),
        "bathe": _rows((3.0, 3.5, 4.0, 4.5, 5.0), (0.00099, 0.0027, 0.0039, 0.0064, 0.011),
                       (508, 188, 126, 78, 45), (5.988, 6.968, 8.067, 8.961, 9.977),
                       (3.48, 1.45, 1.09, 0.742, 0.469)),
        "hfdi": _rows((3.0, 3.5, 4.0, 4.5, 5.0), (0.0024, 0.0053, 0.0068, 0.0079, 0.010),
                      (205, 96, 75, 63, 51), (2.961, 3.406, 3.920, 4.460, 5.020),
                      (0.922, 0.482, 0.422, 0.395, 0.353)),
    },
    "toss_rule": {  # Table 5, T_o = 0.1
        "newmark": _rows((3.0, 3.5, 4.0, 4.5, 5.0),
                         (0.000069, 0.000092, 0.00013, 0.00014, 0.00013),
                         (1453, 1090, 765, 722, 763), (3.003, 3.537, 4.031, 4.528, 5.012),
                         (32.1, 28.4, 22.7, 24.0, 28.1)),
        "bathe": _rows((3.0, 3.5, 4.0, 4.5, 5.0),
                       (0.000052, 0.00012, 0.00022, 0.00032, 0.00045),
                       (1930, 803, 461, 316, 223), (6.007, 6.995, 8.004, 9.016, 9.982),
                       (85.3, 41.3, 27.1, 20.9, 16.3)),
        "hfdi": _rows((3.0, 3.5, 4.0, 4.5, 5.0),
                      (0.00011, 0.00018, 0.00021, 0.00025, 0.00029),
                      (933, 568, 473, 400, 339), (2.996, 3.532, 4.017, 4.480, 5.044),
                      (25.7, 18.4, 17.4, 16.4, 15.7)),
    },
}


@dataclass(frozen=True)
class Experiment:
    """One benchmark of the paper: a model and what the paper did with it.

    Attributes
    ----------
    name : str
        The model's name in :func:`hfdi.models.get`.
    title : str
        As the report and the figures head it.
    table : int
        The paper's table of the benchmark.
    observation_time : float
        ``T_o`` of the table runs.
    long_observation_time : float or None
        End of the long energy runs (Figs. 7 and 18); ``T_o`` when ``None``.
    targets : mapping of str to tuple of float
        The paper's target iteration counts per scheme of its tables (per
        sub-step for Bathe, which the paper writes ``2·N̄``); another
        scheme's table runs take :data:`OTHER_SCHEME_TARGETS`
        (:meth:`table_targets`).
    paper : mapping
        The paper's table: scheme → target → ``{"mean_step", "steps",
        "mean_iterations", "cpu_time"}``, or ``None`` for a run it reports
        as "div".
    shown_runs : mapping of str to tuple of (scheme, target)
        The runs the paper draws in its trajectory, energy and configuration
        figures, per figure kind.
    eps_figures : mapping of str to int
        The paper's figure number of the error norm of each quantity (an
        analogue's number when the paper shows it for another benchmark).
    eps_in_paper : tuple of str
        The quantities whose error figure the paper itself shows.
    step_figure : int
        The number of the step-size figure (11 or 22).
    step_in_paper : bool
        Whether the paper shows the step sizes of this benchmark.
    quantities : mapping of str to Quantity
        How validation labels each quantity of interest.
    length_unit, energy_unit : str
        Units of positions and energies on axis labels (``""``: unnamed).
    cost : float
        Relative CPU time of the benchmark's outputs in ``all``: parallel
        tasks are submitted longest first. Affects when they run, never what
        they compute.
    """

    name: str
    title: str
    table: int
    observation_time: float
    targets: Mapping[str, tuple]
    paper: Mapping
    long_observation_time: float | None = None
    shown_runs: Mapping[str, tuple] = field(default_factory=dict)
    eps_figures: Mapping[str, int] = field(default_factory=dict)
    eps_in_paper: tuple = ()
    step_figure: int = 11
    step_in_paper: bool = False
    quantities: Mapping[str, Quantity] = field(default_factory=dict)
    length_unit: str = ""
    energy_unit: str = ""
    cost: float = 0.5

    @property
    def long_time(self) -> float:
        """End of the long energy runs: ``long_observation_time`` or ``T_o``."""
        return float(self.long_observation_time or self.observation_time)

    def table_targets(self, scheme: str) -> tuple:
        """The target iteration counts of the table runs of ``scheme``: the
        paper's for a scheme of its table, :data:`OTHER_SCHEME_TARGETS` for
        another scheme of :data:`hfdi.SCHEMES` (the paper has no numbers to
        compare those runs with); ``ValueError`` naming the schemes for a name
        the library does not know."""
        if scheme in self.targets:
            return tuple(float(t) for t in self.targets[scheme])
        if scheme in SCHEME_ORDER:
            return OTHER_SCHEME_TARGETS
        raise ValueError(f"unknown scheme {scheme!r}; available: {', '.join(SCHEME_ORDER)}")

    def model(self, **params):
        """A new model of this benchmark, with ``params`` for its constructor."""
        return hfdi.models.get(self.name, **params)

    def quantity(self, name: str) -> Quantity:
        """How ``name`` is labelled (its own name when the record has no label)."""
        return self.quantities.get(name) or _QUANTITIES.get(name) or Quantity(name, "", name)


#: Labels shared by every benchmark whose quantity ``u`` is its displacements.
_QUANTITIES = {"u": Quantity(r"\mathbf{u}", "", "displacements u")}

_PAPER_ORDER = (3.0, 3.5, 4.0, 4.5, 5.0)

EXPERIMENTS = {
    "dumbbell": Experiment(
        "dumbbell", "Dumbbell", table=2, observation_time=2.0, long_observation_time=10.0,
        targets={"newmark": _PAPER_ORDER, "bathe": _PAPER_ORDER,
                 "hfdi": (3.0, 3.1, 3.2, 3.3, 3.5)},
        paper=PAPER_TABLES["dumbbell"],
        # the runs the paper's text names for Figs. 4-6
        shown_runs={"trajectory": (("newmark", 4.5), ("bathe", 4.5), ("hfdi", 3.3)),
                    "energy": (("newmark", 4.5), ("bathe", 4.5), ("hfdi", 3.3))},
        eps_figures={"u": 9, "stretch": 10},
        quantities={"stretch": Quantity(r"\lambda", "-", "stretch λ")},
        cost=1.0),
    "tetrahedra": Experiment(
        "tetrahedra", "Tetrahedra", table=3, observation_time=50.0,
        targets={s: (3.0, 3.5, 4.0, 4.5) for s in PAPER_SCHEMES},
        paper=PAPER_TABLES["tetrahedra"],
        shown_runs={"trajectory": (("bathe", 4.0), ("hfdi", 4.0))},      # Figs. 12-13
        eps_figures={"u": 9, "f": 10}, eps_in_paper=("u", "f"),
        step_figure=11, step_in_paper=True,
        quantities={"f": Quantity(r"\mathbf{f}", "", "interaction forces f")},
        cost=0.75),
    "articulated": Experiment(
        "articulated", "Articulated system", table=4, observation_time=0.5,
        long_observation_time=3.0,
        targets={s: _PAPER_ORDER for s in PAPER_SCHEMES},
        paper=PAPER_TABLES["articulated"],
        shown_runs={"configuration": (("newmark", 5.0), ("bathe", 5.0), ("hfdi", 5.0)),
                    "trajectory": (("bathe", 4.5), ("hfdi", 4.0)),       # Figs. 15-17
                    "energy": (("bathe", 4.5), ("hfdi", 4.0))},
        eps_figures={"u": 9, "delta_alpha": 10},
        quantities={"delta_alpha": Quantity(r"\Delta\alpha", "rad", "relative angle Δα")},
        cost=1.1),
    "toss_rule": Experiment(
        "toss_rule", "Toss rule", table=5, observation_time=0.1,
        targets={s: _PAPER_ORDER for s in PAPER_SCHEMES},
        paper=PAPER_TABLES["toss_rule"],
        # the paper does not name the runs of Figs. 23-24: N̄ = 4.0 for each scheme
        shown_runs={"trajectory": (("newmark", 4.0), ("bathe", 4.0), ("hfdi", 4.0))},
        eps_figures={"alpha_mv": 20, "m_c": 21, "u": 9, "alpha_t_mv": 20, "N_c": 21},
        eps_in_paper=("alpha_mv", "m_c"), step_figure=22, step_in_paper=True,
        quantities={"alpha_mv": Quantity(r"\alpha_{mv}", "rad", "mean rotation α_mv"),
                    "m_c": Quantity(r"m_c", "N·m", "central bending moment m_c"),
                    "alpha_t_mv": Quantity(r"\alpha_{t,mv}", "rad/s",
                                           "mean angular velocity α_t,mv"),
                    "N_c": Quantity(r"N_c", "N", "central axial force N_c")},
        # in SI; the others state frequencies in rad/s (docs/models.md), so their
        # time is in s and their lengths and energies in units the paper leaves unnamed
        length_unit="m", energy_unit="J", cost=1.6),
}


#: What the paper's figures show of which other benchmarks get analogues.
FIGURE_SUBJECTS = {9: "ε of u of the tetrahedra", 10: "ε of f of the tetrahedra",
                   11: "the step sizes of the tetrahedra", 20: "ε of α_mv of the toss rule",
                   21: "ε of m_c of the toss rule", 22: "the step sizes of the toss rule"}


def names() -> list:
    """The benchmarks in the paper's order (Tables 2-5)."""
    return sorted(EXPERIMENTS, key=lambda n: (EXPERIMENTS[n].table, n))


def experiment(name: str) -> Experiment:
    """The record of ``name``; ``ValueError`` naming the known ones otherwise."""
    try:
        return EXPERIMENTS[name]
    except KeyError:
        raise ValueError(f"unknown problem {name!r}; available: "
                         f"{', '.join(names())}") from None


def paper_row(problem: str, scheme: str, target: float):
    """The paper's numbers for one run: a dict, ``None`` for "div", or
    ``KeyError`` when the paper has no such run (a scheme it did not run
    included)."""
    return EXPERIMENTS[problem].paper[scheme][round(float(target), 3)]
