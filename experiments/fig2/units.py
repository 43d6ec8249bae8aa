"""Units of work of a Figure-2 run, one file each and skipped when it exists: the per-seed stages,
their scheduler (:func:`run_fig2_seed`, :func:`run_all`), the seed lock and the measured unit times."""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from envs.collection import TRAFFIC_DEFAULTS, make_traffic_env
from experiments.common.names import (
    DATASET_SEED_BASE,
    EVAL_SEED_BASE,
    MAX_SEED,
    SAMPLED_METHODS,
    STYLE_SEED_BASE,
    acting_name,
    delta_name,
    replicate_name,
    sampled_name,
)
from experiments.fig2.budget import Fig2Budget, finetune_overrides
from experiments.fig2.manifest import RunPaths, check_manifest
from sb3_ua2c.checks import check_int


class UnitLog(list):
    """Names of the units run, in order, and their wall-clock seconds (``seconds[name]``)."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds: dict[str, float] = {}

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        """Record unit ``name`` and the time the ``with`` block takes (only if it completes)."""
        start = time.perf_counter()
        yield
        self.append(name)
        self.seconds[name] = time.perf_counter() - start


def complete_dataset(path: Path, n_episodes: int) -> Any:
    """The dataset at ``path`` when it holds ``n_episodes`` episodes, else ``None`` (missing, damaged: collect it)."""
    from sb3_ua2c.offline import METADATA_FILE, OfflineDatasetError, load_dataset

    if (path / METADATA_FILE).is_file():
        try:
            ds = load_dataset(path)
        except OfflineDatasetError:
            return None
        return ds if len(ds) == n_episodes else None
    return None


def _evaluation(raw: Path, method: str, checkpoint: Path, seed: int, budget: Fig2Budget, settings: dict[str, Any],
                entropy_threshold: float | None, log: UnitLog, n_elite: int | None = None,
                flow_steps: int | None = None, deterministic: bool = True) -> None:
    """Evaluate ``checkpoint`` on seed ``seed``'s scenarios into ``<raw>/<method>.json`` unless it exists
    (``deterministic``: fixed candidate noise, see :func:`envs.evaluation.evaluate`)."""
    from envs.evaluation import evaluate, plan_length_shares, summarize
    from sb3_ua2c.pipeline import write_json

    path = raw / f"{method}.json"
    if path.is_file():
        return
    with log.timed(f"seed{seed}/evaluate/{method}"):
        episodes = evaluate(checkpoint, n_episodes=budget.eval_episodes, seeds=(EVAL_SEED_BASE + seed,),
                            env_settings_=settings, entropy_threshold=entropy_threshold, n_elite=n_elite,
                            flow_steps=flow_steps, deterministic=deterministic)
        delta = None if entropy_threshold is None else delta_name(float(entropy_threshold))
        write_json(path, {
            "method": method, "seed": seed, "checkpoint": checkpoint.name, "entropy_threshold": delta,
            "eval_seed": EVAL_SEED_BASE + seed, "n_elite": n_elite, "flow_steps": flow_steps,
            "deterministic": deterministic,
            "summary": {**summarize(episodes),  # the L_t histogram up to the longest chunk of the run
                        "length_shares": plan_length_shares(episodes, max((budget.chunk_size, *budget.k_sweep)))},
            "episodes": episodes,
        })



class SeedBusyError(ValueError):
    """Another process is running the same seed in the same work directory (a usage error: exit code 2)."""


@contextmanager
def seed_lock(work: Path, name: str = ".lock") -> Iterator[None]:
    """Hold an exclusive lock on a seed's work directory (``<work>/<name>``, ``flock``; one per part of a seed)
    while inside: two ``fig2`` processes on one work directory would otherwise train the same unit at once.
    The lock dies with its process; without ``fcntl`` (Windows) there is none.

    :raises SeedBusyError: if another open lock holds it, naming the directory and the holder's pid
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    with open(work / name, "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            raise SeedBusyError(f"{work} is in use by another fig2 process (pid {holder}); wait for it or use "
                                "another --work directory") from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


SEED_PARTS = ("main", "style")
"""The two independent chains of a seed's units, which may run at the same time: ``"main"`` (the
dataset, Phase 1, Phase 2 and their evaluations: (a)-(c) and the sweeps) and ``"style"`` (the
style classifier of (d) and the style-context ablation, which has its own dataset and arms)."""


