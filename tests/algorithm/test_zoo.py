"""rl-zoo integration (issue 6): YAML configs, the launcher, continuing from checkpoints, the sampler."""

from __future__ import annotations

import importlib
import inspect
import math
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import optuna
import pytest
import torch
import yaml
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution
from stable_baselines3 import SAC
from torch import nn

from sb3_ua2c import zoo
from sb3_ua2c.defaults import defaults
from sb3_ua2c.presets import PAPER

REPO = Path(__file__).resolve().parents[2]
CONFIGS = REPO / "zoo_configs"
PAPER_FILE = CONFIGS / "ua2c_paper.py"


def _read_config(path: Path) -> dict:
    """The entries of a zoo config as rl-zoo3 reads them (a ``.py`` file is run, its ``hyperparams`` kept)."""
    if path.suffix == ".py":
        namespace: dict = {}
        exec(path.read_text(), namespace)
        return namespace["hyperparams"]
    return yaml.safe_load(path.read_text())


# --------------------------------------------------------------------------- YAML keys


def _algo_class(name: str) -> type:
    zoo.register()
    from rl_zoo3 import ALGOS

    return ALGOS[name]


def _constructor_arguments(cls: type) -> set[str]:
    return set(inspect.signature(cls.__init__).parameters) - {"self", "args", "kwargs"}


def unknown_keys(algo_cls: type, entry: dict) -> list[str]:
    """Keys of one rl-zoo entry that are neither constructor arguments nor rl-zoo keys (incl. policy_kwargs)."""
    unknown = sorted(set(entry) - _constructor_arguments(algo_cls) - zoo.ZOO_KEYS - {"policy"})
    if "policy_kwargs" in entry:
        # rl-zoo3 evaluates the string in a namespace that has ``nn`` (torch.nn) and builtins.
        policy_kwargs = entry["policy_kwargs"]
        if isinstance(policy_kwargs, str):
            policy_kwargs = eval(policy_kwargs, {"nn": nn})
        policy_cls = algo_cls.policy_aliases[entry["policy"]]
        unknown += [
            f"policy_kwargs.{k}" for k in sorted(set(policy_kwargs) - _constructor_arguments(policy_cls))
        ]
    wrappers = entry.get("env_wrapper") or []
    for wrapper in wrappers if isinstance(wrappers, list) else [wrappers]:
        name, kwargs = next(iter(wrapper.items())) if isinstance(wrapper, dict) else (wrapper, {})
        module, _, cls_name = name.rpartition(".")
        wrapper_cls = getattr(importlib.import_module(module), cls_name)
        unknown += [
            f"{cls_name}.{k}" for k in sorted(set(kwargs or {}) - _constructor_arguments(wrapper_cls))
        ]
    return unknown


def test_unknown_keys_detects_a_misspelled_key():
    entry = {"policy": "MlpPolicy", "n_timesteps": 10, "learning_rate": 1e-3, "learnig_starts": 5,
             "policy_kwargs": "dict(net_arch=[8], n_critic=3)",
             "env_wrapper": [{"envs.wrappers.DrivingStyleContext": {"update_evry": 5}}]}  # fmt: skip
    assert unknown_keys(SAC, entry) == [
        "learnig_starts", "policy_kwargs.n_critic", "DrivingStyleContext.update_evry",
    ]  # fmt: skip


@pytest.mark.parametrize("config", sorted(CONFIGS.glob("*.*")), ids=lambda p: p.name)
def test_yaml_keys_are_constructor_arguments_or_zoo_keys(config):
    entries = _read_config(config)
    assert {"Pendulum-v1", "MixedTraffic-v0"} <= set(entries)
    algo_cls = _algo_class(config.stem.removesuffix("_paper"))  # ua2c_paper.py: UA2C's paper preset
    for env_id, entry in entries.items():
        assert unknown_keys(algo_cls, entry) == [], f"{config.name}:{env_id}"


def test_baselines_share_env_ids_and_budgets_with_ua2c():
    configs = {p.stem: _read_config(p) for p in CONFIGS.glob("*.*")}
    assert set(configs) == {"ua2c", "ua2c_paper", "sac", "tqc", "crossq"}
    assert set(configs["sac"]) == set(configs["tqc"]) == set(configs["crossq"]) == set(configs["ua2c"])
    assert set(configs["ua2c_paper"]) == set(configs["ua2c"])
    # Same training budget and discount on each env id: the comparisons are like for like.
    for env_id in configs["ua2c"]:
        for key in ("n_timesteps", "gamma"):
            values = {algo: float(entries[env_id].get(key, 0.99)) for algo, entries in configs.items()}
            assert len(set(values.values())) == 1, (env_id, key, values)


