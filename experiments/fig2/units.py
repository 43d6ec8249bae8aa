"""Units of work of a Figure-2 run, one file each and skipped when it exists, and their scheduler."""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from envs import collection, evaluation, style
from envs.collection import TRAFFIC_DEFAULTS, make_traffic_env
from experiments.common import names
from experiments.common.runner import Unit, make_executor, run_units
from experiments.fig2.budget import Fig2Budget, RunPaths, finetune_overrides
from sb3_ua2c import pipeline
from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import METADATA_FILE, OfflineDatasetError, load_dataset

#: The two independent chains of a seed's units, which may run at the same time: ``"main"`` (the dataset,
#: Phase 1, Phase 2 and their evaluations: (a)-(c) and the sweeps) and ``"style"`` ((d)'s style classifier
#: and the style-context ablation, with its own dataset and arms); each with its lock and unit-seconds files.
SEED_PARTS = ("main", "style")
_PART_FILES = {"main": (".lock", "unit_seconds.json"), "style": (".lock-style", "unit_seconds_style.json")}


def complete_dataset(path: Path, n_episodes: int) -> Any:
    """The dataset at ``path`` when it holds ``n_episodes`` episodes, else ``None`` (missing, damaged: collect it)."""
    try:
        ds = load_dataset(path) if (path / METADATA_FILE).is_file() else None
    except OfflineDatasetError:
        return None
    return ds if ds is not None and len(ds) == n_episodes else None


class SeedBusyError(ValueError):
    """Another process is running the same seed in the same work directory (a usage error: exit code 2)."""