def run_fig2_seed(seed: int, budget: Fig2Budget, paths: RunPaths, part: str = "all") -> list[str]:
    """Run (or resume) the units of one seed's ``part`` (one of :data:`SEED_PARTS`, or ``"all"``) under the part's
    lock; return the names of the units executed. Their wall-clock seconds are merged into the part's
    ``<work>/seed<s>/unit_seconds[_style].json`` (the measured cost, next to :func:`estimate_seconds`)."""
    import torch

    if part not in (*SEED_PARTS, "all"):
        raise ValueError(f"part must be one of {[*SEED_PARTS, 'all']}, got {part!r}")
    torch.set_num_threads(1)
    work, raw = paths.seed_work(seed), paths.seed_raw(seed)
    work.mkdir(parents=True, exist_ok=True)
    raw.mkdir(parents=True, exist_ok=True)
    executed: list[str] = []
    for name in SEED_PARTS if part == "all" else (part,):
        lock_file, seconds_file = _PART_FILES[name]
        log = UnitLog()
        with seed_lock(work, lock_file):
            try:
                _PART_UNITS[name](seed, budget, work, raw, log)
            finally:  # also on an interruption: the finished units' times are kept
                _merge_seconds(work / seconds_file, log.seconds)
        executed += log
    return executed


def _merge_seconds(path: Path, seconds: Mapping[str, float]) -> None:
    from sb3_ua2c.pipeline import write_json

    if not seconds:
        return
    old = json.loads(path.read_text()) if path.is_file() else {}
    write_json(path, {**old, **seconds})


@dataclass(frozen=True)
class _SeedUnits:
    """The units of one seed; each one is skipped when its file exists."""

    seed: int
    budget: Fig2Budget
    work: Path
    raw: Path
    log: UnitLog

    def dataset(self, name: str, style_classifier: str | None = None) -> Any:
        """The seed's offline dataset ``<work>/<name>`` (the style ablation's: with the style context)."""
        from envs.collection import collect_dataset

        path, n_episodes = self.work / name, self.budget.dataset_episodes
        ds = complete_dataset(path, n_episodes)
        if ds is None:
            with self.log.timed(f"seed{self.seed}/{name}"):
                ds = collect_dataset(path, n_episodes, env_kwargs=dict(self.budget.env_kwargs), overwrite=True,
                                     style_classifier=style_classifier, seed=DATASET_SEED_BASE + 10_000 * self.seed)
        return ds

    def pretrained(self, k: int, dataset: Any, name: str) -> Path:
        """Phase 1 of the arm with chunk length ``k`` into ``<work>/<name>.zip``."""
        from sb3_ua2c.pipeline import pretrain

        path = self.work / f"{name}.zip"
        if not path.is_file():
            with self.log.timed(f"seed{self.seed}/pretrain/{name}"):
                pretrain(dataset, path, self.budget.pretrain_steps, seed=self.seed, make_env=make_traffic_env,
                         algo_kwargs={**TRAFFIC_DEFAULTS, **self.budget.arm_kwargs(k)})
        return path

    def finetuned(self, start: Path, dataset: Any, name: str, delta: float, replicate: int = 0) -> Path:
        """Phase 2 from ``start`` with threshold ``delta`` in online phase ``replicate``, into
        ``<work>/<name>.zip``; its training episodes go to ``<raw>/online/<name>.json``."""
        from sb3_ua2c.pipeline import finetune

        path, monitor = self.work / f"{name}.zip", self.work / f"{name}.monitor.csv"
        if not path.is_file():
            with self.log.timed(f"seed{self.seed}/finetune/{name}"):
                finetune(start, path, self.budget.finetune_steps, dataset=dataset, entropy_threshold=delta,
                         seed=self.seed + MAX_SEED * (self.budget.online_seed_offset + replicate),
                         algo_overrides=finetune_overrides(self.budget), monitor_file=monitor, make_env=make_traffic_env)
        _online_episodes(self.raw / "online" / f"{name}.json", monitor)
        return path

    def evaluate(self, method: str, checkpoint: Path, settings: dict[str, Any], delta: float | None, **kwargs: Any) -> None:
        """:func:`_evaluation` of ``checkpoint`` as ``method`` (``kwargs``: ``n_elite``, ``flow_steps``,
        ``deterministic``)."""
        _evaluation(self.raw, method, checkpoint, self.seed, self.budget, settings, delta, self.log, **kwargs)