# --------------------------------------------------------------------------- one home per default


def _differs(value, default) -> bool:
    if isinstance(value, dict) and isinstance(default, dict):
        return any(_differs(v, default.get(k)) for k, v in value.items())
    if isinstance(value, list | tuple) and isinstance(default, list | tuple):
        return list(value) != list(default)
    return value != default


def stated_default_problems(text: str, reference: dict) -> list[str]:
    """
    The lines of a UA2C zoo YAML that break "one home per default": a hyperparameter stated with the
    value of ``reference`` (``defaults()``: it must be left out), or with another value but no ``#``
    comment on its line saying why. ``policy_kwargs`` (a ``dict(...)`` string or a mapping) is
    checked key by key; rl-zoo3's own keys are not hyperparameters of the algorithm.
    """
    lines = text.splitlines()
    problems = []
    for env_node, entry_node in yaml.compose(text).value:
        for key_node, value_node in entry_node.value:
            key, line = key_node.value, key_node.start_mark.line
            if key not in reference:
                continue
            value = yaml.safe_load(yaml.serialize(value_node))
            if key == "policy_kwargs":
                value = eval(value, {"nn": nn}) if isinstance(value, str) else value
                stated = [(f"policy_kwargs.{k}", v, reference[key].get(k)) for k, v in value.items()]
            else:
                stated = [(key, value, reference[key])]
            commented = "#" in lines[value_node.end_mark.line][value_node.end_mark.column :]
            for name, value, default in stated:
                where = f"{env_node.value}.{name} (line {line + 1})"
                if not _differs(value, default):
                    problems.append(f"{where}: {value!r} is the default, leave it out")
                elif not commented:
                    problems.append(f"{where}: {value!r} differs from the default {default!r} without a comment")
    return problems


def test_stated_default_problems_finds_defaults_and_unexplained_values():
    reference = {"q_weight": 0.3, "history_len": 4, "gamma": 0.99,
                 "policy_kwargs": {"net_arch": [512, 512], "n_elite": 8}}  # fmt: skip
    text = """\
Env-v0:
  n_timesteps: 100                 # not a hyperparameter of the algorithm
  q_weight: 0.3
  history_len: 1                   # fully observed
  gamma: 0.9
  policy_kwargs: "dict(net_arch=[512, 512], n_elite=1)"
Other-v0:
  q_weight: !!float 3e-1  # a comment does not excuse the default
  policy_kwargs: {net_arch: [64], n_elite: 8}  # small task
"""
    assert stated_default_problems(text, reference) == [
        "Env-v0.q_weight (line 3): 0.3 is the default, leave it out",
        "Env-v0.gamma (line 5): 0.9 differs from the default 0.99 without a comment",
        "Env-v0.policy_kwargs.net_arch (line 6): [512, 512] is the default, leave it out",
        "Env-v0.policy_kwargs.n_elite (line 6): 1 differs from the default 8 without a comment",
        "Other-v0.q_weight (line 8): 0.3 is the default, leave it out",
        "Other-v0.policy_kwargs.n_elite (line 9): 8 is the default, leave it out",
    ]
    assert stated_default_problems("Env-v0:\n  history_len: 1  # fully observed\n", reference) == []


def test_ua2c_yaml_states_no_default_and_says_why_for_every_value():
    assert stated_default_problems((CONFIGS / "ua2c.yml").read_text(), defaults()) == []


def test_paper_file_is_the_preset_on_ua2c_yaml_problems():
    paper, default = _read_config(PAPER_FILE), _read_config(CONFIGS / "ua2c.yml")
    assert set(paper) == set(default)
    for env_id, entry in paper.items():
        assert {key: entry[key] for key in PAPER} == PAPER
        # the rest (budget, buffer, observation, action space, wrapper) is ua2c.yml's entry
        assert {k: v for k, v in entry.items() if k not in PAPER} == default[env_id], env_id


# --------------------------------------------------------------------------- launcher arguments


@pytest.fixture
def zoo_argv(monkeypatch) -> list[list[str]]:
    """The ``sys.argv`` rl-zoo3's ``train`` / ``enjoy`` receive from the launcher (rl-zoo3 itself not run)."""
    import rl_zoo3.enjoy
    import rl_zoo3.train

    seen = []
    for module, name in ((rl_zoo3.train, "train"), (rl_zoo3.enjoy, "enjoy")):
        monkeypatch.setattr(module, name, lambda name=name: seen.append([name, *sys.argv]))
    return seen