@contextmanager
def seed_lock(work: Path, name: str = ".lock") -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``<work>/<name>`` while inside: two processes would train the same unit."""
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


def run_fig2_seed(seed: int, budget: Fig2Budget, paths: RunPaths, part: str = "all") -> list[str]:
    """Run (or resume) one seed's ``part`` under its lock, recording its units' seconds; return the units run."""
    if part not in (*SEED_PARTS, "all"):
        raise ValueError(f"part must be one of {[*SEED_PARTS, 'all']}, got {part!r}")
    torch.set_num_threads(1)
    units = SeedUnits(seed, budget, paths.seed_work(seed), paths.seed_raw(seed))
    units.work.mkdir(parents=True, exist_ok=True)
    units.raw.mkdir(parents=True, exist_ok=True)
    executed: list[str] = []
    for name in SEED_PARTS if part == "all" else (part,):
        lock_file, seconds_file = _PART_FILES[name]
        units.seconds = {}
        with seed_lock(units.work, lock_file):
            try:
                getattr(units, name)()  # units.main() or units.style()
            finally:  # also on an interruption: the finished units' times are kept
                if units.seconds:
                    path = units.work / seconds_file
                    old = json.loads(path.read_text()) if path.is_file() else {}
                    pipeline.write_json(path, {**old, **units.seconds})
        executed += list(units.seconds)
    return executed


@dataclass
class SeedUnits:
    """The units of one seed, each skipped when its file exists; ``seconds``: those run, with their seconds."""

    seed: int
    budget: Fig2Budget
    work: Path
    raw: Path
    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        """Record unit ``seed<s>/<name>`` and the time the ``with`` block takes (only if it completes)."""
        start = time.perf_counter()
        yield
        self.seconds[f"seed{self.seed}/{name}"] = time.perf_counter() - start

    def dataset(self, name: str, style_classifier: str | None = None) -> Any:
        """The seed's offline dataset ``<work>/<name>`` (the style ablation's: with the style context)."""
        path, n_episodes = self.work / name, self.budget.dataset_episodes
        ds = complete_dataset(path, n_episodes)
        if ds is None:
            with self.timed(name):
                ds = collection.collect_dataset(path, n_episodes, env_kwargs=dict(self.budget.env_kwargs), overwrite=True,
                                                style_classifier=style_classifier,
                                                seed=names.DATASET_SEED_BASE + 10_000 * self.seed)
        return ds

    def pretrained(self, k: int, dataset: Any, name: str) -> Path:
        """Phase 1 of the arm with chunk length ``k`` into ``<work>/<name>.zip``."""
        path = self.work / f"{name}.zip"
        if not path.is_file():
            with self.timed(f"pretrain/{name}"):
                pipeline.pretrain(dataset, path, self.budget.pretrain_steps, seed=self.seed, make_env=make_traffic_env,
                                  algo_kwargs={**TRAFFIC_DEFAULTS, **self.budget.arm_kwargs(k)})
        return path

    def finetuned(self, start: Path, dataset: Any, name: str, delta: float, replicate: int = 0) -> Path:
        """Phase 2 from ``start`` with ``delta`` into ``<work>/<name>.zip``, its episodes into ``<raw>/online/``."""
        path, monitor = self.work / f"{name}.zip", self.work / f"{name}.monitor.csv"
        if not path.is_file():
            with self.timed(f"finetune/{name}"):
                pipeline.finetune(start, path, self.budget.finetune_steps, dataset=dataset, entropy_threshold=delta,
                                  seed=self.seed + names.MAX_SEED * (self.budget.online_seed_offset + replicate),
                                  algo_overrides=finetune_overrides(self.budget), monitor_file=monitor,
                                  make_env=make_traffic_env)
        episodes = self.raw / "online" / f"{name}.json"  # not the wall times; none from a run of an earlier version
        if not episodes.is_file() and monitor.is_file():
            rows = [{"reward": e["r"], "length": int(e["l"]), "collision": bool(e["collision"])}
                    for e in pipeline.read_monitor(monitor)]
            pipeline.write_json(episodes, {"episodes": rows})
        return path

    def evaluate(self, method: str, checkpoint: Path, settings: dict[str, Any], delta: float | None,
                 n_elite: int | None = None, flow_steps: int | None = None, deterministic: bool = True) -> None:
        """Evaluate ``checkpoint`` on the seed's scenarios into ``<raw>/<method>.json``."""
        path, budget = self.raw / f"{method}.json", self.budget
        if path.is_file():
            return
        with self.timed(f"evaluate/{method}"):
            episodes = evaluation.evaluate(checkpoint, n_episodes=budget.eval_episodes,
                                           seeds=(names.EVAL_SEED_BASE + self.seed,), env_settings_=settings,
                                           entropy_threshold=delta, n_elite=n_elite, flow_steps=flow_steps,
                                           deterministic=deterministic)
            pipeline.write_json(path, {
                "method": method, "seed": self.seed, "checkpoint": checkpoint.name,
                "entropy_threshold": None if delta is None else names.delta_name(float(delta)),
                "eval_seed": names.EVAL_SEED_BASE + self.seed, "n_elite": n_elite, "flow_steps": flow_steps,
                "deterministic": deterministic,
                "summary": {**evaluation.summarize(episodes),  # the L_t histogram up to the longest chunk of the run
                            "length_shares": evaluation.plan_length_shares(episodes,
                                                                           max((budget.chunk_size, *budget.k_sweep)))},
                "episodes": episodes,
            })

    def main(self) -> None:
        """The units of part ``"main"``, in dependency order: (a)-(c) and the sweeps."""
        budget, k, delta = self.budget, self.budget.chunk_size, self.budget.entropy_threshold
        ds = self.dataset("dataset")
        settings = pipeline.env_settings(ds)
        ckpt = self.offline(ds, settings)
        adaptive, fixed = self.online(ds, settings, ckpt[k])
        if budget.sampled_eval:  # the same checkpoints acting with fresh candidate noise, as in Phase 2
            sampled = {"onestep": (ckpt[1], None), "chunk": (ckpt[k], math.inf), "chunk_adaptive": (ckpt[k], delta),
                       "fixed": (fixed, math.inf), "adaptive": (adaptive, delta), "fixed_adaptive": (fixed, delta)}
            for method, (checkpoint, threshold) in sampled.items():  # names.SAMPLED_METHODS, in order
                self.evaluate(names.sampled_name(method), checkpoint, settings, threshold, deterministic=False)
        # more online phases from the same checkpoint, pooled into (c) (the first one is in online())
        for r in range(1, budget.online_replicates):
            for arm, threshold in (("adaptive", delta), ("fixed", math.inf)):
                name = names.replicate_name(arm, r)
                tuned = self.finetuned(ckpt[k], ds, name, threshold, r)
                self.evaluate(name, tuned, settings, threshold)
                if budget.sampled_eval:
                    self.evaluate(names.sampled_name(name), tuned, settings, threshold, deterministic=False)

    def offline(self, ds: Any, settings: dict[str, Any]) -> dict[int, Path]:
        """(a), (b), the k and the acting sweeps; returns the checkpoints by chunk length."""
        budget = self.budget
        ckpt = {k: self.pretrained(k, ds, f"pretrain_k{k}") for k in budget.pretrain_ks}
        self.evaluate("onestep", ckpt[1], settings, None)
        self.evaluate("chunk", ckpt[budget.chunk_size], settings, math.inf)
        self.evaluate("chunk_adaptive", ckpt[budget.chunk_size], settings, budget.entropy_threshold)
        for k in budget.k_sweep:
            self.evaluate(f"k{k}", ckpt[k], settings, math.inf)
        for n, m in budget.acting_variants():  # other acting rules for the same two checkpoints
            for arm, k in (("onestep", 1), ("chunk", budget.chunk_size)):
                name = names.acting_name(arm, n, m, budget.default_elite)
                self.evaluate(name, ckpt[k], settings, None if k == 1 else math.inf, n_elite=m, flow_steps=n)
        return ckpt

    def online(self, ds: Any, settings: dict[str, Any], start: Path) -> tuple[Path, Path]:
        """(c) and the δ sweep, first online phase; returns the adaptive and fixed checkpoints."""
        delta = self.budget.entropy_threshold
        adaptive = self.finetuned(start, ds, "adaptive", delta)
        fixed = self.finetuned(start, ds, "fixed", math.inf)
        self.evaluate("adaptive", adaptive, settings, delta)
        self.evaluate("fixed", fixed, settings, math.inf)
        self.evaluate("fixed_adaptive", fixed, settings, delta)  # the execution rule alone
        for d in self.budget.delta_sweep:
            self.evaluate(f"delta_{names.delta_name(d)}", adaptive, settings, d)
        return adaptive, fixed

    def style(self) -> None:
        """The units of part ``"style"``: (d), then the arm with the style context c_t (Eq. 6)."""
        budget, seed = self.budget, self.seed
        data = self._stored(self.work / "style_data.npz", style.StyleDataset.load, "style/collect",
                            lambda: style.collect_style_dataset(budget.style_episodes, env_kwargs=dict(budget.env_kwargs),
                                                                seed=names.STYLE_SEED_BASE + 10_000 * seed,
                                                                progress_bar=False))
        classifier = self.work / "style_classifier.pt"
        model = self._stored(classifier, style.DrivingStyleClassifier.load, "style/train",
                             lambda: style.train_style_classifier(data, progress_bar=False, train_config={
                                 "max_epochs": budget.style_max_epochs, "seed": seed})[0])
        if not (self.raw / "style.json").is_file():
            with self.timed("style/evaluate"):
                pipeline.write_json(self.raw / "style.json", {"seed": seed, **style.evaluate_style_classifier(model, data)})
        if budget.style_ablation:
            ds_style = self.dataset("dataset_style", str(classifier.resolve()))
            pre_style = self.pretrained(budget.chunk_size, ds_style, "pretrain_style")
            fine_style = self.finetuned(pre_style, ds_style, "adaptive_style", budget.entropy_threshold)
            self.evaluate("adaptive_style", fine_style, pipeline.env_settings(ds_style), budget.entropy_threshold)

    def _stored(self, path: Path, load: Callable[[Path], Any], unit: str, make: Callable[[], Any]) -> Any:
        """The object saved at ``path``, or ``make()``'s (unit ``unit``), saved there atomically."""
        if path.is_file():
            return load(path)
        with self.timed(unit):
            obj = make()
            tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
            obj.save(tmp)
            os.replace(tmp, path)
        return obj


def measured_seconds(paths: RunPaths, seeds: Sequence[int]) -> dict[str, float]:
    """Wall-clock seconds of the units run so far per stage of :func:`~experiments.fig2.budget.estimate_seconds`."""
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
    """Run (or resume) every seed's parts as executor units, the ``"main"`` parts first; return the units run."""
    check_int("Fig2Budget.workers", workers)
    paths.check_budget(budget)
    parts = [(s, part) for part in SEED_PARTS for s in seeds]
    executor = make_executor(min(workers, len(parts)), ray_address, serial=ray_address is None and workers == 1)
    units = [Unit(f"seed{s}/{part}", run_fig2_seed_unit, {"seed": s, "budget": budget.to_dict(), "paths": paths,
                                                           "part": part}) for s, part in parts]
    executed: list[str] = []
    for (s, part), result in zip(parts, run_units(units, executor, printer=None), strict=True):
        printer(f"seed {s} ({part}): {len(result.value)} unit(s) run in {result.wall_seconds:.0f} s")
        executed += result.value
    return executed
