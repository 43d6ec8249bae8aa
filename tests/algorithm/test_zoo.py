"""rl-zoo integration (issue 6): YAML configs, the launcher, continuing from checkpoints, the sampler."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import optuna
import pytest
import torch
import yaml
from stable_baselines3 import SAC
from torch import nn

from sb3_ua2c import zoo

REPO = Path(__file__).resolve().parents[2]
CONFIGS = REPO / "zoo_configs"


# --------------------------------------------------------------------------- YAML keys


def _algo_class(name: str) -> type:
    zoo.register()
    from rl_zoo3 import ALGOS

    return ALGOS[name]


def _constructor_arguments(cls: type) -> set[str]:
    return set(inspect.signature(cls.__init__).parameters) - {"self", "args", "kwargs"}


def unknown_keys(algo_cls: type, entry: dict) -> list[str]:
    """Keys of one rl-zoo entry that are neither constructor arguments nor rl-zoo keys (incl. policy_kwargs)."""
    unknown = sorted(set(entry) - _constructor_arguments(algo_cls) - zoo.ZOO_KEYS)
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


@pytest.mark.parametrize("config", sorted(CONFIGS.glob("*.yml")), ids=lambda p: p.name)
def test_yaml_keys_are_constructor_arguments_or_zoo_keys(config):
    entries = yaml.safe_load(config.read_text())
    assert {"Pendulum-v1", "MixedTraffic-v0"} <= set(entries)
    algo_cls = _algo_class(config.stem.removesuffix("_paper"))  # ua2c_paper.yml: UA2C's paper preset
    for env_id, entry in entries.items():
        assert unknown_keys(algo_cls, entry) == [], f"{config.name}:{env_id}"


def test_baselines_share_env_ids_and_budgets_with_ua2c():
    configs = {p.stem: yaml.safe_load(p.read_text()) for p in CONFIGS.glob("*.yml")}
    assert set(configs) == {"ua2c", "ua2c_paper", "sac", "tqc", "crossq"}
    assert set(configs["sac"]) == set(configs["tqc"]) == set(configs["crossq"]) == set(configs["ua2c"])
    assert set(configs["ua2c_paper"]) == set(configs["ua2c"])
    # Same training budget and discount on each env id: the comparisons are like for like.
    for env_id in configs["ua2c"]:
        for key in ("n_timesteps", "gamma"):
            values = {algo: float(entries[env_id].get(key, 0.99)) for algo, entries in configs.items()}
            assert len(set(values.values())) == 1, (env_id, key, values)


# --------------------------------------------------------------------------- launcher arguments


def test_build_zoo_argv_defaults_algo_and_adds_optimize_flag():
    assert zoo.build_zoo_argv("train", ["--env", "Pendulum-v1", "--conf-file", "c.yml"]) == [
        "--algo", "ua2c", "--env", "Pendulum-v1", "--conf-file", "c.yml",
    ]  # fmt: skip
    assert zoo.build_zoo_argv("optimize", ["--algo", "sac", "--n-trials", "2"]) == [
        "--algo", "sac", "--n-trials", "2", "--optimize-hyperparameters",
    ]  # fmt: skip
    assert zoo.build_zoo_argv("enjoy", ["--algo=sac", "-f", "logs"]) == ["--algo=sac", "-f", "logs"]
    # -optimize already given: not added twice; -conf short form accepted.
    assert zoo.build_zoo_argv("optimize", ["-conf", "u.yml", "-optimize"]) == [
        "--algo", "ua2c", "-conf", "u.yml", "-optimize",
    ]  # fmt: skip


def test_build_zoo_argv_rejects_bad_input():
    with pytest.raises(ValueError, match="Unknown command 'fit'"):
        zoo.build_zoo_argv("fit", [])
    with pytest.raises(ValueError, match="--conf-file"):
        zoo.build_zoo_argv("train", ["--env", "Pendulum-v1"])


def test_main_without_arguments_prints_usage_and_exits(capsys):
    with pytest.raises(SystemExit) as excinfo:
        zoo.main([])
    assert excinfo.value.code == 2
    assert "train" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="Unknown command 'fit'"):
        zoo.main(["fit"])


def test_optimize_flag_prefix_is_recognised():
    # argparse accepts --optimize for --optimize-hyperparameters: not appended a second time.
    assert zoo.build_zoo_argv("optimize", ["--algo", "sac", "--optimize"]) == ["--algo", "sac", "--optimize"]


def test_prepare_storage_creates_the_optuna_schema_once(tmp_path):
    import sqlalchemy

    zoo.prepare_storage(None)  # in-memory study: nothing to do
    zoo.prepare_storage(str(tmp_path / "journal.log"))  # journal file: nothing to do
    assert not (tmp_path / "journal.log").exists()
    url = f"sqlite:///{tmp_path / 'sweep.db'}"
    zoo.prepare_storage(url)
    zoo.prepare_storage(url)  # idempotent
    engine = sqlalchemy.create_engine(url)
    tables = set(sqlalchemy.inspect(engine).get_table_names())
    engine.dispose()
    assert {"studies", "trials", "trial_params", "alembic_version"} <= tables


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
    "policy_kwargs": {"net_arch": [16], "critic_kwargs": {"embed_dim": 16, "ff_dim": 16, "n_heads": 2}},
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
    entry = yaml.safe_load((CONFIGS / "ua2c.yml").read_text())["MixedTraffic-v0"]
    assert data["num_timesteps"] == 120
    assert data["chunk_size"] == entry["chunk_size"]
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

    assert zoo.needs_own_process("MixedTraffic-v0") is True
    assert zoo.needs_own_process("Pendulum-v1") is False
    # training + evaluation envs, times parallel trials
    assert zoo.envs_in_one_process(n_envs=1, n_eval_envs=1, evaluates=False) == 1
    assert zoo.envs_in_one_process(n_envs=1, n_eval_envs=1, evaluates=True) == 2
    assert zoo.envs_in_one_process(n_envs=4, n_eval_envs=2, evaluates=True, n_jobs=3) == 18


def test_train_on_mixed_traffic_with_evaluation(tmp_path):
    """rl-zoo3 evaluates in the training process's lifetime: both envs run in their own processes."""
    tiny = {k: v for k, v in TINY_UA2C.items() if k not in ("chunk_size", "learning_starts")}
    zoo.main(["train", *_mixed_traffic_args(tmp_path, "-n", "80", "--eval-freq", "40", "--eval-episodes", "2",
                                            *SHORT_EPISODES, *_params(tiny, learning_starts=30))])  # fmt: skip
    run = tmp_path / "ua2c" / "MixedTraffic-v0_1"
    evaluations = np.load(run / "evaluations.npz")
    np.testing.assert_array_equal(evaluations["timesteps"], [40, 80])
    np.testing.assert_array_equal(evaluations["ep_lengths"], [[10, 10], [10, 10]])
    assert (run / "best_model.zip").is_file() and (run / "MixedTraffic-v0.zip").is_file()
    monitor = (run / "0.monitor.csv").read_text().splitlines()[2:]  # after the JSON and the header line
    assert [line.split(",")[1] for line in monitor] == ["20"] * 4  # 80 steps = 4 training episodes