def test_main_defaults_algo_and_turns_optimize_into_train(zoo_argv):
    zoo.main(["train", "--env", "Pendulum-v1", "--conf-file", "c.yml"])
    zoo.main(["optimize", "--algo", "sac", "--n-trials", "2"])
    zoo.main(["enjoy", "--algo=sac", "-f", "logs"])
    assert zoo_argv == [
        ["train", "ua2c-zoo train", "--algo", "ua2c", "--env", "Pendulum-v1", "--conf-file", "c.yml"],
        ["train", "ua2c-zoo train", "--algo", "sac", "--n-trials", "2", "--optimize-hyperparameters"],
        ["enjoy", "ua2c-zoo enjoy", "--algo=sac", "-f", "logs"],
    ]


def test_main_prints_usage_for_help_nothing_or_an_unknown_command(capsys, zoo_argv):
    for argv, code in (([], 2), (["fit"], 2), (["--help"], 0)):
        with pytest.raises(SystemExit) as excinfo:
            zoo.main(argv)
        assert excinfo.value.code == code
        assert "usage: ua2c-zoo {train,enjoy,optimize}" in capsys.readouterr().out
    assert zoo_argv == []


def test_register_installs_ua2c_and_the_experiment_manager():
    import rl_zoo3
    import rl_zoo3.train
    from rl_zoo3.exp_manager import ExperimentManager

    from sb3_ua2c import UA2C

    zoo.register()
    assert rl_zoo3.ALGOS["ua2c"] is UA2C
    assert rl_zoo3.train.ExperimentManager.__name__ == "UA2CExperimentManager"
    assert issubclass(rl_zoo3.train.ExperimentManager, ExperimentManager)


# --------------------------------------------------------------------------- train / enjoy / continue


def _train(log_folder: Path, algo: str, *extra: str, env_id: str = "Pendulum-v1") -> None:
    zoo.main(
        ["train", "--algo", algo, "--env", env_id, "--conf-file", str(CONFIGS / f"{algo}.yml"),
         "-f", str(log_folder), "--eval-freq", "-1", "--verbose", "0", "--num-threads", "1", *extra]
    )  # fmt: skip


def _policy_tensors(model) -> list[torch.Tensor]:
    return [t.detach().clone() for t in model.policy.state_dict().values()]


def test_train_enjoy_and_continue_sac(tmp_path, capsys):
    tiny = ["-params", "learning_starts:100", "batch_size:32", "policy_kwargs:dict(net_arch=[16])"]
    _train(tmp_path, "sac", "-n", "300", "--seed", "1", *tiny)
    first = tmp_path / "sac" / "Pendulum-v1_1" / "Pendulum-v1.zip"
    start = SAC.load(first)
    assert start.num_timesteps == 300

    # -i with no gradient step: timesteps grow, weights are exactly the checkpoint's.
    _train(
        tmp_path, "sac", "-n", "200", "--seed", "2", "-i", str(first), "-params", "learning_starts:1000000"
    )
    frozen = SAC.load(tmp_path / "sac" / "Pendulum-v1_2" / "Pendulum-v1.zip")
    assert frozen.num_timesteps == 500
    assert all(
        torch.equal(a, b) for a, b in zip(_policy_tensors(start), _policy_tensors(frozen), strict=True)
    )

    # -i with learning: the same start, then the weights move.
    _train(tmp_path, "sac", "-n", "200", "--seed", "3", "-i", str(first))
    moved = SAC.load(tmp_path / "sac" / "Pendulum-v1_3" / "Pendulum-v1.zip")
    assert moved.num_timesteps == 500
    assert not all(
        torch.equal(a, b) for a, b in zip(_policy_tensors(start), _policy_tensors(moved), strict=True)
    )

    capsys.readouterr()
    zoo.main(["enjoy", "--algo", "sac", "--env", "Pendulum-v1", "-f", str(tmp_path), "--exp-id", "1",
              "--no-render", "-n", "250", "--num-threads", "1"])  # fmt: skip
    out = capsys.readouterr().out
    assert "Loading " + str(first) in out
    assert "Episode Length 200" in out  # Pendulum-v1 truncates at 200 steps


# Tiny UA2C: the launcher tests check plumbing, not learning.
TINY_UA2C = {
    "learning_starts": 100,
    "batch_size": 32,
    "buffer_size": 1000,
    "chunk_size": 3,
    "history_len": 2,
    "flow_steps": 3,
    "target_flow_steps": 2,
    "n_candidates": 8,
    "n_target_candidates": 2,
    "policy_kwargs": {"net_arch": [16]},
}


