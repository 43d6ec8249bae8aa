"""Method names, labels and seed ranges of the Figure-2 runner, and the paper's numbers it is checked against."""

from __future__ import annotations

import math

#: The paper's Fig. 2 figures (one seed), in percent.
PAPER = {"offline_reward_gain_pct": 6.70, "offline_jerk_change_pct": -18.37, "online_reward_gain_pct": 13.17}
#: The comparison behind each of the paper's numbers (``comparisons`` key of ``fig2.json``).
CLAIM_COMPARISONS = {"offline_reward_gain_pct": "offline_reward", "offline_jerk_change_pct": "offline_jerk",
                     "online_reward_gain_pct": "online_reward"}
#: Metrics of :class:`envs.evaluation.EpisodeMetrics` aggregated per method.
METRICS = (
    "reward", "cumulative_jerk", "jerk_per_step", "collision", "merge_success", "mean_speed", "mean_executed_length")
#: fine-tuned arms whose Phase-2 training episodes are logged (``<raw>/online/<arm>.json``)
ONLINE_ARMS = ("fixed", "adaptive", "adaptive_style")
#: The four arms of Fig. 2 (a)-(c).
MAIN_METHODS = ("onestep", "chunk", "fixed", "adaptive")
#: Methods also evaluated with fresh candidate noise per replanning (``Fig2Budget.sampled_eval``).
SAMPLED_METHODS = ("onestep", "chunk", "chunk_adaptive", "fixed", "adaptive", "fixed_adaptive")
#: Row labels of the report's tables, by method name.
METHOD_LABELS = {
    "onestep": "one-step baseline (k=1)",
    "chunk": "chunk policy (offline, full chunks)",
    "chunk_adaptive": "chunk policy (offline, adaptive execution)",
    "fixed": "fixed chunks (δ=inf, online)",
    "adaptive": "adaptive chunks (online)",
    "fixed_adaptive": "fixed-trained checkpoint, adaptive execution",
    "adaptive_style": "adaptive chunks + style context c_t",
}
METHOD_LABELS.update({f"{m}_sampled": f"{METHOD_LABELS[m]}, sampled" for m in SAMPLED_METHODS})

#: Seed offsets: datasets, evaluation scenarios and style data never share a SUMO seed as long as
#: run seeds are < MAX_SEED, episodes per dataset < 10,000 and evaluation episodes <= 1,000.
DATASET_SEED_BASE = 1_000_000  # episode i of run seed s: 1_000_000 + 10_000 s + i
STYLE_SEED_BASE = 3_000_000  # episode i of run seed s: 3_000_000 + 10_000 s + i
EVAL_SEED_BASE = 2_000  # evaluate() resets episode i of seed e with 1000 * e + i -> 2_000_000 + 1000 s + i
#: Evaluation scenarios by role: episode i of run seed s is SUMO scenario 1000 * (base + s) + i.
#: Figure 2's held-out scenarios (``EVAL_SEED_BASE``) served UA2C's earlier choices; new choices are made on
#: the validation scenarios, reported numbers come from the test scenarios.
VALIDATION_SEED_BASE = 3_000
TEST_SEED_BASE = 4_000
SCENARIO_BASES = {"figure2": EVAL_SEED_BASE, "validation": VALIDATION_SEED_BASE, "test": TEST_SEED_BASE}
MAX_SEED = 100


def delta_name(delta: float) -> str:
    """File-name-safe label of a threshold: ``0.5 -> "0.5"``, ``-1 -> "m1"``, ``inf -> "inf"``."""
    return "inf" if math.isinf(delta) else f"{delta:g}".replace("-", "m")


def replicate_name(arm: str, replicate: int) -> str:
    """Unit name of a fine-tuned arm in online phase ``replicate``: ``"fixed"``, ``"fixed_r2"``."""
    return arm if replicate == 0 else f"{arm}_r{replicate}"


def sampled_name(method: str) -> str:
    """Raw-result name of ``method`` evaluated with fresh candidate noise: ``"chunk"`` -> ``"chunk_sampled"``."""
    return f"{method}_sampled"


def acting_name(arm: str, flow_steps: int | None, n_elite: int, default_elite: int) -> str:
    """Method name of an arm acting with ``flow_steps`` (``None``: the checkpoint's) and ``n_elite`` (unnamed when
    the ``default_elite``): ``("chunk", 2, 8, 1) -> "chunk_flow2_elite8"``."""
    elite = "" if n_elite == default_elite else f"_elite{n_elite}"
    return arm + ("" if flow_steps is None else f"_flow{flow_steps}") + elite
