"""Reproduction of the paper's Figure 2 on ``MixedTraffic-v0`` over several seeds (paper §4):
``python -m experiments fig2`` (see ``docs/figure2.md``).

Per seed: (a), (b) the offline chunk policy (whole chunks) against the one-step baseline on one dataset;
(c) adaptive against fixed execution, both fine-tuned from the same chunk checkpoint; (d) the driving-style
classifier of Eq. 5; and the δ, k, acting and style-context sweeps. Every unit of work is a file written
atomically (dataset, checkpoints, per-seed raw results), so a run resumes where it stopped.

By role: :mod:`~experiments.fig2.budget` (budget and estimate), :mod:`~experiments.fig2.manifest` (directories),
:mod:`~experiments.fig2.units` (units and scheduler), :mod:`~experiments.fig2.aggregation` (raw results ->
``fig2.json``), :mod:`~experiments.fig2.report` and :mod:`~experiments.fig2.plots` (``fig2.md``, panels),
:mod:`~experiments.fig2.cli` (the command line).
"""