def _params(base: dict | None = None, **overrides) -> list[str]:
    """``-params key:value ...`` for rl-zoo3 (values are ``eval``'d by rl-zoo3)."""
    params = {**(TINY_UA2C if base is None else base), **overrides}
    return ["-params", *(f"{k}:{v!r}" for k, v in params.items())]


def test_train_enjoy_and_continue_ua2c(tmp_path, capsys):
    from sb3_ua2c import UA2C

    _train(tmp_path, "ua2c", "-n", "300", "--seed", "1", *_params())
    first = tmp_path / "ua2c" / "Pendulum-v1_1" / "Pendulum-v1.zip"
    start = UA2C.load(first)
    assert start.num_timesteps == 300
    assert start.chunk_size == 3 and start.policy.net_arch == [16]

    # -i without gradient steps: timesteps grow and the weights are exactly the checkpoint's.
    _train(tmp_path, "ua2c", "-n", "200", "--seed", "2", "-i", str(first), *_params(learning_starts=10**6))
    frozen = UA2C.load(tmp_path / "ua2c" / "Pendulum-v1_2" / "Pendulum-v1.zip")
    assert frozen.num_timesteps == 500
    assert all(
        torch.equal(a, b) for a, b in zip(_policy_tensors(start), _policy_tensors(frozen), strict=True)
    )

    # enjoy: rl-zoo3 passes state/episode_start, so the adaptive chunks are executed statefully.
    capsys.readouterr()
    zoo.main(["enjoy", "--env", "Pendulum-v1", "-f", str(tmp_path), "--exp-id", "1", "--no-render",
              "-n", "250", "--num-threads", "1", "--deterministic"])  # fmt: skip
    out = capsys.readouterr().out
    assert "Loading " + str(first) in out
    assert "Episode Length 200" in out


@pytest.fixture(scope="module")
def mixed_traffic_checkpoint(tmp_path_factory) -> Path:
    """UA2C trained 120 steps on MixedTraffic-v0 through the launcher with the YAML entry (tiny networks,
    style-context wrapper as in the YAML)."""
    log_folder = tmp_path_factory.mktemp("zoo-mixed-traffic")
    tiny = {k: v for k, v in TINY_UA2C.items() if k not in ("chunk_size", "learning_starts")}
    _train(log_folder, "ua2c", "-n", "120", "--seed", "0", "--gym-packages", "envs",
           *_params(tiny, learning_starts=40), env_id="MixedTraffic-v0")  # fmt: skip
    return log_folder / "ua2c" / "MixedTraffic-v0_1" / "MixedTraffic-v0.zip"


def test_train_ua2c_on_mixed_traffic_with_the_yaml_entry(mixed_traffic_checkpoint):
    from stable_baselines3.common.save_util import load_from_zip_file

    data, params, _ = load_from_zip_file(mixed_traffic_checkpoint, device="cpu", print_system_info=False)
    assert data["num_timesteps"] == 120
    assert data["chunk_size"] == defaults()["chunk_size"] == 5  # ua2c.yml leaves it to the default
    # MixedTraffic-v0's 20 numbers + the style context c_t of Eq. 6 (6 slots x 3 styles)
    assert data["observation_space"].shape == (38,)
    assert data["action_space"].shape == (2,)
    assert "policy" in params


def test_enjoy_the_mixed_traffic_checkpoint(mixed_traffic_checkpoint, capsys):
    from sb3_ua2c import UA2C

    model = UA2C.load(mixed_traffic_checkpoint)
    assert model.policy.discrete_dims == {1: 3}  # lane change: 3 categories
    capsys.readouterr()
    zoo.main(["enjoy", "--env", "MixedTraffic-v0", "--gym-packages", "envs", "--no-render", "-n", "200",
              "-f", str(mixed_traffic_checkpoint.parents[2]), "--num-threads", "1"])  # fmt: skip
    out = capsys.readouterr().out
    assert "Loading " + str(mixed_traffic_checkpoint) in out
    assert "Episode Length" in out  # an episode ends within 200 steps (time limit 40 s at 0.2 s)


# --------------------------------------------------------------------------- process-exclusive envs

# Short MixedTraffic-v0 episodes keep the runs below: 20 training steps per episode (4 s), 10 per
# evaluation episode (the AV is still on the empty ramp after 2 s, so none ends earlier).
SHORT_EPISODES = ["--env-kwargs", "time_limit:4.0", "--eval-env-kwargs", "time_limit:2.0"]