@pytest.mark.slow
def test_optimize_on_mixed_traffic(tmp_path):
    storage = f"sqlite:///{tmp_path / 'sweep.db'}"
    zoo.main(["optimize", *_mixed_traffic_args(tmp_path, "-n", "40", "--n-trials", "1", "--n-evaluations", "2",
                                               "--eval-episodes", "1", "--sampler", "random", "--pruner", "none",
                                               "--no-optim-plots", "--storage", storage, "--study-name", "mt",
                                               *SHORT_EPISODES, "-params", "learning_starts:1000000",
                                               "buffer_size:1000")])  # fmt: skip
    (trial,) = optuna.load_study(study_name="mt", storage=storage).trials
    assert trial.state == optuna.trial.TrialState.COMPLETE
    assert math.isfinite(trial.value)


def test_explicit_dummy_vec_env_with_several_sumo_envs_stops_before_training(tmp_path, capsys):
    for extra in (["--eval-freq", "40"], ["--eval-freq", "-1", "-params", "n_envs:2"]):
        with pytest.raises(SystemExit, match="--vec-env dummy would keep 2 of them open") as excinfo:
            zoo.main(["train", *_mixed_traffic_args(tmp_path, "-n", "40", "--vec-env", "dummy", *extra)])
        assert "SubprocVecEnv" not in str(excinfo.value) and "libsumo" in str(excinfo.value)
    with pytest.raises(SystemExit, match="would keep 6 of them open"):
        zoo.main(["optimize", *_mixed_traffic_args(tmp_path, "-n", "40", "--vec-e=dummy", "--n-jobs", "3")])
    assert not (tmp_path / "ua2c" / "MixedTraffic-v0_1" / "0.monitor.csv").exists()  # no env was built


