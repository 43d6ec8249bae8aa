"""Aggregation and report of the head-to-head: ``peers.json``, ``peers.md`` and the PNGs."""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common import records, stats
from experiments.common.records import figure, section, table
from experiments.peers.budget import ARM_LABELS, ARMS, UA2C_ARMS
from sb3_ua2c.execution import format_length_shares, length_shares

#: Evaluation metrics reported per arm (keys of the evaluation episodes).
METRICS = ("reward", "collision", "merge_success", "cumulative_jerk", "jerk_per_step")
#: Metrics of the probability of improvement.
POI_METRICS = ("reward", "collision", "merge_success", "jerk_per_step")
CURVE_BINS = 20
#: Figure 2's claims (a)-(c) among the UA2C arms: claim -> (arm X, arm Y, metric, evaluation, higher is better).
FIGURE2_CLAIMS = {
    "(a) offline reward, chunks (k = 5) vs one-step": ("ua2c_fixed", "ua2c_onestep", "reward", "offline_evaluation", True),
    "(b) offline cum. jerk, chunks vs one-step": ("ua2c_fixed", "ua2c_onestep", "cumulative_jerk", "offline_evaluation",
                                                 False),
    "(c) online reward, adaptive vs fixed chunks": ("ua2c", "ua2c_fixed", "reward", "evaluation", True),
}


def binned_curve(episodes: Sequence[Mapping[str, Any]], online_steps: int, bins: int = CURVE_BINS) -> np.ndarray:
    """``(bins,)``: one seed's mean online return per bin of env steps (an empty bin repeats the previous one)."""
    width = online_steps / bins
    out = np.full(bins, np.nan)
    ends = np.array([e["end_step"] for e in episodes], dtype=float)
    rewards = np.array([e["reward"] for e in episodes], dtype=float)
    for i in range(bins):
        inside = (ends > i * width) & (ends <= (i + 1) * width)
        if inside.any():
            out[i] = rewards[inside].mean()
        elif i > 0:
            out[i] = out[i - 1]
    return out


def curve_band(per_seed: np.ndarray, reps: int = 2000, seed: int = 0) -> dict[str, list[float]]:
    """Mean over seeds of binned curves ``(n_seeds, bins)`` with a 95 % percentile bootstrap band over seeds."""
    n = per_seed.shape[0]
    rng = np.random.default_rng(seed)
    with np.errstate(all="ignore"), warnings.catch_warnings():  # all-NaN columns before the first episode
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(per_seed, axis=0)
        boot = np.nanmean(per_seed[rng.integers(0, n, size=(reps, n))], axis=1)  # (reps, bins)
        low, high = np.nanpercentile(boot, [2.5, 97.5], axis=0)
    return {"mean": mean.tolist(), "ci_low": low.tolist(), "ci_high": high.tolist()}


def arm_length_shares(records: Sequence[Mapping[str, Any]], evaluation: str = "evaluation") -> list[float] | None:
    """The share of an arm's evaluation plans with ``L_t = 1 .. k`` (``None`` where a record keeps none)."""
    if not all(r.get(evaluation) for r in records):
        return None
    episodes = [e for r in records for e in r[evaluation]["episodes"]]
    lengths = [n for e in episodes for n in e.get("plan_lengths", ())]
    if not lengths or any("plan_lengths" not in e for e in episodes):
        return None
    return length_shares(lengths, int(records[0].get("hyperparams", {}).get("chunk_size", max(lengths))))


def lengths_table(summary: Mapping[str, Any]) -> list[str]:
    """``L_t`` per arm, offline and online (Markdown), or a line saying that the records keep none."""
    rows = [(arm["label"], arm.get("length_shares") or {}) for arm in summary["arms"].values()]
    if not any(shares.get("online") or shares.get("offline") for _, shares in rows):
        return ["Not recorded in these runs (the records keep L_t per plan since 2026-12-04: rerun to see it)."]
    return table(["arm", "offline: L_t = 1..k, % of plans", "online"],
                 ([label, *("–" if shares.get(p) is None else format_length_shares(shares[p])
                            for p in ("offline", "online"))] for label, shares in rows))