def _main_units(seed: int, budget: Fig2Budget, work: Path, raw: Path, log: UnitLog) -> None:
    """The units of part ``"main"`` of a seed, in dependency order: (a)-(c) and the sweeps."""
    from sb3_ua2c.pipeline import env_settings

    units = _SeedUnits(seed, budget, work, raw, log)
    ds = units.dataset("dataset")
    settings = env_settings(ds)
    ckpt = _offline_units(units, ds, settings)
    adaptive, fixed = _online_units(units, ds, settings, ckpt[budget.chunk_size])
    if budget.sampled_eval:  # the same checkpoints acting with fresh candidate noise, as in Phase 2
        k, delta = budget.chunk_size, budget.entropy_threshold
        sampled = {
            "onestep": (ckpt[1], None), "chunk": (ckpt[k], math.inf), "chunk_adaptive": (ckpt[k], delta),
            "fixed": (fixed, math.inf), "adaptive": (adaptive, delta), "fixed_adaptive": (fixed, delta),
        }
        for method in SAMPLED_METHODS:
            checkpoint, threshold = sampled[method]
            units.evaluate(sampled_name(method), checkpoint, settings, threshold, deterministic=False)
    # more online phases from the same checkpoint, pooled into (c) (the first one is in _online_units)
    for r in range(1, budget.online_replicates):
        for arm, delta in (("adaptive", budget.entropy_threshold), ("fixed", math.inf)):
            name = replicate_name(arm, r)
            tuned = units.finetuned(ckpt[budget.chunk_size], ds, name, delta, r)
            units.evaluate(name, tuned, settings, delta)
            if budget.sampled_eval:
                units.evaluate(sampled_name(name), tuned, settings, delta, deterministic=False)


def _style_units(seed: int, budget: Fig2Budget, work: Path, raw: Path, log: UnitLog) -> None:
    """The units of part ``"style"`` of a seed: (d), driving-style inference, then (beyond the paper)
    the style context c_t appended to the observation (Eq. 6), pre-trained and fine-tuned on its own data."""
    from sb3_ua2c.pipeline import env_settings

    classifier = _style_unit(seed, budget, work, raw, log)
    if budget.style_ablation:
        units = _SeedUnits(seed, budget, work, raw, log)
        ds_style = units.dataset("dataset_style", str(classifier.resolve()))
        pre_style = units.pretrained(budget.chunk_size, ds_style, "pretrain_style")
        fine_style = units.finetuned(pre_style, ds_style, "adaptive_style", budget.entropy_threshold)
        units.evaluate("adaptive_style", fine_style, env_settings(ds_style), budget.entropy_threshold)


_PART_UNITS = {"main": _main_units, "style": _style_units}
_PART_FILES = {"main": (".lock", "unit_seconds.json"), "style": (".lock-style", "unit_seconds_style.json")}  # lock, seconds


def _offline_units(units: _SeedUnits, ds: Any, settings: dict[str, Any]) -> dict[int, Path]:
    """(a), (b), the k sweep and the acting sweep: every chunk length pre-trained on the same data with
    the same gradient budget, then evaluated; returns the checkpoints by chunk length."""
    budget = units.budget
    ckpt = {k: units.pretrained(k, ds, f"pretrain_k{k}") for k in budget.pretrain_ks}
    units.evaluate("onestep", ckpt[1], settings, None)
    units.evaluate("chunk", ckpt[budget.chunk_size], settings, math.inf)
    units.evaluate("chunk_adaptive", ckpt[budget.chunk_size], settings, budget.entropy_threshold)
    for k in budget.k_sweep:
        units.evaluate(f"k{k}", ckpt[k], settings, math.inf)
    default_elite = budget.default_elite
    for n, m in budget.acting_variants():  # other acting rules for the same two checkpoints
        for arm, k in (("onestep", 1), ("chunk", budget.chunk_size)):
            delta = None if k == 1 else math.inf
            units.evaluate(acting_name(arm, n, m, default_elite), ckpt[k], settings, delta, n_elite=m, flow_steps=n)
    return ckpt


def _online_units(units: _SeedUnits, ds: Any, settings: dict[str, Any], start: Path) -> tuple[Path, Path]:
    """(c) and the δ sweep, first online phase: adaptive and fixed fine-tuned from the same chunk
    checkpoint ``start`` with the same online budget; returns their checkpoints."""
    budget = units.budget
    adaptive = units.finetuned(start, ds, "adaptive", budget.entropy_threshold)
    fixed = units.finetuned(start, ds, "fixed", math.inf)
    units.evaluate("adaptive", adaptive, settings, budget.entropy_threshold)
    units.evaluate("fixed", fixed, settings, math.inf)
    # the execution rule alone: the fixed arm's checkpoint executed with adaptive chunks
    units.evaluate("fixed_adaptive", fixed, settings, budget.entropy_threshold)
    for delta in budget.delta_sweep:
        units.evaluate(f"delta_{delta_name(delta)}", adaptive, settings, delta)
    return adaptive, fixed