def test_explicit_dummy_vec_env_with_one_sumo_env_runs_in_process(tmp_path):
    from envs.sumo import process_owner

    zoo.main(["train", *_mixed_traffic_args(tmp_path, "-n", "40", "--vec-env", "dummy", "--eval-freq", "-1",
                                            *SHORT_EPISODES, *_params(learning_starts=10**6))])  # fmt: skip
    monitor = (tmp_path / "ua2c" / "MixedTraffic-v0_1" / "0.monitor.csv").read_text().splitlines()[2:]
    assert [line.split(",")[1] for line in monitor] == ["20", "20"]
    assert process_owner() is None  # rl-zoo3 closed the in-process env


def test_continue_rejects_a_chunk_size_that_differs_from_the_checkpoint(tmp_path):
    _train(tmp_path, "ua2c", "-n", "150", "--seed", "1", *_params())
    first = tmp_path / "ua2c" / "Pendulum-v1_1" / "Pendulum-v1.zip"
    with pytest.raises(ValueError, match="chunk_size=4 .* checkpoint .* chunk_size=3"):
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


def test_convert_ua2c_params_maps_one_minus_gamma():
    assert zoo.convert_ua2c_params({"one_minus_gamma": 0.01, "chunk_size": 5}) == {
        "gamma": 0.99,
        "chunk_size": 5,
    }


def test_convert_ua2c_params_moves_policy_arguments_into_policy_kwargs():
    assert zoo.convert_ua2c_params({"net_arch": "small", "critic_embed_dim": 32, "q_weight": 0.5}) == {
        "q_weight": 0.5,
        "policy_kwargs": {"net_arch": [64, 64], "critic_kwargs": {"embed_dim": 32}},
    }
    # the MLP critic has no embed_dim: the sampled value does not reach it
    assert zoo.convert_ua2c_params({"critic_arch": "mlp", "critic_embed_dim": 32}) == {
        "policy_kwargs": {"critic_arch": "mlp"}}
    with pytest.raises(ValueError, match="net_arch must be one of"):
        zoo.convert_ua2c_params({"net_arch": "huge"})


def _sample(n_trials: int, seed: int = 0) -> tuple[optuna.Study, list[dict]]:
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed), direction="maximize")
    samples = []
    for _ in range(n_trials):
        trial = study.ask()
        samples.append(zoo.sample_ua2c_params(trial, n_actions=1, n_envs=1, additional_args={}))
        study.tell(trial, 0.0)
    return study, samples