def arm_summary(records: Sequence[Mapping[str, Any]], reps: int = 2000) -> dict[str, Any]:
    """IQM and mean with CI of every metric, offline score, learning curve and times of one arm's records."""
    seeds = sorted(r["seed"] for r in records)
    scores = {m: stats.score_matrix(records, m) for m in METRICS}  # metric -> (n_runs, 1)
    offline = ({m: stats.iqm_with_ci({"x": stats.score_matrix(records, m, "offline_evaluation")}, reps=reps)["x"]
                for m in METRICS} if all(r.get("offline_evaluation") for r in records) else None)
    ordered = sorted(records, key=lambda r: r["seed"])
    areas = [stats.learning_curve_area([e["end_step"] for e in r["online_episodes"]],
                                       [e["reward"] for e in r["online_episodes"]])
             if r["online_episodes"] else float("nan") for r in ordered]
    online_steps = int(records[0]["online_steps"])
    curve = None  # an offline-only reference row, or an evaluation variant of another arm, has no curve
    if online_steps > 0 and all(r["online_episodes"] for r in records):
        curves = np.array([binned_curve(r["online_episodes"], online_steps) for r in ordered])
        curve = {"env_steps": [online_steps * (i + 1) / CURVE_BINS for i in range(CURVE_BINS)],
                 **curve_band(curves, reps=reps)}
    wall = [r["wall_seconds"]["total"] for r in records]
    cpu = [r["cpu_seconds"]["total"] for r in records]
    first = records[0]
    training = None  # the online training episodes: one collision rate and one mean reward per run
    if all(r["online_episodes"] and all("collision" in e for e in r["online_episodes"]) for r in records):
        runs = {key: np.array([[np.mean([float(e[key]) for e in r["online_episodes"]])] for r in ordered])
                for key in ("collision", "reward")}  # key -> (n_runs, 1)
        training = {"episodes_per_run": float(np.mean([len(r["online_episodes"]) for r in records])),
                    **stats.mean_with_ci(runs, reps=reps)}
    return {
        "label": ARM_LABELS.get(first["arm"], first["arm"]), "seeds": seeds, "online_steps": online_steps,
        "eval_episodes_per_seed": len(first["evaluation"]["episodes"]), "offline_steps": int(first["offline_steps"]),
        "metrics": stats.iqm_with_ci(scores, reps=reps), "means": stats.mean_with_ci(scores, reps=reps),
        "per_seed": {m: scores[m][:, 0].tolist() for m in METRICS},
        "curve_area": {"per_seed": areas, **(stats.mean_with_ci({"x": np.array(areas)[:, None]}, reps=reps)["x"]
                                             if np.all(np.isfinite(areas)) else {})},
        "offline_metrics": offline, "curve": curve, "training_episodes": training,
        "length_shares": {"offline": arm_length_shares(records, "offline_evaluation"),
                          "online": arm_length_shares(records)},
        "wall_seconds": {"mean_per_seed": float(np.mean(wall)), "total": float(np.sum(wall))},
        "cpu_seconds": {"mean_per_seed": float(np.mean(cpu)), "total": float(np.sum(cpu))},
        "hyperparams": first["hyperparams"], "notes": first["notes"],
    }


def pair_summary(records: Mapping[str, Sequence[Mapping[str, Any]]], ours: str, peer: str,
                 reps: int = 2000) -> dict[str, Any]:
    """``P(ours > peer)`` per metric and, over the seeds both ran, the paired per-seed reward difference."""
    out: dict[str, Any] = {m: stats.probability_of_improvement(
        stats.score_matrix(records[ours], m), stats.score_matrix(records[peer], m),
        higher_is_better=m not in stats.LOWER_IS_BETTER, reps=reps) for m in POI_METRICS}
    scores = shared_seed_scores(records, ours, peer, "reward")
    if scores is not None:
        out["reward_paired"] = stats.paired_difference(*scores)
    return out


