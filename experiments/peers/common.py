"""What every peer unit shares: inputs, zoo hyperparameters, transitions, learning curve, timing and record."""

from __future__ import annotations

import ast
import json
import os
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from envs.collection import BehaviourConfig
from envs.evaluation import evaluate, evaluate_behaviour, summarize
from experiments.common.records import episode_rows, recorded_path
from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import Episode, OfflineDataset, load_dataset
from sb3_ua2c.pipeline import env_settings, read_monitor

#: Keys of a zoo entry that configure rl-zoo3 itself, not the algorithm.
ZOO_ONLY_KEYS = frozenset({
    "n_timesteps", "env_wrapper", "normalize", "n_envs", "frame_stack", "callback", "vec_env_wrapper",
    "env_kwargs", "eval_env_kwargs", "policy",
})


@dataclass(frozen=True)
class ArmInputs:
    """What every arm unit of a seed gets: its directory, the seed's dataset (it defines the environment), seed,
    online env steps and evaluation scenarios (:func:`envs.evaluation.evaluate`'s)."""

    out_dir: str | os.PathLike
    dataset: str | os.PathLike | OfflineDataset
    seed: int
    online_steps: int
    eval_seeds: Sequence[int]
    eval_episodes: int

    def __post_init__(self) -> None:  # a bad evaluation protocol raises here, before any training
        seeds = self.eval_seeds
        seeds = tuple(seeds) if isinstance(seeds, Sequence) and not isinstance(seeds, str) else None
        if not seeds:
            raise ValueError(f"eval_seeds must be a non-empty sequence of integers, got {self.eval_seeds!r}")
        for s in seeds:
            check_int("eval_seeds", s, low=0)
        check_int("eval_episodes", self.eval_episodes)
        object.__setattr__(self, "eval_seeds", tuple(int(s) for s in seeds))

    def load_dataset(self) -> OfflineDataset:
        """The seed's dataset, loaded unless it is already."""
        return self.dataset if isinstance(self.dataset, OfflineDataset) else load_dataset(self.dataset)


def zoo_hyperparams(algo: str, env_id: str = "MixedTraffic-v0", conf_file: str | os.PathLike | None = None) -> dict[str, Any]:
    """The constructor arguments of ``algo`` for ``env_id`` in an rl-zoo3 YAML file (default: ``zoo_configs/<algo>.yml``
    of the source checkout this package runs from)."""
    path = Path(conf_file or Path(__file__).resolve().parents[2] / "zoo_configs" / f"{algo}.yml")
    if not path.is_file():
        raise FileNotFoundError(f"no zoo config {path}: pass conf_file= (e.g. zoo_configs/{algo}.yml of a source checkout)")
    entries = yaml.safe_load(path.read_text()) or {}
    if env_id not in entries:
        raise ValueError(f"{path} has no entry for {env_id!r}; entries: {sorted(entries)}")
    params = {k: v for k, v in entries[env_id].items() if k not in ZOO_ONLY_KEYS}
    if isinstance(params.get("policy_kwargs"), str):
        params["policy_kwargs"] = literal_call(params["policy_kwargs"])
    return params


def literal_call(expression: str) -> Any:
    """Evaluate a literal or nested ``dict(key=literal, ...)`` expression (rl-zoo3's ``policy_kwargs``)."""

    def convert(node: ast.AST) -> Any:
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
            return {kw.arg: convert(kw.value) for kw in node.keywords}
        if isinstance(node, ast.List | ast.Tuple):
            values = [convert(e) for e in node.elts]
            return values if isinstance(node, ast.List) else tuple(values)
        return ast.literal_eval(node)

    try:
        return convert(ast.parse(expression, mode="eval").body)
    except (SyntaxError, ValueError) as exc:
        raise ValueError(f"cannot read {expression!r}: only literals and dict(...) calls are accepted") from exc


def episode_transitions(episodes: Sequence[Episode]) -> dict[str, np.ndarray]:
    """One row per step of ``episodes``, as an off-policy buffer holds them (only a termination ends a bootstrap)."""
    if not episodes:
        raise ValueError("episodes must not be empty")
    return {
        "observations": np.concatenate([ep.observations[:-1] for ep in episodes]),
        "next_observations": np.concatenate([ep.observations[1:] for ep in episodes]),
        "actions": np.concatenate([ep.actions for ep in episodes]),
        "rewards": np.concatenate([ep.rewards for ep in episodes]).astype(np.float32),
        "terminations": np.concatenate([ep.terminations for ep in episodes]).astype(bool),
    }