def _online_episodes(path: Path, monitor: Path) -> None:
    """Copy the Phase-2 training episodes (return, length, collision; not the wall times) of one arm from its
    Monitor log into the raw results, unless done (or the log is missing: a run of an earlier version)."""
    from sb3_ua2c.pipeline import read_monitor, write_json

    if path.is_file() or not monitor.is_file():
        return
    episodes = [{"reward": e["r"], "length": int(e["l"]), "collision": bool(e["collision"])} for e in read_monitor(monitor)]
    write_json(path, {"episodes": episodes})


def _style_unit(seed: int, budget: Fig2Budget, work: Path, raw: Path, log: UnitLog) -> Path:
    """Style data, classifier (Eq. 5) and its held-out evaluation of one seed; returns the classifier path."""
    from envs import style
    from sb3_ua2c.pipeline import write_json

    data_path, model_path, result_path = work / "style_data.npz", work / "style_classifier.pt", raw / "style.json"
    if data_path.is_file():
        data = style.StyleDataset.load(data_path)
    else:
        with log.timed(f"seed{seed}/style/collect"):
            data = style.collect_style_dataset(budget.style_episodes, seed=STYLE_SEED_BASE + 10_000 * seed,
                                               env_kwargs=dict(budget.env_kwargs), progress_bar=False)
            tmp = data_path.with_name(".style_data.tmp.npz")
            data.save(tmp)
            os.replace(tmp, data_path)
    if model_path.is_file():
        model = style.DrivingStyleClassifier.load(model_path)
    else:
        with log.timed(f"seed{seed}/style/train"):
            model, _ = style.train_style_classifier(data, train_config={"max_epochs": budget.style_max_epochs,
                                                                          "seed": seed}, progress_bar=False)
            tmp = model_path.with_name(".style_classifier.tmp.pt")
            model.save(tmp)
            os.replace(tmp, model_path)
    if not result_path.is_file():
        with log.timed(f"seed{seed}/style/evaluate"):
            write_json(result_path, {"seed": seed, **style.evaluate_style_classifier(model, data)})
    return model_path


def measured_seconds(paths: RunPaths, seeds: Sequence[int]) -> dict[str, float]:
    """Wall-clock seconds of the units run so far (``<work>/seed<s>/unit_seconds*.json``) per stage of
    :func:`estimate_seconds` and ``"total"`` (stages without a record are absent)."""
    out: dict[str, float] = {}
    for s in seeds:
        records: dict[str, float] = {}
        for _, file in _PART_FILES.values():
            path = paths.seed_work(s) / file
            if path.is_file():
                records.update(json.loads(path.read_text()))
        for name, seconds in records.items():
            parts = name.split("/")  # seed<s>/<stage>[/<what>]
            stage = "style_ablation" if name.endswith("_style") else {"dataset": "datasets"}.get(parts[1], parts[1])
            out[stage] = out.get(stage, 0.0) + float(seconds)
    if out:
        out["total"] = sum(out.values())
    return out


def run_fig2_seed_unit(seed: int, budget: dict[str, Any], paths: RunPaths, part: str = "all") -> list[str]:
    """:func:`run_fig2_seed` as an executor unit (plain arguments: it may run in another process or on a Ray node)."""
    return run_fig2_seed(seed, Fig2Budget.from_dict(budget), paths, part)


def run_all(seeds: Sequence[int], budget: Fig2Budget, paths: RunPaths, workers: int = 1, printer: Any = print,
            ray_address: str | None = None) -> list[str]:
    """Run (or resume) every seed as two :mod:`experiments.common.runner` units, its parts (:data:`SEED_PARTS`):
    every ``"main"`` part first, then the shorter ``"style"`` parts, which fill the workers the main parts leave
    idle. A part resumes its own units (they are files), so the units have no result file and always run.

    :return: the units executed, over all seeds
    :raises UnitsFailedError: after every part ran, naming the parts that raised
    """
    from experiments.common.runner import Unit, make_executor, run_units

    check_int("Fig2Budget.workers", workers)
    check_manifest(paths, budget)
    parts = [(s, part) for part in SEED_PARTS for s in seeds]
    serial = ray_address is None and workers == 1
    executor = make_executor(min(workers, len(parts)), ray_address, serial=serial)
    units = [Unit(f"seed{s}/{part}", run_fig2_seed_unit, {"seed": s, "budget": budget.to_dict(), "paths": paths,
                                                           "part": part}) for s, part in parts]
    executed: list[str] = []
    for (s, part), result in zip(parts, run_units(units, executor, printer=None), strict=True):
        printer(f"seed {s} ({part}): {len(result.value)} unit(s) run in {result.wall_seconds:.0f} s")
        executed += result.value
    return executed