def shared_seed_scores(records: Mapping[str, Sequence[Mapping[str, Any]]], x: str, y: str, metric: str,
                       evaluation: str = "evaluation") -> tuple[np.ndarray, np.ndarray] | None:
    """The scores of arms ``x`` and ``y`` on the 2 or more seeds both ran, else ``None``."""
    shared = sorted({r["seed"] for r in records.get(x, ())} & {r["seed"] for r in records.get(y, ())})
    if len(shared) < 2:
        return None
    xs, ys = ([r for r in records[a] if r["seed"] in shared] for a in (x, y))
    if not all(r.get(evaluation) for r in (*xs, *ys)):
        return None
    return stats.run_scores(xs, metric, evaluation), stats.run_scores(ys, metric, evaluation)


def figure2_claims(records: Mapping[str, Sequence[Mapping[str, Any]]]) -> dict[str, Any]:
    """Per claim of :data:`FIGURE2_CLAIMS` whose arms share 2 or more seeds, their means and paired difference."""
    out = {}
    for claim, (x, y, metric, evaluation, higher) in FIGURE2_CLAIMS.items():
        scores = shared_seed_scores(records, x, y, metric, evaluation)
        if scores is None:
            continue
        sx, sy = scores  # (n_shared,) each
        out[claim] = {"x": x, "y": y, "metric": metric, "evaluation": evaluation, "x_mean": float(sx.mean()),
                      "y_mean": float(sy.mean()), **stats.paired_difference(sx, sy, higher_is_better=higher)}
    return out


def figure2_lines(summary: Mapping[str, Any]) -> list[str]:
    """The claims of :func:`figure2_claims` as Markdown table rows, or one line saying why there are none."""
    claims = summary.get("figure2") or {}
    if not claims:
        return ["The run lacks the UA2C arms these claims compare (fixed, one-step, adaptive)."]
    return table(["claim", "X", "Y", "paired difference, X better when > 0 [95 % CI]", "X ahead in"],
                 ([claim, f"{c['x_mean']:.2f}", f"{c['y_mean']:.2f}", stats.interval(c),
                   f"{c['x_better_runs']} of {c['runs']}"] for claim, c in claims.items()))


def aggregate(records: Mapping[str, Sequence[Mapping[str, Any]]], reps: int = 2000) -> dict[str, Any]:
    """``peers.json`` without its header: per arm, per (UA2C arm, peer) pair and Figure 2's claims."""
    arms = [a for a in ARMS if records.get(a)] + sorted(set(records) - set(ARMS))
    if not arms:
        raise ValueError("no arm records to aggregate: run the units first")
    ours = [a for a in arms if a in UA2C_ARMS]
    peers = [a for a in arms if a not in UA2C_ARMS]
    return {
        "arms": {a: arm_summary(records[a], reps) for a in arms},
        "pairs": {f"{o}_vs_{p}": {"ua2c": o, "peer": p, **pair_summary(records, o, p, reps)} for o in ours for p in peers},
        "figure2": figure2_claims(records),
    }


def verdicts(summary: Mapping[str, Any]) -> list[str]:
    """Per (UA2C arm, peer), the verdict of the paired reward difference and the probability of improvement."""
    lines = []
    for pair in summary["pairs"].values():
        o, p = (summary["arms"][pair[side]]["label"] for side in ("ua2c", "peer"))
        head = stats.verdict(o, p, pair["reward_paired"]) if "reward_paired" in pair else f"{o} vs {p}: no shared seeds"
        lines.append(f"{head}; P({o} > {p}) = {stats.interval(pair['reward'], 'probability', sign='')}")
    return lines


def headline(summary: Mapping[str, Any]) -> str:
    """The best UA2C arm against the best peer by IQM reward, then their means."""
    arms = summary["arms"]
    reward = {a: arms[a]["metrics"]["reward"]["iqm"] for a in arms}
    ours = [a for a in arms if a in UA2C_ARMS]
    peers = [a for a in arms if a not in UA2C_ARMS]
    if not ours or not peers:
        return "Only one side was run: no head-to-head verdict."
    o, p = max(ours, key=reward.get), max(peers, key=reward.get)
    pair, lo, lp = summary["pairs"][f"{o}_vs_{p}"], arms[o]["label"], arms[p]["label"]
    paired = stats.verdict(lo, lp, pair["reward_paired"]) if "reward_paired" in pair else "no shared seeds"
    (ro, co), (rp, cp) = ([arms[a]["means"][m]["mean"] for m in ("reward", "collision")] for a in (o, p))
    return (f"Best UA2C arm by IQM reward over runs, {lo} ({reward[o]:.2f}); best peer, {lp} ({reward[p]:.2f}). "
            f"Paired per seed: {paired}; P(UA2C > peer) = {pair['reward']['probability']:.2f}. By the mean reward: "
            f"{ro:.2f} vs {rp:.2f} ({ro - rp:+.2f}); collision rate {co:.2f} vs {cp:.2f}.")