def _mixed_traffic_args(log_folder: Path, *extra: str) -> list[str]:
    return ["--env", "MixedTraffic-v0", "--gym-packages", "envs", "--conf-file", str(CONFIGS / "ua2c.yml"),
            "-f", str(log_folder), "--verbose", "0", "--num-threads", "1", "--seed", "0", *extra]  # fmt: skip


def test_process_exclusive_envs_are_detected_from_the_registry():
    import envs  # noqa: F401  (registers MixedTraffic-v0)

    assert zoo.process_exclusive("MixedTraffic-v0") is True
    assert zoo.process_exclusive("Pendulum-v1") is False


def test_train_on_mixed_traffic_with_evaluation(tmp_path):
    """rl-zoo3 evaluates in the training process's lifetime: with --vec-env subproc both envs run in
    their own processes."""
    tiny = {k: v for k, v in TINY_UA2C.items() if k not in ("chunk_size", "learning_starts")}
    zoo.main(["train", *_mixed_traffic_args(tmp_path, "-n", "80", "--eval-freq", "40", "--eval-episodes", "2",
                                            "--vec-env", "subproc", *SHORT_EPISODES,
                                            *_params(tiny, learning_starts=30))])  # fmt: skip
    run = tmp_path / "ua2c" / "MixedTraffic-v0_1"
    evaluations = np.load(run / "evaluations.npz")
    np.testing.assert_array_equal(evaluations["timesteps"], [40, 80])
    np.testing.assert_array_equal(evaluations["ep_lengths"], [[10, 10], [10, 10]])
    assert (run / "best_model.zip").is_file() and (run / "MixedTraffic-v0.zip").is_file()
    monitor = (run / "0.monitor.csv").read_text().splitlines()[2:]  # after the JSON and the header line
    assert [line.split(",")[1] for line in monitor] == ["20"] * 4  # 80 steps = 4 training episodes


def test_dummy_vec_env_with_several_sumo_envs_stops_before_any_env_is_built(tmp_path):
    # rl-zoo3's default --vec-env dummy with an evaluation env, with n_envs 2, and in a sweep
    for extra in (["--eval-freq", "40"], ["--vec-env", "dummy", "--eval-freq", "-1", "-params", "n_envs:2"]):
        with pytest.raises(ValueError, match="--vec-env dummy would put several MixedTraffic-v0 envs in one "
                                             "process.*pass --vec-env subproc"):  # fmt: skip
            zoo.main(["train", *_mixed_traffic_args(tmp_path, "-n", "40", *extra)])
    assert not list(tmp_path.rglob("*.monitor.csv"))  # no env was built
    # a sweep: rl-zoo3 builds and closes one env to read the spaces, then each trial needs two
    with pytest.raises(ValueError, match="--vec-env subproc"):
        zoo.main(["optimize", *_mixed_traffic_args(tmp_path, "-n", "40", "--n-trials", "1")])


def test_dummy_vec_env_with_one_sumo_env_runs_in_process(tmp_path):
    from envs.sumo import process_owner

    zoo.main(["train", *_mixed_traffic_args(tmp_path, "-n", "40", "--eval-freq", "-1",
                                            *SHORT_EPISODES, *_params(learning_starts=10**6))])  # fmt: skip
    monitor = (tmp_path / "ua2c" / "MixedTraffic-v0_1" / "0.monitor.csv").read_text().splitlines()[2:]
    assert [line.split(",")[1] for line in monitor] == ["20", "20"]
    assert process_owner() is None  # rl-zoo3 closed the in-process env


def _journal(path: Path) -> optuna.storages.JournalStorage:
    """The study storage rl-zoo3 opens for ``--storage *.log`` (Optuna's journal file)."""
    return optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(path)))


@pytest.mark.slow
def test_optimize_on_mixed_traffic(tmp_path):
    storage = tmp_path / "sweep.log"
    zoo.main(["optimize", *_mixed_traffic_args(tmp_path, "-n", "40", "--vec-env", "subproc", "--n-trials", "1",
                                               "--n-evaluations", "2", "--eval-episodes", "1", "--sampler", "random",
                                               "--pruner", "none", "--no-optim-plots", "--storage", str(storage),
                                               "--study-name", "mt", *SHORT_EPISODES, "-params",
                                               "learning_starts:1000000", "buffer_size:1000")])  # fmt: skip
    (trial,) = optuna.load_study(study_name="mt", storage=_journal(storage)).trials
    assert trial.state == optuna.trial.TrialState.COMPLETE
    assert math.isfinite(trial.value)


