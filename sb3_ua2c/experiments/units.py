"""Units of work of a Figure-2 run, one file each and skipped when it exists: the per-seed stages,
their scheduler (:func:`run_seed`, :func:`run_all`), the seed lock and the measured unit times."""

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

from sb3_ua2c.checks import check_int
from sb3_ua2c.experiments.budget import Fig2Budget
from sb3_ua2c.experiments.manifest import RunPaths, check_manifest, write_manifest
from sb3_ua2c.experiments.names import (
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


def _dataset(
    path: Path,
    n_episodes: int,
    seed: int,
    env_kwargs: dict[str, Any],
    style_classifier: str | None,
    log: UnitLog,
    unit: str,
):
    """Load the dataset at ``path``, or collect it (unit ``unit``) when missing or damaged."""
    from sb3_ua2c.offline import METADATA_FILE, OfflineDatasetError, collect_dataset, load_dataset

    if (path / METADATA_FILE).is_file():
        try:
            return load_dataset(path)
        except OfflineDatasetError:
            pass  # damaged: collect again
    with log.timed(unit):
        return collect_dataset(
            path,
            n_episodes,
            env_kwargs=env_kwargs,
            style_classifier=style_classifier,
            seed=seed,
            overwrite=True,
        )


def _evaluation(
    raw: Path,
    method: str,
    checkpoint: Path,
    seed: int,
    budget: Fig2Budget,
    settings: dict[str, Any],
    entropy_threshold: float | None,
    log: UnitLog,
    n_elite: int | None = None,
    flow_steps: int | None = None,
    deterministic: bool = True,
) -> None:
    """Evaluate ``checkpoint`` on seed ``seed``'s scenarios into ``<raw>/<method>.json`` unless it exists
    (``deterministic``: fixed candidate noise, see :func:`sb3_ua2c.pipeline.evaluate`)."""
    from sb3_ua2c.pipeline import evaluate, summarize, write_json

    path = raw / f"{method}.json"
    if path.is_file():
        return
    with log.timed(f"seed{seed}/evaluate/{method}"):
        episodes = evaluate(
            checkpoint,
            n_episodes=budget.eval_episodes,
            seeds=(EVAL_SEED_BASE + seed,),
            env_settings_=settings,
            entropy_threshold=entropy_threshold,
            n_elite=n_elite,
            flow_steps=flow_steps,
            deterministic=deterministic,
        )
        write_json(
            path,
            {
                "method": method,
                "seed": seed,
                "checkpoint": checkpoint.name,
                "entropy_threshold": None
                if entropy_threshold is None
                else delta_name(float(entropy_threshold)),
                "eval_seed": EVAL_SEED_BASE + seed,
                "n_elite": n_elite,
                "flow_steps": flow_steps,
                "deterministic": deterministic,
                "summary": summarize(episodes),
                "episodes": episodes,
            },
        )


def finetune_overrides(budget: Fig2Budget) -> dict[str, Any]:
    """Phase-2 update cadence of every fine-tuned arm: one gradient step per ``chunk_size`` env steps.

    UA2C's default (one update per plan) would give the adaptive arm, whose plans are shorter,
    up to ``k`` times the updates of the fixed arm for the same environment steps. The budget's
    ``finetune_kwargs`` come on top.
    """
    return {**budget.finetune_kwargs, "train_freq": budget.chunk_size, "gradient_steps": 1}


class SeedBusyError(RuntimeError):
    """Another process is running the same seed in the same work directory."""


@contextmanager
def seed_lock(work: Path) -> Iterator[None]:
    """Hold an exclusive lock on a seed's work directory (``<work>/.lock``, ``flock``) while inside.

    Two ``fig2`` processes on one work directory (e.g. a second one started with ``--seed-list``)
    would otherwise train the same unit at once and write the same files. The lock dies with its
    process, so an interrupted run leaves nothing to clean up.

    On a platform without ``fcntl`` (Windows) there is no lock: do not start two runs on one
    work directory there.

    :param work: the seed's work directory (must exist)
    :raises SeedBusyError: if another open lock holds it, naming the directory and the holder's pid
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield
        return
    with open(work / ".lock", "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            raise SeedBusyError(
                f"{work} is in use by another fig2 process (pid {holder}); wait for it or use "
                "another --work directory"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def run_seed(seed: int, budget: Fig2Budget, paths: RunPaths) -> list[str]:
    """Run (or resume) every unit of one seed; return the names of the units actually executed.

    The wall-clock seconds of every unit run are merged into ``<work>/seed<s>/unit_seconds.json``
    (measured cost of the run, next to :func:`estimate_seconds`). The seed's work directory is
    locked meanwhile (:func:`seed_lock`).

    :param seed: the seed (datasets, networks, online env, evaluation scenarios derive from it)
    :param budget: the run's budget
    :param paths: the run's directories
    """
    import torch

    torch.set_num_threads(1)
    work, raw = paths.seed_work(seed), paths.seed_raw(seed)
    work.mkdir(parents=True, exist_ok=True)
    raw.mkdir(parents=True, exist_ok=True)
    log = UnitLog()
    with seed_lock(work):
        try:
            _run_seed_units(seed, budget, work, raw, log)
        finally:  # also on an interruption: the finished units' times are kept
            _merge_seconds(work / "unit_seconds.json", log.seconds)
    return list(log)


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
        return _dataset(
            self.work / name,
            self.budget.dataset_episodes,
            DATASET_SEED_BASE + 10_000 * self.seed,
            dict(self.budget.env_kwargs),
            style_classifier,
            self.log,
            f"seed{self.seed}/{name}",
        )

    def pretrained(self, k: int, dataset: Any, name: str) -> Path:
        """Phase 1 of the arm with chunk length ``k`` into ``<work>/<name>.zip``."""
        from sb3_ua2c.pipeline import pretrain

        path = self.work / f"{name}.zip"
        if not path.is_file():
            with self.log.timed(f"seed{self.seed}/pretrain/{name}"):
                pretrain(dataset, path, self.budget.pretrain_steps, seed=self.seed, algo_kwargs=self.budget.arm_kwargs(k))
        return path

    def finetuned(self, start: Path, dataset: Any, name: str, delta: float, replicate: int = 0) -> Path:
        """Phase 2 from ``start`` with threshold ``delta`` in online phase ``replicate``, into
        ``<work>/<name>.zip``; its training episodes go to ``<raw>/online/<name>.json``."""
        from sb3_ua2c.pipeline import finetune

        path, monitor = self.work / f"{name}.zip", self.work / f"{name}.monitor.csv"
        if not path.is_file():
            with self.log.timed(f"seed{self.seed}/finetune/{name}"):
                finetune(
                    start, path, self.budget.finetune_steps, dataset=dataset, entropy_threshold=delta,
                    seed=self.seed + MAX_SEED * (self.budget.online_seed_offset + replicate),
                    algo_overrides=finetune_overrides(self.budget), monitor_file=monitor,
                )
        _online_episodes(self.raw / "online" / f"{name}.json", monitor)
        return path

    def evaluate(self, method: str, checkpoint: Path, settings: dict[str, Any], delta: float | None, **kwargs: Any) -> None:
        """:func:`_evaluation` of ``checkpoint`` as ``method`` (``kwargs``: ``n_elite``, ``flow_steps``,
        ``deterministic``)."""
        _evaluation(self.raw, method, checkpoint, self.seed, self.budget, settings, delta, self.log, **kwargs)


def _run_seed_units(seed: int, budget: Fig2Budget, work: Path, raw: Path, log: UnitLog) -> None:
    """The units of :func:`run_seed`, in dependency order."""
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
    # (d): driving-style inference
    classifier = _style_unit(seed, budget, work, raw, log)
    # beyond the paper: the style context c_t appended to the observation (Eq. 6)
    if budget.style_ablation:
        ds_style = units.dataset("dataset_style", str(classifier.resolve()))
        pre_style = units.pretrained(budget.chunk_size, ds_style, "pretrain_style")
        fine_style = units.finetuned(pre_style, ds_style, "adaptive_style", budget.entropy_threshold)
        units.evaluate("adaptive_style", fine_style, env_settings(ds_style), budget.entropy_threshold)
    # more online phases from the same checkpoint, pooled into (c) (the first one is in _online_units)
    for r in range(1, budget.online_replicates):
        for arm, delta in (("adaptive", budget.entropy_threshold), ("fixed", math.inf)):
            name = replicate_name(arm, r)
            tuned = units.finetuned(ckpt[budget.chunk_size], ds, name, delta, r)
            units.evaluate(name, tuned, settings, delta)
            if budget.sampled_eval:
                units.evaluate(sampled_name(name), tuned, settings, delta, deterministic=False)


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
    for n, m in budget.acting_variants:  # other acting rules for the same two checkpoints
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
    from sb3_ua2c import style
    from sb3_ua2c.pipeline import write_json

    data_path, model_path, result_path = (
        work / "style_data.npz",
        work / "style_classifier.pt",
        raw / "style.json",
    )
    if data_path.is_file():
        data = style.StyleDataset.load(data_path)
    else:
        with log.timed(f"seed{seed}/style/collect"):
            data = style.collect_style_dataset(
                budget.style_episodes,
                seed=STYLE_SEED_BASE + 10_000 * seed,
                env_kwargs=dict(budget.env_kwargs),
                progress_bar=False,
            )
            tmp = data_path.with_name(".style_data.tmp.npz")
            data.save(tmp)
            os.replace(tmp, data_path)
    if model_path.is_file():
        model = style.DrivingStyleClassifier.load(model_path)
    else:
        with log.timed(f"seed{seed}/style/train"):
            model, _ = style.train_style_classifier(
                data, train_config={"max_epochs": budget.style_max_epochs, "seed": seed}, progress_bar=False
            )
            tmp = model_path.with_name(".style_classifier.tmp.pt")
            model.save(tmp)
            os.replace(tmp, model_path)
    if not result_path.is_file():
        with log.timed(f"seed{seed}/style/evaluate"):
            write_json(result_path, {"seed": seed, **style.evaluate_style_classifier(model, data)})
    return model_path


def measured_seconds(paths: RunPaths, seeds: Sequence[int]) -> dict[str, float]:
    """Wall-clock seconds of the units run so far, by the stages of :func:`estimate_seconds`.

    :param paths: the run's directories (reads ``<work>/seed<s>/unit_seconds.json``)
    :param seeds: the seeds to count
    :return: seconds per stage and ``"total"`` (stages without a record are absent)
    """
    out: dict[str, float] = {}
    for s in seeds:
        path = paths.seed_work(s) / "unit_seconds.json"
        if not path.is_file():
            continue
        for name, seconds in json.loads(path.read_text()).items():
            parts = name.split("/")  # seed<s>/<stage>[/<what>]
            if name.endswith("_style"):
                stage = "style_ablation"
            else:
                stage = {
                    "dataset": "datasets",
                    "pretrain": "pretrain",
                    "finetune": "finetune",
                    "evaluate": "evaluate",
                    "style": "style",
                }.get(parts[1], parts[1])
            out[stage] = out.get(stage, 0.0) + float(seconds)
    if out:
        out["total"] = sum(out.values())
    return out


def run_seed_unit(seed: int, budget: dict[str, Any], paths: RunPaths) -> list[str]:
    """:func:`run_seed` as an executor unit (plain arguments: it may run in another process or on a Ray node)."""
    return run_seed(seed, Fig2Budget.from_dict(budget), paths)


def run_all(
    seeds: Sequence[int],
    budget: Fig2Budget,
    paths: RunPaths,
    workers: int = 1,
    printer: Any = print,
    ray_address: str | None = None,
) -> list[str]:
    """Run (or resume) every seed, one :mod:`sb3_ua2c.executor` unit per seed: ``workers`` seeds at a
    time in separate processes (one SUMO simulation per process), in this process when
    ``workers=1``, or as Ray tasks on the cluster at ``ray_address``. A seed resumes its own units
    (they are files), so the seed units have no result file and always run.

    :return: the units executed, over all seeds
    :raises UnitsFailedError: after every seed ran, naming the seeds that raised
    """
    from sb3_ua2c.executor import Unit, make_executor, run_units

    check_int("Fig2Budget.workers", workers)
    check_manifest(paths, budget)
    write_manifest(paths, budget)
    serial = ray_address is None and (workers == 1 or len(seeds) == 1)
    executor = make_executor(min(workers, max(len(seeds), 1)), ray_address, serial=serial)
    units = [Unit(f"seed{s}", run_seed_unit, {"seed": s, "budget": budget.to_dict(), "paths": paths}) for s in seeds]
    executed: list[str] = []
    for s, result in zip(seeds, run_units(units, executor, printer=None), strict=True):
        printer(f"seed {s}: {len(result.value)} unit(s) run in {result.wall_seconds:.0f} s")
        executed += result.value
    return executed