def _cell(stat: Mapping[str, float] | None, digits: int = 2, key: str = "iqm") -> str:
    return "–" if stat is None else stats.interval(stat, key, digits, sign="")


def _digits(metric: str) -> int:
    return 1 if metric == "cumulative_jerk" else 2


def results_table(summary: Mapping[str, Any]) -> list[str]:
    """The per-arm IQMs [95 % CI] of :data:`METRICS`, the offline reward and the minutes per seed."""
    return table(["arm", "reward", "collision", "merge success", "cum. jerk", "jerk/step", "offline reward",
                  "wall / CPU min per seed"],
                 ([arm["label"], *(_cell(arm["metrics"][m], _digits(m)) for m in METRICS),
                   _cell(arm["offline_metrics"]["reward"] if arm["offline_metrics"] else None),
                   f"{arm['wall_seconds']['mean_per_seed'] / 60:.1f} / {arm['cpu_seconds']['mean_per_seed'] / 60:.1f}"]
                  for arm in summary["arms"].values()))


def means_table(summary: Mapping[str, Any]) -> list[str]:
    """The per-arm means [95 % CI] of :data:`METRICS` (0/1 metrics as rates) and the online curve area."""
    return table(["arm", "reward", "collision rate", "merge rate", "cum. jerk", "jerk/step", "online curve area"],
                 ([arm["label"], *(_cell(arm["means"][m], _digits(m), "mean") for m in METRICS),
                   _cell(arm["curve_area"] if "mean" in arm.get("curve_area", {}) else None, key="mean")]
                  for arm in summary["arms"].values()))


def training_table(summary: Mapping[str, Any]) -> list[str]:
    """Per arm, the collision rate and mean reward of its online training episodes, means over runs [95 % CI]."""
    rows = [(arm["label"], arm.get("training_episodes")) for arm in summary["arms"].values()]
    return table(["arm", "training episodes per run", "collision rate", "reward per episode"],
                 ([label, f"{t['episodes_per_run']:.0f}", _cell(t["collision"], key="mean"),
                   _cell(t["reward"], 1, "mean")] for label, t in rows if t))


def readme_table(summary: Mapping[str, Any]) -> list[str]:
    """The short table for the README: IQM and mean reward, collision and merge rates per arm."""
    return table(["arm", "reward (IQM [95 % CI])", "mean reward", "collision rate", "merge rate"],
                 ([arm["label"], _cell(arm["metrics"]["reward"]),
                   *(f"{arm['means'][m]['mean']:.2f}" for m in ("reward", "collision", "merge_success"))]
                  for arm in summary["arms"].values()))


def pairs_table(summary: Mapping[str, Any]) -> list[str]:
    return table(["UA2C arm", "peer", *(f"P(better) {m}" for m in POI_METRICS)],
                 ([summary["arms"][pair["ua2c"]]["label"], summary["arms"][pair["peer"]]["label"],
                   *(stats.interval(pair[m], "probability", sign="") for m in POI_METRICS)]
                  for pair in summary["pairs"].values()))