@pytest.mark.slow
def test_two_workers_share_one_study_in_a_journal_file(tmp_path):
    """Several workers, one study: Optuna's journal file through rl-zoo3's ``--storage *.log``; then
    ``--trial-id`` retrains with a stored trial's parameters."""
    storage = tmp_path / "sweep.log"
    common = ["--env", "Pendulum-v1", "--conf-file", str(CONFIGS / "ua2c.yml"), "-n", "40", "--storage", str(storage),
              "--study-name", "pendulum", "--num-threads", "1", "--verbose", "0", "-params",
              "learning_starts:1000000", "buffer_size:1000"]  # fmt: skip
    sweep = ["optimize", *common, "--n-trials", "1", "--n-evaluations", "1", "--eval-episodes", "1",
             "--sampler", "random", "--pruner", "none", "--no-optim-plots"]  # fmt: skip
    workers = [
        subprocess.Popen([sys.executable, "-m", "sb3_ua2c.zoo", *sweep, "--seed", str(seed), "-f", f"logs{seed}"],
                         cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        for seed in (1, 2)
    ]  # fmt: skip
    for worker in workers:
        _, stderr = worker.communicate(timeout=280)
        assert worker.returncode == 0, stderr[-3000:]
    trials = optuna.load_study(study_name="pendulum", storage=_journal(storage)).trials
    assert [t.number for t in trials] == [0, 1]
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    assert trials[0].params != trials[1].params  # each worker drew its own point

    zoo.main(["train", *common, "--trial-id", "1", "-f", str(tmp_path / "retrain"), "--eval-freq", "-1"])
    from sb3_ua2c import UA2C

    model = UA2C.load(tmp_path / "retrain" / "ua2c" / "Pendulum-v1_1" / "Pendulum-v1.zip")
    assert model.chunk_size == trials[1].params["chunk_size"]
    assert model.policy.net_arch == list(zoo.NET_ARCHS[trials[1].params["net_arch"]])


def test_continue_rejects_a_chunk_size_that_differs_from_the_checkpoint(tmp_path):
    _train(tmp_path, "ua2c", "-n", "150", "--seed", "1", *_params())
    first = tmp_path / "ua2c" / "Pendulum-v1_1" / "Pendulum-v1.zip"
    # UA2C.load refuses it (sb3_ua2c.checkpoints): the networks were built for chunk_size=3
    with pytest.raises(ValueError, match="networks do not match this UA2C model .*chunk_size"):
        _train(tmp_path, "ua2c", "-n", "100", "-i", str(first), *_params(chunk_size=4))


def _random_episodes(n_episodes: int, seed: int) -> list:
    from sb3_ua2c.offline import Episode

    env = gym.make("Pendulum-v1")
    env.action_space.seed(seed)
    episodes = []
    for i in range(n_episodes):
        obs, _ = env.reset(seed=seed + i)
        observations, actions, rewards, terminations, truncations = [obs], [], [], [], []
        done = False
        while not done:
            action = env.action_space.sample()
            obs, reward, terminated, truncated, _ = env.step(action)
            observations.append(obs)
            actions.append(action)
            rewards.append(reward)
            terminations.append(terminated)
            truncations.append(truncated)
            done = terminated or truncated
        episodes.append(Episode(np.array(observations), np.array(actions), np.array(rewards, dtype=np.float32),
                                np.array(terminations), np.array(truncations)))  # fmt: skip
    return episodes


def test_continue_online_from_an_offline_pretrained_checkpoint(tmp_path):
    from sb3_ua2c import UA2C

    kwargs = {**TINY_UA2C, "learning_starts": 0}
    offline = UA2C("MlpPolicy", "Pendulum-v1", seed=0, **kwargs)
    assert offline.add_offline_episodes(_random_episodes(2, seed=0)) == 400
    offline.pretrain(20)
    n_offline = offline.replay_buffer.n_samples()[1]
    assert n_offline > 0
    # rl-zoo3 loads replay_buffer.pkl found next to the checkpoint: the offline data comes along.
    (tmp_path / "offline").mkdir()
    checkpoint = tmp_path / "offline" / "pretrained.zip"
    offline.save(checkpoint)
    offline.save_replay_buffer(tmp_path / "offline" / "replay_buffer.pkl")

    _train(tmp_path, "ua2c", "-n", "200", "--seed", "3", "-i", str(checkpoint), "--save-replay-buffer",
           *_params(learning_starts=0))  # fmt: skip
    run = tmp_path / "ua2c" / "Pendulum-v1_1"
    online = UA2C.load(run / "Pendulum-v1.zip")
    assert online.num_timesteps == 200  # the offline checkpoint had 0 environment steps
    online.load_replay_buffer(run / "replay_buffer.pkl")
    n_online_after, n_offline_after = online.replay_buffer.n_samples()
    assert n_offline_after == n_offline and n_online_after > 0
    # Online updates moved the pre-trained weights.
    assert not all(
        torch.equal(a, b) for a, b in zip(_policy_tensors(offline), _policy_tensors(online), strict=True)
    )


def test_offline_dataset_callback_adds_the_dataset_when_continuing(tmp_path):
    from sb3_ua2c import UA2C
    from sb3_ua2c.offline import write_dataset

    env = gym.make("Pendulum-v1")
    episodes = _random_episodes(2, seed=5)
    dataset = write_dataset(
        episodes, tmp_path / "data" / "pendulum-v0", env.observation_space, env.action_space
    )
    # A checkpoint without replay_buffer.pkl: the YAML/-params callback brings the data in.
    checkpoint = tmp_path / "fresh.zip"
    UA2C("MlpPolicy", env, seed=0, **TINY_UA2C).save(checkpoint)
    callback = [{"sb3_ua2c.zoo.OfflineDatasetCallback": {"dataset": str(dataset)}}]
    _train(tmp_path, "ua2c", "-n", "50", "-i", str(checkpoint), "--save-replay-buffer",
           *_params(learning_starts=10**6, callback=callback))  # fmt: skip
    buffer_model = UA2C("MlpPolicy", env, **TINY_UA2C)
    buffer_model.load_replay_buffer(tmp_path / "ua2c" / "Pendulum-v1_1" / "replay_buffer.pkl")
    # 2 episodes x 200 steps, one k-step window per start
    assert buffer_model.replay_buffer.n_samples()[1] == 400


def test_offline_dataset_callback_rejects_bad_input():
    with pytest.raises(ValueError, match="dataset must be a directory path"):
        zoo.OfflineDatasetCallback(dataset="")
    callback = zoo.OfflineDatasetCallback(dataset="anywhere")
    sac = SAC("MlpPolicy", "Pendulum-v1", buffer_size=10)
    callback.init_callback(sac)
    with pytest.raises(ValueError, match="needs a UA2C model, got SAC"):
        callback.on_training_start({}, {})


# --------------------------------------------------------------------------- sampler


def test_convert_ua2c_params_maps_gamma_net_arch_and_policy_arguments():
    assert zoo.convert_ua2c_params({"one_minus_gamma": 0.01, "chunk_size": 5}) == {"gamma": 0.99, "chunk_size": 5}
    assert zoo.convert_ua2c_params(
        {"net_arch": "small", "critic_arch": "mlp", "q_weight": 0.5, "critic_kwargs.width": 48}
    ) == {"q_weight": 0.5, "policy_kwargs": {"net_arch": [64, 64], "critic_arch": "mlp", "critic_kwargs": {"width": 48}}}
    with pytest.raises(ValueError, match="net_arch must be one of"):
        zoo.convert_ua2c_params({"net_arch": "huge"})


def _sample(n_trials: int, seed: int = 0, space=None) -> tuple[optuna.Study, list[dict]]:
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed), direction="maximize")
    samples = []
    for _ in range(n_trials):
        trial = study.ask()
        samples.append(zoo.sample_ua2c_params(trial, n_actions=1, n_envs=1, additional_args={}, space=space))
        study.tell(trial, 0.0)
    return study, samples