def test_sampler_draws_inside_the_search_space():
    space = zoo.UA2CSearchSpace()
    study, samples = _sample(30)
    policy_fields = {"net_arch", "critic_arch", "critic_embed_dim", "n_elite"}
    for trial, params in zip(study.trials, samples, strict=True):
        assert set(params) == {f.name for f in dataclasses.fields(zoo.UA2CSearchSpace)} - policy_fields | {
            "policy_kwargs"
        }
        assert space.gamma[0] <= params["gamma"] <= space.gamma[1]
        assert math.isclose(params["gamma"], trial.user_attrs["gamma"])
        for name in (
            "learning_rate",
            "tau",
            "entropy_threshold",
            "q_weight",
            "flow_steps",
            "target_flow_steps",
        ):
            low, high = getattr(space, name)
            assert low <= params[name] <= high, name
        for name in (
            "batch_size", "chunk_size", "history_len", "n_candidates", "n_target_candidates", "smooth_weight",
            "discrete_entropy", "commit_discrete", "online_targets",
        ):
            assert params[name] in getattr(space, name), name
        assert tuple(params["policy_kwargs"]["net_arch"]) in zoo.NET_ARCHS.values()
        if params["policy_kwargs"]["critic_arch"] == "transformer":
            assert params["policy_kwargs"]["critic_kwargs"]["embed_dim"] in space.critic_embed_dim
        assert params["policy_kwargs"]["critic_arch"] in space.critic_arch
        assert params["policy_kwargs"]["n_elite"] in space.n_elite
        # --trial-id reloads the same constructor arguments from the stored raw parameters.
        assert zoo.convert_ua2c_params(trial.params) == params
    # 30 random draws cover more than one chunk size: the sampler really samples.
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
    space = zoo.UA2CSearchSpace.from_dict({"chunk_size": [4], "flow_steps": [3, 4], "q_weight": [0.5, 0.6]})
    trial = optuna.create_study().ask()
    params = zoo.sample_ua2c_params(trial, 1, 1, {}, space=space)
    assert params["chunk_size"] == 4
    assert params["flow_steps"] in (3, 4)
    assert 0.5 <= params["q_weight"] <= 0.6


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"chunk_sizes": (3,)}, "Unknown UA2C search-space key.*chunk_sizes"),
        ({"gamma": (0.9, 1.0)}, "gamma must satisfy"),
        ({"learning_rate": (1e-3, 1e-4)}, "learning_rate must satisfy"),
        ({"q_weight": (0.0, 1.0)}, "q_weight must satisfy"),
        ({"chunk_size": ()}, "chunk_size must be a non-empty tuple"),
        ({"n_candidates": (0, 8)}, "n_candidates must be an integer >= 1, got 0"),
        ({"flow_steps": (2.0, 5.0)}, "flow_steps must hold integers"),
        ({"batch_size": (64, True)}, "batch_size must be an integer >= 1, got True"),
        ({"net_arch": ("small", "huge")}, "net_arch must be names among"),
        ({"tau": (0.01,)}, r"tau must be a \(low, high\) tuple"),
        ({"smooth_weight": (-1.0, 10.0)}, "smooth_weight must be a finite number >= 0, got -1.0"),
        ({"smooth_weight": ()}, "smooth_weight must be a non-empty tuple"),
        ({"n_elite": (1, 16), "n_candidates": (8, 32)}, "n_elite=16 must not exceed n_candidates=8"),
        ({"n_elite": (0,)}, "n_elite must be an integer >= 1, got 0"),
        ({"discrete_entropy": (True, "no")}, "discrete_entropy must be a bool, got 'no'"),
        ({"commit_discrete": ()}, "commit_discrete must be a non-empty tuple"),
        ({"online_targets": ("prefix", "plan")}, r"online_targets must be one of \['auto', 'prefix', 'window'\], got 'plan'"),
    ],
)
def test_search_space_rejects_bad_values(config, message):
    with pytest.raises(ValueError, match=message):
        zoo.UA2CSearchSpace.from_dict(config)


def test_register_installs_the_sampler_in_rl_zoo():
    import rl_zoo3.hyperparams_opt as hyperparams_opt

    zoo.register(search_space=zoo.UA2CSearchSpace(chunk_size=(7,)))
    trial = optuna.create_study().ask()
    assert hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"](trial, 1, 1, {})["chunk_size"] == 7
    assert hyperparams_opt.HYPERPARAMS_CONVERTER["ua2c"] is zoo.convert_ua2c_params
    zoo.register()
    assert hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"] is zoo.sample_ua2c_params
    assert np.isfinite(
        hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"](optuna.create_study().ask(), 1, 1, {})["gamma"]
    )


def test_search_space_fields_are_constructor_arguments():
    """The sampler's names are UA2C's (or, into ``policy_kwargs``, UA2CPolicy's): none is declared anew."""
    from sb3_ua2c import UA2C, UA2CPolicy
    from sb3_ua2c.config import policy_kwargs_names
    from sb3_ua2c.critics import critic_defaults

    known = set(inspect.signature(UA2C.__init__).parameters) | set(policy_kwargs_names(UA2CPolicy, UA2C))
    known |= {f"critic_{name}" for name in critic_defaults("transformer")}  # into critic_kwargs
    assert {f.name for f in dataclasses.fields(zoo.UA2CSearchSpace)} <= known