def learning_curve(monitor_file: str | os.PathLike) -> list[dict[str, Any]]:
    """The online training episodes of a ``Monitor`` log, each with the env step at which it ended."""
    steps, out = 0, []
    for e in read_monitor(monitor_file):
        steps += int(e["l"])
        out.append({"end_step": steps, "reward": e["r"], "length": int(e["l"]), "collision": bool(e.get("collision", 0.0))})
    return out


@dataclass
class PhaseClock:
    """Wall and CPU seconds of a unit's phases (``with clock.phase("online"): ...``)."""

    wall: dict[str, float] = field(default_factory=dict)
    cpu: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        yield
        self.wall[name] = self.wall.get(name, 0.0) + time.perf_counter() - wall
        self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - cpu

    def as_dict(self) -> dict[str, Any]:
        return {"wall_seconds": {**self.wall, "total": sum(self.wall.values())},
                "cpu_seconds": {**self.cpu, "total": sum(self.cpu.values())}}


def evaluation_record(policy: Any, settings: Mapping[str, Any], inputs: ArmInputs, **kwargs: Any) -> dict[str, Any]:
    """``policy`` (or a checkpoint acting with ``kwargs``) on the inputs' evaluation scenarios."""
    return episodes_record(evaluate(policy, n_episodes=inputs.eval_episodes, seeds=inputs.eval_seeds,
                                    env_settings_=dict(settings), **kwargs))


def episodes_record(episodes: Sequence[Any]) -> dict[str, Any]:
    """Evaluation episodes (:class:`~envs.evaluation.EpisodeMetrics`) as a record: per episode and their means."""
    return {"summary": summarize(list(episodes)), "episodes": episode_rows(episodes)}


def dataset_behaviour(ds: OfflineDataset) -> BehaviourConfig:
    """The behaviour policy that collected ``ds`` (its metadata's ``behaviour_config``; a ``ValueError`` if none)."""
    config = ds.metadata.get("behaviour_config")
    if config is None:
        raise ValueError(f"dataset {ds.path} records no behaviour_config: it was not collected by envs.collection")
    return BehaviourConfig.from_dict(dict(config))


def run_behaviour(inputs: ArmInputs) -> dict[str, Any]:
    """One unit, the reference row of the data: the dataset's behaviour policy on the evaluation scenarios."""
    ds = inputs.load_dataset()
    behaviour = dataset_behaviour(ds)
    clock = PhaseClock()
    with clock.phase("evaluate"):
        evaluation = episodes_record(evaluate_behaviour(behaviour, inputs.eval_episodes, inputs.eval_seeds,
                                                        env_settings(ds)))
    notes = "the dataset's behaviour policy (its behaviour_config) on the evaluation scenarios; nothing trained"
    return unit_record("behaviour", inputs, ds, 0, {"behaviour_config": dict(ds.metadata["behaviour_config"])}, evaluation, [], clock,
                       offline_evaluation=evaluation, notes=notes)


def unit_record(arm: str, inputs: ArmInputs, dataset: OfflineDataset, online_steps: int,
                hyperparams: Mapping[str, Any], evaluation: Mapping[str, Any], curve: list[dict[str, Any]],
                clock: PhaseClock, offline_steps: int = 0, offline_evaluation: Mapping[str, Any] | None = None,
                notes: str = "") -> dict[str, Any]:
    """The JSON record every peer unit returns."""
    record = {
        "arm": arm, "seed": inputs.seed, "env": env_settings(dataset),
        "dataset": {"path": recorded_path(dataset.path), "episodes": len(dataset), "transitions": dataset.total_steps,
                    "seed": dataset.metadata.get("seed")},
        "eval_seeds": list(inputs.eval_seeds), "eval_episodes": inputs.eval_episodes,
        "online_steps": online_steps, "offline_steps": offline_steps, "hyperparams": dict(hyperparams),
        "evaluation": dict(evaluation),
        "offline_evaluation": None if offline_evaluation is None else dict(offline_evaluation),
        "online_episodes": curve, **clock.as_dict(), "notes": notes,
    }
    return json.loads(json.dumps(record, default=_plain))  # plain JSON types: the same record once stored


def _plain(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")
