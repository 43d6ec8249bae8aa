"""Where a Figure-2 run keeps its files and budget (:class:`RunPaths`)."""

from __future__ import annotations

from experiments.common import records
from experiments.fig2.budget import Fig2Budget

#: Budget fields that change what an existing unit holds; the sweeps may grow between calls.
UNIT_FIELDS = ("dataset_episodes", "pretrain_steps", "finetune_steps", "eval_episodes", "chunk_size",
               "entropy_threshold", "style_episodes", "style_max_epochs", "env_kwargs", "algo_kwargs",
               "onestep_kwargs", "finetune_kwargs", "online_seed_offset")


class RunPaths(records.RunPaths):
    NAME = "fig2"
    BUDGET = Fig2Budget
    FIELDS = UNIT_FIELDS
