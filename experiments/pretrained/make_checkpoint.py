"""Build the pretrained Phase-1 UA2C checkpoint of ``MixedTraffic-v0`` in rl-zoo's trained-agents layout.

``python -m experiments make-checkpoint --out rl-trained-agents``, from the repository root (``docs/zoo.md``)."""

from __future__ import annotations

import argparse
import contextlib
import datetime
import inspect
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from unittest import mock

import rl_zoo3
import rl_zoo3.train as zoo_train
import stable_baselines3
import torch

from envs.cli import MAIN_BUDGET
from envs.collection import TRAFFIC_DEFAULTS
from envs.evaluation import evaluate, summarize
from envs.wrappers import DrivingStyleContext
from sb3_ua2c import UA2C
from sb3_ua2c.defaults import defaults
from sb3_ua2c.offline import load_dataset
from sb3_ua2c.pipeline import env_settings, save_atomic
from sb3_ua2c.version import __version__
from sb3_ua2c.zoo import ZOO_KEYS, register

ALGO = "ua2c"
ENV_ID = "MixedTraffic-v0"
EXP_ID = 1
SCRIPT = "python -m experiments make-checkpoint"

#: The budget of ``python -m envs main`` (``MAIN_BUDGET["full"]`` of ``envs/cli.py``), taken from there.
EPISODES, PRETRAIN_STEPS, EVAL_EPISODES = (MAIN_BUDGET["full"][k] for k in ("episodes", "pretrain_steps", "eval_episodes"))


def experiment_dir(out: str | os.PathLike) -> Path:
    """``<out>/ua2c/MixedTraffic-v0_1``: where rl-zoo's ``enjoy -f <out>`` looks by default."""
    return Path(out) / ALGO / f"{ENV_ID}_{EXP_ID}"


def checkpoint_path(out: str | os.PathLike) -> Path:
    """The shipped checkpoint, ``<out>/ua2c/MixedTraffic-v0_1/MixedTraffic-v0.zip``."""
    return experiment_dir(out) / f"{ENV_ID}.zip"


def zoo_train_argv(log_folder: str, conf_file: str, seed: int) -> list[str]:
    """rl-zoo3 ``train`` arguments whose ``config.yml`` / ``args.yml`` go with the checkpoint."""
    return ["--algo", ALGO, "--env", ENV_ID, "--gym-packages", "envs", "--conf-file", conf_file,
            "-f", log_folder, "--seed", str(seed)]


def write_zoo_config(log_folder: str, conf_file: str, seed: int) -> tuple[Path, dict[str, Any]]:
    """Run rl-zoo3's ``train`` up to where it saves ``config.yml`` and ``args.yml``; return where, and what."""
    register()
    captured: dict[str, Any] = {}

    class ConfigOnly(zoo_train.ExperimentManager):  # type: ignore[misc, valid-type]
        def setup_experiment(self) -> tuple[None, dict[str, Any]]:
            _, saved = self.read_hyperparameters()
            self.create_log_folder()
            self._save_config(saved)
            captured.update(params_path=Path(self.params_path), hyperparams=dict(saved))
            return None, saved  # no model: rl-zoo3's train() stops here

    with (mock.patch.object(zoo_train, "ExperimentManager", ConfigOnly),
          mock.patch.object(sys, "argv", ["ua2c-zoo train", *zoo_train_argv(log_folder, conf_file, seed)])):
        zoo_train.train()
    return captured["params_path"], captured["hyperparams"]


