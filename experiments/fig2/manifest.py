"""Where a run keeps its files (:class:`RunPaths`) and the budget manifest that refuses to resume a run
under another budget."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from experiments.common.records import check_budget_record
from experiments.fig2.budget import Fig2Budget


@dataclass(frozen=True)
class RunPaths:
    """Where a run keeps its files.

    :param out: report directory (``fig2.md``, ``fig2.json``, PNG panels)
    :param raw: per-seed raw results (small JSON files, worth keeping with the report)
    :param work: datasets and checkpoints (large; not part of the report)
    """

    out: Path
    raw: Path
    work: Path

    @classmethod
    def under(cls, out: str | os.PathLike, raw: str | os.PathLike | None = None,
              work: str | os.PathLike | None = None,) -> RunPaths:
        """Default layout: ``<out>/fig2_raw`` and ``<out>/fig2_work`` unless given."""
        out = Path(out)
        return cls(out, Path(raw) if raw else out / "fig2_raw", Path(work) if work else out / "fig2_work")

    def seed_work(self, seed: int) -> Path:
        return self.work / f"seed{seed}"

    def seed_raw(self, seed: int) -> Path:
        return self.raw / f"seed{seed}"


#: Budget fields that change what an existing unit holds; the sweeps may grow between calls.
UNIT_FIELDS = ("dataset_episodes", "pretrain_steps", "finetune_steps", "eval_episodes", "chunk_size",
               "entropy_threshold", "style_episodes", "style_max_epochs", "env_kwargs", "algo_kwargs",
               "onestep_kwargs", "finetune_kwargs", "online_seed_offset")


MANIFEST = "fig2_budget.json"


def check_manifest(paths: RunPaths, budget: Fig2Budget) -> None:
    """Refuse to resume a run made with another budget (its units would be silently reused), then record
    ``budget`` in ``<work>/fig2_budget.json`` (:func:`~experiments.common.records.check_budget_record`).

    Later calls must agree on :data:`UNIT_FIELDS` (the δ and k sweeps and the style ablation may change:
    they only add units).

    :raises ValueError: naming the fields that differ
    """
    check_budget_record(paths.work / MANIFEST, budget.to_dict(), f"the run in {paths.work}", fields=UNIT_FIELDS,
                        read=lambda stored: Fig2Budget.from_dict(stored).to_dict())


def read_manifest(paths: RunPaths) -> Fig2Budget | None:
    """The budget recorded by the last call on ``paths`` (``None`` if there is none)."""
    path = paths.work / MANIFEST
    if not path.is_file():
        return None
    try:
        return Fig2Budget.from_dict(json.loads(path.read_text()))
    except (json.JSONDecodeError, TypeError, ValueError) as exc:
        raise ValueError(f"{path} is not a Fig2Budget record: {exc}") from exc