def write_plots(summary: Mapping[str, Any], out: Path) -> list[Path]:
    """``peers_curves.png`` (the online learning curves) and ``peers_iqm.png`` (IQM bars with 95 % CIs)."""
    arms = summary["arms"]
    curves, bars = out / "peers_curves.png", out / "peers_iqm.png"
    with figure(curves, (10, 4.5)) as fig:
        ax = fig.add_subplot()
        for name, arm in arms.items():
            if (c := arm["curve"]) is not None:
                (line,) = ax.plot(c["env_steps"], c["mean"], label=arm["label"], ls="-" if name in UA2C_ARMS else "--")
                ax.fill_between(c["env_steps"], c["ci_low"], c["ci_high"], color=line.get_color(), alpha=0.15)
        ax.set_xlabel("online env steps")
        ax.set_ylabel("training episode return")
        ax.set_title("Online learning curves (mean over seeds, 95 % bootstrap band)", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the curves, not over them
    panels = (("reward", "return"), ("collision", "collision rate"), ("jerk_per_step", "jerk per step [m/s³]"))
    names = list(arms)
    with figure(bars, (11, 4.2)) as fig:
        for j, (metric, ylabel) in enumerate(panels):
            ax = fig.add_subplot(1, len(panels), j + 1)
            cis = [arms[n]["metrics"][metric] for n in names]
            iqms = np.array([s["iqm"] for s in cis])
            err = np.array([[s["iqm"] - s["ci_low"] for s in cis], [s["ci_high"] - s["iqm"] for s in cis]])
            colors = ["#1f77b4" if n in UA2C_ARMS else "#9e9e9e" for n in names]
            ax.bar(range(len(names)), iqms, yerr=np.clip(err, 0, None), capsize=4, color=colors)
            ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
            ax.set_title(f"IQM {metric} (95 % CI)", fontsize=9)
            ax.set_ylabel(ylabel)
    return [curves, bars]


def _protocol_lines(summary: Mapping[str, Any]) -> list[str]:
    b, calql, sb3 = (summary["budget"][k] for k in ("ua2c", "calql_offline_steps", "sb3_hyperparams"))
    return [
        *section("Protocol"),
        f"- Online budget: **{b['finetune_steps']} env steps for every arm**; offline: {b['pretrain_steps']} gradient "
        "steps for UA2C and the d3rlpy arms except RLPD" + (f" (Cal-QL: {calql})" if calql else "") + ", on the seed's "
        f"Figure-2 dataset ({b['dataset_episodes']} episodes of the behaviour policy, the same data for every arm).",
        f"- Evaluation: {b['eval_episodes']} episodes per seed on the {summary.get('scenarios', 'figure2 scenarios')} "
        "(the same for every arm), deterministic actions. Statistics are run-level: each seed's score is the mean over "
        "its evaluation episodes; IQMs and means over runs carry 95 % stratified bootstrap CIs (rliable), P(UA2C > "
        "peer) is rliable's probability of improvement over runs (0.5 = no difference), and the paired difference is "
        "the mean per-seed difference with its Student-t interval.",
        f"- Observation: {summary['observation']}. Action space: the same `Box` (acceleration, lane-change command "
        "with the env's thresholds) for every arm.",
        *_ua2c_protocol(summary),
        "- SAC, TQC and CrossQ: online from scratch, hyperparameters from `zoo_configs/sac.yml` / `zoo_configs/tqc.yml`"
        " / `zoo_configs/crossq.yml` (the `MixedTraffic-v0` entries" + (f", overridden by {sb3}" if sb3 else "")
        + "; the zoo's style-context wrapper is not applied, so they see the dataset's observation).",
        f"- SAC + offline data: {summary['arms'].get('sac_offline_mix', {}).get('notes', 'not run')}.",
        "- IQL: d3rlpy 2.8.1 with its default hyperparameters; Cal-QL and ReBRAC with the settings of d3rlpy's "
        f"reproductions; batch {summary['budget']['d3rlpy_batch_size']}, offline on the dataset, then `fit_online` "
        "with half of each batch from the offline data. Reference rows, nothing learned online: the dataset's "
        "behaviour policy on the same scenarios, and d3rlpy BC (offline only).",
        *([f"- Settings on top of these (`peer_kwargs`, chosen on validation scenarios): {tuned}"]
          if (tuned := summary["budget"].get("peer_kwargs")) else []),
    ]


def _ua2c_protocol(summary: Mapping[str, Any]) -> list[str]:
    """The protocol's lines on the UA2C arms of ``summary`` (those it holds)."""
    b, ours = summary["budget"]["ua2c"], set(summary["arms"]) & set(UA2C_ARMS)
    lines = []
    if ours & {"ua2c", "ua2c_paper"}:
        lines.append(
            "- UA2C as a user gets it (`ua2c`: this release's defaults with the budget's `algo_kwargs`, one "
            "gradient step per env step) and as the paper writes it (`ua2c_paper`: `preset(\"paper\")` with the "
            "budget's learning rate, batch, γ and τ, one gradient step per replanning), each pre-trained offline "
            f"into its own checkpoint, chunk length k = {b['chunk_size']}, then fine-tuned online with the offline "
            "data in the buffer.")
    if ours & {"ua2c_fixed", "ua2c_onestep"}:
        lines.append(
            "- Figure 2's arms at the defaults: `ua2c_fixed` acts the `ua2c` checkpoint with δ = inf (whole "
            "chunks), `ua2c_onestep` is `ua2c` with k = 1 in its own checkpoint; both keep `ua2c`'s update "
            "schedule, so the three arms make the same gradient steps.")
    fig2 = [a for a in UA2C_ARMS if a in ours and UA2C_ARMS[a].cadence != "own"]  # in UA2C_ARMS's order
    if fig2:
        lines.append(
            f"- {', '.join(f'`{a}`' for a in fig2)}: `ua2c` (δ = {b['entropy_threshold']:g}) fine-tuned with one "
            f"gradient step per k = {b['chunk_size']} env steps (Figure 2's cadence: about 1/{b['chunk_size']} of "
            "the peers' updates) or, `_per_step`, one per env step (the peers' cadence).")
    return lines


def format_markdown(summary: Mapping[str, Any]) -> str:
    """``peers.md``: what ran, the verdicts, the tables and the plots."""
    est = summary["estimate"]
    return "\n".join([
        "# Head-to-head on MixedTraffic-v0: UA2C against SB3, sb3-contrib and d3rlpy",
        "",
        f"Command: `{summary['command']}` ({summary['date']}). Seeds: {summary['seeds']}. "
        f"Estimated before the run: {est['cpu'] / 60:.0f} CPU-min, ~{est['wall'] / 60:.0f} min wall on "
        f"{est['workers']} worker(s).",
        *(f"Records reused from the run in `{run}` (the same seeds, data and scenarios): {', '.join(arms)}."
          for run, arms in summary.get("reused", {}).items()),
        *_protocol_lines(summary),
        *section("Verdict (final evaluation reward, paired per seed)", f"**{headline(summary)}**", "",
                 *(f"- {v}" for v in verdicts(summary))),
        *section("Results (IQM over runs [95 % CI]; one score per run = the mean over its evaluation episodes)",
                 *results_table(summary), "",
                 "Offline reward: the checkpoint after the offline phase, evaluated on the same scenarios (arms with "
                 "an offline phase; UA2C acting by its own rule). Times are per seed; a UA2C arm counts its shared "
                 "offline checkpoint.", "",
                 "For the 0/1 metrics (collision, merge success) a run's score is its rate; the IQM over runs trims "
                 "the quarter of runs at each end, so the means over runs are in the next table."),
        *section("Means over runs [95 % CI], and the area under each run's online learning curve", *means_table(summary)),
        *section("While learning: the online training episodes (means over runs [95 % CI])", *training_table(summary)),
        *section("Executed lengths L_t (evaluation plans, pooled over runs)", *lengths_table(summary)),
        *section("Figure 2's claims among the UA2C arms of this run (paired per seed)", *figure2_lines(summary), "",
                 "X and Y are the means over the shared seeds. (a), (b): the offline checkpoints, the chunk policy "
                 "executing whole chunks against the one-step baseline; (b) is a cost, so a positive difference "
                 "means the chunk policy is smoother. (c): after the online phase, δ = 0 against δ = inf from the "
                 "same checkpoint."),
        *section("Probability of improvement of each UA2C arm over each peer (over runs)", *pairs_table(summary), "",
                 "Collision and jerk are costs: P(better) is the probability of a LOWER value.", "",
                 "![online learning curves](peers_curves.png)", "", "![IQM bars](peers_iqm.png)"),
        *section("Short table (for the README)", *readme_table(summary)),
        "",
    ])


def write_report(summary: Mapping[str, Any], out: Path) -> list[Path]:
    """Write ``peers.json``, ``peers.md`` and the PNGs into ``out``; return their paths."""
    return records.write_report(out, "peers", summary, format_markdown(summary), lambda d: write_plots(summary, d))
