"""Reproduction of the paper's Figure 2 on ``MixedTraffic-v0``, over several seeds (paper §4).

One command runs the four panels and the sweeps that go beyond the paper::

    python -m experiments fig2                  # 5 seeds, full budget (estimate printed at start)
    python -m experiments fig2 --quick --seeds 1  # tiny budget, a smoke test (a minute or two)

Per seed ``s`` the runner does, building on :mod:`sb3_ua2c.offline` and :mod:`sb3_ua2c.pipeline`:

* (a), (b) **offline**: one dataset; the chunk policy (``chunk_size=k``) and the one-step
  baseline (``chunk_size=1``) are pre-trained on it with the same number of gradient steps and
  evaluated on the same scenarios (reward, cumulative jerk). The offline chunk policy executes
  its chunks in full (δ = inf): adaptive execution is the Phase-2 mechanism, compared in (c).
* (c) **online**: adaptive (finite δ) and fixed (δ = inf) execution, both fine-tuned from the
  SAME chunk checkpoint of (a) with the same number of online steps, evaluated on the same
  scenarios with their own execution rule.
* (d) **driving style**: a labelled slot dataset, the Transformer classifier of Eq. 5 and its
  evaluation on held-out episodes (:func:`envs.style.evaluate_style_classifier`); the panel
  shows the confusion matrix summed over seeds (rows inferred, columns ground truth).
* sweeps: δ (the fine-tuned adaptive checkpoint executed with several thresholds: mean executed
  length ``L_t`` vs reward), k (pre-training with several chunk lengths, same gradient budget)
  and the style context c_t (Eq. 6) appended to the observation vs not (own dataset, same
  pre-training and online budgets as the adaptive arm).

Every unit of work is a file, written atomically: the dataset ``<work>/seed<s>/dataset``, the
checkpoints ``<work>/seed<s>/*.zip`` and the per-seed raw results ``<raw>/seed<s>/*.json``.
A unit whose file exists is skipped, so an interrupted run resumes where it stopped and a second
call only rebuilds the report.

Relative changes. Rewards may be negative, so a relative change is taken with respect to the
magnitude of the baseline: ``100 · (new − base) / |base|`` (:func:`relative_change_pct`).
The headline figures apply it to the means over seeds; the table also gives the per-seed changes'
mean and 95% confidence interval. Confidence intervals are Student-t intervals over seeds
(:func:`t_confidence_interval`), ``mean ± t_{0.975, n−1} · sd / √n``.

The package, by role (import each name from the module that defines it):

* :mod:`~experiments.common.names`: method names and labels, seed ranges, the paper's numbers
* :mod:`~experiments.fig2.budget`: :class:`Fig2Budget`, ``FULL_BUDGET``, ``QUICK_BUDGET``, :class:`CostModel`
* :mod:`~experiments.common.stats`: Student-t intervals and relative changes over seeds
* :mod:`~experiments.fig2.manifest`: the run's directories and the budget manifest of a resumed run
* :mod:`~experiments.fig2.units`: the units of work, their scheduler and lock
* :mod:`~experiments.fig2.aggregation`: per-seed raw results -> ``fig2.json``
* :mod:`~experiments.fig2.report` and :mod:`~experiments.fig2.plots`: ``fig2.md`` and the panels
* :mod:`~experiments.fig2.cli`: the command line
"""
