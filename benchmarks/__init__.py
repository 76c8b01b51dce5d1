"""Performance tooling, apart from the paper's validation and not installed.

``python -m benchmarks precision|scale|profile|cosim`` (``make bench`` runs the
first two into ``docs/performance-data``):

* :mod:`benchmarks.precision` — work–precision of our schemes against IDA,
  Radau and BDF;
* :mod:`benchmarks.scale` — cost per Newton iteration and memory of the toss
  rule against its size, and a full run against IDA;
* :mod:`benchmarks.profile` — cost per Newton iteration split into model,
  linear algebra and driver;
* :mod:`benchmarks.cosim` — the FMU through fmpy against the library in-process.

Every run goes through the run driver of :mod:`validation.runs`, every
reference and error norm through :mod:`validation.reference` and
:mod:`validation.errors`, every argument through :mod:`validation.options`.
"""