def pretrain_arguments(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """``python -m envs pretrain --hyperparams`` of the zoo config: its constructor arguments but those
    ``pretrain`` sets itself, which must agree."""
    kwargs = {key: value for key, value in hyperparams.items() if key not in ZOO_KEYS}
    if isinstance(kwargs.get("policy_kwargs"), str):
        kwargs["policy_kwargs"] = eval(kwargs["policy_kwargs"], {"nn": torch.nn})  # as rl-zoo3 does
    if kwargs.pop("policy", "MlpPolicy") != "MlpPolicy":
        raise ValueError(f"the zoo config's policy must be MlpPolicy, got {hyperparams['policy']!r}")
    for key, value in TRAFFIC_DEFAULTS.items():
        if kwargs.pop(key, value) != value:
            raise ValueError(f"the zoo config's {key}={hyperparams[key]!r} differs from pretrain's {value!r}")
    return kwargs


def style_classifier_of(env_wrapper: Any) -> str | None:
    """The ``--style-classifier`` that gives the observation of the zoo config's ``env_wrapper``."""
    if env_wrapper is None:
        return None
    entries = env_wrapper if isinstance(env_wrapper, list) else [env_wrapper]
    if len(entries) != 1:
        raise ValueError(f"expected one env_wrapper (DrivingStyleContext) in the zoo config, got {env_wrapper!r}")
    entry = entries[0]
    name, kwargs = (entry, {}) if isinstance(entry, str) else next(iter(entry.items()))
    if name != f"{DrivingStyleContext.__module__}.{DrivingStyleContext.__name__}":
        raise ValueError(f"unexpected env_wrapper {name!r} in the zoo config")
    defaults = {k: p.default for k, p in inspect.signature(DrivingStyleContext).parameters.items()}
    for key, value in (kwargs or {}).items():
        if key != "classifier" and value != defaults[key]:
            raise ValueError(f"the zoo config's DrivingStyleContext {key}={value!r} differs from collect's {defaults[key]!r}")
    classifier = (kwargs or {}).get("classifier")
    return "default" if classifier is None else str(classifier)


def drop_optimizer_moments(src: Path, dst: Path) -> Path:
    """Save ``src`` again without the optimizers' per-parameter state (Adam moments): the weights only."""
    model = UA2C.load(src, device="cpu")
    for optimizer in (model.actor.optimizer, model.critic.optimizer):
        optimizer.state.clear()
    return save_atomic(model, dst)


def run_cli(argv: list[str]) -> float:
    """Run ``python -m envs <argv>`` (the project's command line); return its wall time [s]."""
    print(f"$ {_shell(argv)}", flush=True)
    t0 = time.time()
    code = subprocess.run([sys.executable, "-m", "envs", *argv]).returncode
    if code != 0:
        raise SystemExit(f"python -m envs {argv[0]} failed with exit code {code}")
    return time.time() - t0


def _shell(argv: Sequence[str]) -> str:
    """``python -m envs <argv>`` as the README shows it (an argument with a space, brace, quote or bracket quoted)."""
    return "python -m envs " + " ".join(f"'{a}'" if any(c in a for c in " {}\"[]") else a for a in argv)


def check_no_machine_paths(folder: Path, forbidden: Sequence[str]) -> None:
    """Fail if a text file of ``folder`` mentions a path of this machine."""
    for path in folder.rglob("*"):
        if path.is_file() and path.suffix in (".yml", ".md", ".txt"):
            text = path.read_text()
            for word in forbidden:
                if word and word in text:
                    raise RuntimeError(f"{path} contains the local path {word!r}")


def readme(info: dict[str, Any]) -> str:
    s = info["summary"]
    rows = "\n".join(f"| {name} | {value} |" for name, value in (
        ("reward (mean)", f"{s['reward']:.2f}"), ("cumulative jerk [m/s³] (mean)", f"{s['cumulative_jerk']:.1f}"),
        ("jerk per step [m/s³] (mean)", f"{s['jerk_per_step']:.3f}"), ("collision rate", f"{s['collision']:.2f}"),
        ("merge success rate", f"{s['merge_success']:.2f}"), ("mean speed [m/s]", f"{s['mean_speed']:.2f}"),
        ("mean executed chunk length L_t", f"{s['mean_executed_length']:.2f}")))
    episodes = "\n".join(
        f"| {r.seed} | {r.reward:.2f} | {r.length} | {r.cumulative_jerk:.1f} | {'yes' if r.collision else 'no'} "
        f"| {'yes' if r.merge_success else 'no'} | {r.mean_executed_length:.2f} |" for r in info["episodes"])
    return f"""# UA2C on MixedTraffic-v0, Phase 1 (offline pre-training)

`MixedTraffic-v0.zip` is a UA2C checkpoint pre-trained offline (Phase 1, fixed chunks of k = 5) on
SUMO-driven data of `MixedTraffic-v0`, with the driving-style context c_t in the observation
(38 numbers). Its hyperparameters and networks are those of the `MixedTraffic-v0` entry of
`zoo_configs/ua2c.yml`, so rl-zoo's `enjoy -f rl-trained-agents` runs it and `train -i` continues
from it. `MixedTraffic-v0/config.yml` and `MixedTraffic-v0/args.yml` are the files rl-zoo3's `train`
writes for that entry (`{info['zoo_command']}`); the weights themselves come from offline
pre-training, not from rl-zoo3's online training.

## How it was made

```bash
{SCRIPT} --out {info['out_name']}
```

which runs (torch on 1 thread; the dataset goes to a temporary directory):

```bash
{info['collect_command']}
{info['pretrain_command']}
```

| | |
|---|---|
| date (UTC) | {info['date']} |
| sb3-ua2c / Stable-Baselines3 / rl-zoo3 / torch | {info['versions']} |
| dataset | {info['n_episodes']} episodes, {info['total_steps']} steps (behaviour policy: SUMO's driver with takeovers, `BehaviourConfig()` defaults; mean return {info['mean_return']:.2f}) |
| gradient steps | {info['steps']} (batch size {info['batch_size']}) |
| seed | {info['seed']} (collection, networks and minibatches) |
| wall time | collection {info['collect_seconds']:.0f} s, pre-training {info['pretrain_seconds']:.0f} s |
| checkpoint size | {info['size']} bytes |

The checkpoint holds the weights (actor, critic, target critic) and the saved hyperparameters; the
optimizers' moment estimates are left out ({info['full_size']} bytes with them), so Adam starts
afresh when training continues. Acting, loading and continuing need nothing else.

## Evaluation

`envs.evaluation.evaluate` on {len(info['episodes'])} held-out scenarios (evaluation seed {info['eval_seed']}:
resets with seeds {info['episodes'][0].seed}..{info['episodes'][-1].seed}, none of them in the dataset), deterministic
stateful `predict` with adaptive execution (δ = {info['entropy_threshold']}), as `python -m envs main` evaluates:

| metric | value |
|---|---|
{rows}

| reset seed | reward | steps | cumulative jerk | collision | merged | mean L_t |
|---|---|---|---|---|---|---|
{episodes}
"""


def main(argv: Sequence[str] | None = None, prog: str = SCRIPT) -> int:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="rl-trained-agents", help="trained-agents folder (rl-zoo's -f)")
    parser.add_argument("--conf-file", default="zoo_configs/ua2c.yml")
    parser.add_argument("--episodes", type=int, default=EPISODES, help="default: main's 200")
    parser.add_argument("--steps", type=int, default=PRETRAIN_STEPS, help="gradient steps (default: main's 3000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=EVAL_EPISODES, help="default: main's 10")
    parser.add_argument("--work", default=None, help="keep the dataset and the full checkpoint here")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing <out>/ua2c/MixedTraffic-v0_1")
    args = parser.parse_args(argv)

    torch.set_num_threads(1)
    out = Path(args.out)
    log_folder = os.path.relpath(out) if out.is_absolute() else str(out)
    dest = experiment_dir(out)
    if dest.exists():
        if not args.overwrite:
            raise SystemExit(f"{dest} exists: pass --overwrite to replace it")
        shutil.rmtree(dest)
    others = sorted((out / ALGO).glob(f"{ENV_ID}_[0-9]*"))
    if others:
        raise SystemExit(f"{others[0]} exists: rl-zoo would number this experiment after it")

    params_path, hyperparams = write_zoo_config(log_folder, args.conf_file, args.seed)
    if params_path.resolve() != (dest / ENV_ID).resolve():
        raise RuntimeError(f"rl-zoo3 wrote to {params_path}, expected {dest / ENV_ID}")
    (params_path / "command.txt").write_text(f"{SCRIPT} --out {out.name}\n")
    with contextlib.ExitStack() as stack:
        work = Path(args.work) if args.work else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        info = build(args, out, work, hyperparams)
        (dest / "README.md").write_text(readme(info))
    check_no_machine_paths(dest, [str(Path.cwd()), str(Path.home()), tempfile.gettempdir() + "/"])
    print(json.dumps(info["summary"], indent=1))
    print(f"checkpoint: {checkpoint_path(out)} ({info['size']} bytes)")
    return 0


def build(args: argparse.Namespace, out: Path, work: Path, hyperparams: dict[str, Any]) -> dict[str, Any]:
    """Collect, pre-train, save and evaluate the checkpoint (the dataset in ``work``); return what the README shows."""
    style = style_classifier_of(hyperparams.get("env_wrapper"))
    algo_kwargs = pretrain_arguments(hyperparams)
    dataset_dir, full_ckpt = work / "dataset", work / "pretrained.zip"
    collect_argv = [
        "collect", "--episodes", str(args.episodes), "--seed", str(args.seed), "--out", str(dataset_dir),
        "--overwrite", "--no-progress", "--threads", "1"] + (["--style-classifier", style] if style else [])
    pretrain_argv = ["pretrain", "--dataset", str(dataset_dir), "--out", str(full_ckpt), "--steps", str(args.steps),
                     "--seed", str(args.seed), "--hyperparams", json.dumps(algo_kwargs, sort_keys=True),
                     "--no-progress", "--threads", "1"]
    collect_seconds = run_cli(collect_argv)
    pretrain_seconds = run_cli(pretrain_argv)
    dataset = load_dataset(dataset_dir)
    shipped = drop_optimizer_moments(full_ckpt, checkpoint_path(out))
    eval_seed = args.seed + 100
    reset_seeds = {1000 * eval_seed + i for i in range(args.eval_episodes)}  # envs.evaluation.evaluate's resets
    if reset_seeds & {episode.seed for episode in dataset.episodes}:
        raise RuntimeError("the evaluation scenarios overlap the dataset's")
    t0 = time.time()
    results = evaluate(shipped, n_episodes=args.eval_episodes, seeds=(eval_seed,), env_settings_=env_settings(dataset))
    print(f"evaluation: {time.time() - t0:.0f} s", flush=True)

    trained_with = {**defaults(), **algo_kwargs}  # the zoo entry's values over the library's defaults

    def shown(cmd: list[str]) -> str:
        return _shell(cmd).replace(str(dataset_dir), "DATA/dataset").replace(str(full_ckpt), "DATA/pretrained.zip")

    return {
        "out_name": out.name, "collect_command": shown(collect_argv), "pretrain_command": shown(pretrain_argv),
        "zoo_command": "ua2c-zoo train " + " ".join(zoo_train_argv("rl-trained-agents", args.conf_file, args.seed)),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "versions": f"{__version__} / {stable_baselines3.__version__} / {rl_zoo3.__version__} / {torch.__version__}",
        "n_episodes": len(dataset), "total_steps": dataset.total_steps, "mean_return": dataset.metadata["mean_return"],
        "steps": args.steps, "batch_size": trained_with["batch_size"], "seed": args.seed, "eval_seed": eval_seed,
        "collect_seconds": collect_seconds, "pretrain_seconds": pretrain_seconds,
        "size": shipped.stat().st_size, "full_size": full_ckpt.stat().st_size,
        "entropy_threshold": trained_with["entropy_threshold"], "summary": summarize(results), "episodes": results,
    }