def test_sampler_draws_inside_the_search_space():
    space = zoo.SEARCH_SPACE
    study, samples = _sample(30)
    policy_fields = {"net_arch", "critic_arch", "n_elite"}
    for trial, params in zip(study.trials, samples, strict=True):
        assert set(params) == set(space) - policy_fields - {"one_minus_gamma"} | {"gamma", "policy_kwargs"}
        assert 0.95 <= params["gamma"] <= 0.9999
        for name, dist in space.items():
            value = trial.params[name]
            if isinstance(dist, CategoricalDistribution):
                assert value in dist.choices, name
            else:
                assert dist.low <= value <= dist.high, name
                assert isinstance(value, int) is isinstance(dist, IntDistribution), name
        assert tuple(params["policy_kwargs"]["net_arch"]) in zoo.NET_ARCHS.values()
        assert set(params["policy_kwargs"]) == policy_fields
        # --trial-id reloads the same constructor arguments from the stored raw parameters.
        assert zoo.convert_ua2c_params(trial.params) == params
    # 30 random draws cover more than one value: the sampler really samples.
    for name in ("chunk_size", "discrete_entropy", "commit_discrete", "online_targets", "n_elite", "critic_arch"):
        assert len({t.params[name] for t in study.trials}) > 1, name


def test_sampled_hyperparameters_build_a_ua2c_model():
    from sb3_ua2c import UA2C

    env = gym.make("Pendulum-v1")
    for params in _sample(6, seed=1)[1]:
        model = UA2C("MlpPolicy", env, buffer_size=100, **params)
        assert model.chunk_size == params["chunk_size"]
        assert math.isclose(model.gamma, params["gamma"])
        assert model.policy.net_arch == params["policy_kwargs"]["net_arch"]
        assert model.policy.n_elite == params["policy_kwargs"]["n_elite"]
        assert model.replay_buffer.online_targets == params["online_targets"]
        assert model.policy.discrete_entropy is params["discrete_entropy"]
        assert model.policy.commit_discrete is params["commit_discrete"]


