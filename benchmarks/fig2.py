"""Figure 2 of the UA2C paper on MixedTraffic-v0: (a) offline reward and (b) cumulative jerk of
the chunk policy vs the one-step baseline, (c) online reward of adaptive vs fixed chunk
execution, (d) the driving-style confusion matrix, plus the δ, k and style-context sweeps;
N seeds with 95% confidence intervals. Resumable: finished units are skipped.

    python benchmarks/fig2.py                      # 5 seeds, full budget (about two hours on 2 cores)
    python benchmarks/fig2.py --quick --seeds 1    # smoke test (seconds)
    python benchmarks/fig2.py --report-only        # rebuild results/fig2.md from the raw results

The comparisons run our method against its own peers (one-step baseline, fixed execution) on the
same data and budgets, and print relative changes next to the paper's figures.
"""

from __future__ import annotations

import sys

import torch

from sb3_ua2c.experiments import main

if __name__ == "__main__":
    torch.set_num_threads(1)
    sys.exit(main())