def test_custom_search_space_restricts_the_sampler():
    space = {"chunk_size": CategoricalDistribution([4]), "flow_steps": IntDistribution(3, 4),
             "q_weight": FloatDistribution(0.5, 0.6)}  # fmt: skip
    zoo.check_search_space(space)
    (params,) = _sample(1, space=space)[1]
    assert params["chunk_size"] == 4 and params["flow_steps"] in (3, 4) and 0.5 <= params["q_weight"] <= 0.6
    assert set(params) == {"chunk_size", "flow_steps", "q_weight"}


@pytest.mark.parametrize(
    ("space", "message"),
    [
        ({"chunk_sizes": CategoricalDistribution([3])}, "unknown UA2C hyperparameter 'chunk_sizes'"),
        ({"one_minus_gamma": FloatDistribution(0.01, 1.5)}, r"gamma must be a number in \[0, 1\], got -0.5"),
        ({"learning_rate": FloatDistribution(-1e-3, 1e-3)}, "learning_rate must be"),
        ({"n_candidates": CategoricalDistribution([0, 8])}, "n_candidates must be an integer >= 1, got 0"),
        ({"batch_size": CategoricalDistribution([64, True])}, "batch_size must be an integer >= 1, got True"),
        ({"net_arch": CategoricalDistribution(["small", "huge"])}, "net_arch must be names among"),
        ({"tau": (0.001, 0.01)}, "search space 'tau' must be an optuna distribution"),
        ({"smooth_weight": CategoricalDistribution([-1.0, 10.0])}, "smooth_weight must be a finite number >= 0, got -1.0"),
        ({"n_elite": CategoricalDistribution([1, 16]), "n_candidates": CategoricalDistribution([8, 32])},
         "n_elite=16 must not exceed n_candidates=8"),
        ({"discrete_entropy": CategoricalDistribution([True, "no"])}, "discrete_entropy must be a bool, got 'no'"),
        ({"online_targets": CategoricalDistribution(["prefix", "plan"])},
         r"online_targets must be one of \['auto', 'prefix', 'window'\], got 'plan'"),
        ({"entropy_threshold": FloatDistribution(-math.inf, 1.0)}, "entropy_threshold"),
    ],
)  # fmt: skip
def test_search_space_rejects_bad_values(space, message):
    with pytest.raises(ValueError, match=message):
        zoo.check_search_space(space)
    with pytest.raises(ValueError, match=message):
        zoo.register(search_space=space)


def test_register_installs_the_sampler_in_rl_zoo():
    import rl_zoo3.hyperparams_opt as hyperparams_opt

    zoo.register(search_space={**zoo.SEARCH_SPACE, "chunk_size": CategoricalDistribution([7])})
    trial = optuna.create_study().ask()
    assert hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"](trial, 1, 1, {})["chunk_size"] == 7
    assert hyperparams_opt.HYPERPARAMS_CONVERTER["ua2c"] is zoo.convert_ua2c_params
    zoo.register()
    assert hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"] is zoo.sample_ua2c_params
    zoo.check_search_space(zoo.SEARCH_SPACE)


def test_search_space_names_are_constructor_arguments():
    """The sampler's names are UA2C's (or, into ``policy_kwargs``, UA2CPolicy's): none is declared anew,
    and none of the flat critic settings that ``critic_kwargs`` replaces."""
    from sb3_ua2c import UA2C, UA2CPolicy
    from sb3_ua2c.config import policy_kwargs_names

    known = set(inspect.signature(UA2C.__init__).parameters) | set(policy_kwargs_names(UA2CPolicy, UA2C))
    assert set(zoo.SEARCH_SPACE) - {"one_minus_gamma"} <= known
    assert not {name for name in zoo.SEARCH_SPACE if name.startswith("critic_") and name != "critic_arch"}
