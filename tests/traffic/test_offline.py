"""Offline datasets and the Phase 1 / Phase 2 stages (the command line: ``test_cli.py``)."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from envs.collection import BehaviourConfig, collect_dataset
from sb3_ua2c import UA2C
from sb3_ua2c.chunking import discounted_chunk_return
from sb3_ua2c.offline import Episode, OfflineDatasetError, load_dataset, write_dataset

PENDULUM_OBS = gym.spaces.Box(-8.0, 8.0, (3,), np.float32)
PENDULUM_ACT = gym.spaces.Box(-2.0, 2.0, (1,), np.float32)
#: a short MixedTraffic episode (4 s = 20 steps) keeps SUMO tests fast
SHORT_ENV = {"time_limit": 4.0}


def hand_episode(t_len: int = 4, terminated: bool = True) -> Episode:
    """o_t = [t, 0, 0] (so a sample's history names its start), r_t = t + 1, a_t = 0.5 (env units)."""
    obs = np.zeros((t_len + 1, 3), dtype=np.float32)
    obs[:, 0] = np.arange(t_len + 1)
    end = np.zeros(t_len, dtype=bool)
    end[-1] = True
    return Episode(
        observations=obs,
        actions=np.full((t_len, 1), 0.5, dtype=np.float32),
        rewards=np.arange(1, t_len + 1, dtype=np.float64),
        terminations=end if terminated else np.zeros(t_len, dtype=bool),
        truncations=np.zeros(t_len, dtype=bool) if terminated else end,
    )


# ---------------------------------------------------------------------------------------------
# dataset files
# ---------------------------------------------------------------------------------------------
def test_dataset_round_trip(tmp_path: Path) -> None:
    episodes = [hand_episode(4), hand_episode(3, terminated=False)]
    path = write_dataset(episodes, tmp_path / "ds", PENDULUM_OBS, PENDULUM_ACT, metadata={"behaviour": "hand", "seed": 7})
    ds = load_dataset(path)
    assert len(ds) == 2 and ds.total_steps == 7
    assert ds.metadata == {"behaviour": "hand", "seed": 7}
    assert ds.observation_space == PENDULUM_OBS and ds.action_space == PENDULUM_ACT
    for got, want in zip(ds, episodes, strict=True):
        np.testing.assert_array_equal(got.observations, want.observations)
        np.testing.assert_array_equal(got.actions, want.actions)
        np.testing.assert_array_equal(got.rewards, want.rewards)
        np.testing.assert_array_equal(got.terminations, want.terminations)
        np.testing.assert_array_equal(got.truncations, want.truncations)
    with pytest.raises(FileExistsError, match="already exists"):
        write_dataset(episodes, path, PENDULUM_OBS, PENDULUM_ACT)


def test_relative_dataset_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    path = write_dataset([hand_episode()], Path("runs") / "ds", PENDULUM_OBS, PENDULUM_ACT)
    assert path == tmp_path / "runs" / "ds"
    assert load_dataset(Path("runs") / "ds").total_steps == 4
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["ds"]  # no temporary directory left


def test_missing_and_corrupt_datasets_raise(tmp_path: Path) -> None:
    with pytest.raises(OfflineDatasetError, match="no dataset at"):
        load_dataset(tmp_path / "nothing")
    path = write_dataset([hand_episode()], tmp_path / "ds", PENDULUM_OBS, PENDULUM_ACT)
    for f in (path / "data").iterdir():
        if f.suffix in (".hdf5", ".h5"):
            f.write_bytes(b"not an hdf5 file")
    with pytest.raises(OfflineDatasetError, match="corrupt or unreadable"):
        load_dataset(path)


def test_interrupted_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import minari

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(minari, "create_dataset_from_buffers", boom)
    with pytest.raises(KeyboardInterrupt):
        write_dataset([hand_episode()], tmp_path / "ds", PENDULUM_OBS, PENDULUM_ACT)
    assert list(tmp_path.iterdir()) == []


def test_bad_episodes_and_behaviour_raise() -> None:
    with pytest.raises(OfflineDatasetError, match="T\\+1=3"):
        Episode(np.zeros((2, 3)), np.zeros((2, 1)), np.zeros(2), np.zeros(2, bool), np.zeros(2, bool))
    with pytest.raises(OfflineDatasetError, match="NaN"):
        Episode(np.zeros((3, 3)), np.full((2, 1), np.nan), np.zeros(2), np.zeros(2, bool), np.zeros(2, bool))
    with pytest.raises(ValueError, match="perturb_prob"):
        BehaviourConfig(perturb_prob=1.5)
    with pytest.raises(ValueError, match="noise"):
        BehaviourConfig.from_dict({"noise": 1.0})


# ---------------------------------------------------------------------------------------------
# chunk transitions (Eq. 4) from a hand-made episode
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("terminated", [True, False])
def test_chunk_transitions_from_hand_made_episode(terminated: bool) -> None:
    model = UA2C("MlpPolicy", "Pendulum-v1", chunk_size=3, history_len=2, gamma=0.5, seed=0)
    assert model.add_offline_episodes([hand_episode(4, terminated)]) == 4
    batch = model.replay_buffer.sample(64)
    start = batch.observation_history[:, -1, 0].long()  # o_t = [t, 0, 0]
    expected = {  # t: (rewards r_{t:t+2} zero past L, L, bootstrap)
        0: ([1, 2, 3], 3, 1.0),
        1: ([2, 3, 4], 3, 0.0 if terminated else 1.0),
        2: ([3, 4, 0], 2, 0.0 if terminated else 1.0),
        3: ([4, 0, 0], 1, 0.0 if terminated else 1.0),
    }
    seen = set()
    for i, t in enumerate(start.tolist()):
        rewards, horizon, bootstrap = expected[t]
        assert batch.rewards[i].tolist() == rewards
        assert batch.horizons[i].item() == horizon
        assert batch.bootstrap[i].item() == bootstrap
        # history o_{t-1:t} padded with o_0 at the start; next history ends at o_{t+L}
        assert batch.observation_history[i, :, 0].tolist() == [max(t - 1, 0), t]
        assert batch.next_observation_history[i, -1, 0].item() == t + horizon
        # actions 0.5 in [-2, 2] are 0.25 normalised
        assert th.allclose(batch.chunks[i, :horizon], th.full((horizon, 1), 0.25))
        seen.add(t)
    assert seen == {0, 1, 2, 3}
    # discounted return of the first window: 1 + 0.5·2 + 0.25·3 = 2.75
    ret = discounted_chunk_return(th.tensor([[1.0, 2.0, 3.0]]), th.tensor([3.0]), 0.5)
    assert ret.item() == pytest.approx(2.75)


# ---------------------------------------------------------------------------------------------
# SUMO: collection, Phase 1, Phase 2, mismatches, command line
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def traffic_dataset(tmp_path_factory: pytest.TempPathFactory):
    path = tmp_path_factory.mktemp("data") / "ds"
    return collect_dataset(path, 3, env_kwargs=SHORT_ENV, seed=3, behaviour=BehaviourConfig(sumo_fraction=2 / 3))


def test_collected_dataset_records_the_performed_actions(traffic_dataset) -> None:
    ds = traffic_dataset
    assert len(ds) == 3 and ds.total_steps == 60  # 3 episodes x 4 s / 0.2 s
    assert ds.metadata["env_kwargs"] == SHORT_ENV and ds.metadata["seed"] == 3
    assert ds.metadata["behaviour_config"]["sumo_fraction"] == pytest.approx(2 / 3)
    for ep in ds:
        assert ep.observations.shape == (21, 20) and ep.actions.shape == (20, 2)
        assert np.all(ep.actions[:, 0] >= -4.5) and np.all(ep.actions[:, 0] <= 3.0)
        assert set(np.unique(ep.actions[:, 1])) <= {-1.0, 0.0, 1.0}
        assert ep.truncations[-1] and not ep.terminations.any()
    # same seed, same data
    again = collect_dataset(ds.path.parent / "again", 3, env_kwargs=SHORT_ENV, seed=3,
                            behaviour=BehaviourConfig(sumo_fraction=2 / 3))
    for a, b in zip(ds, again, strict=True):
        np.testing.assert_array_equal(a.observations, b.observations)
        np.testing.assert_array_equal(a.actions, b.actions)


def test_behaviour_driver_style_changes_how_sumo_drives_the_av(tmp_path: Path) -> None:
    import envs  # noqa: F401
    from envs.collection import collect_episodes, make_traffic_env

    env = make_traffic_env(env_kwargs={"time_limit": 10.0})
    try:
        accel = {}
        for style in ("conservative", "aggressive"):
            behaviour = BehaviourConfig(sumo_fraction=1.0, perturb_prob=0.0, lane_change_prob=0.0, driver_style=style)
            (ep,) = collect_episodes(env, 1, behaviour, seed=5)
            accel[style] = float(ep.actions[:, 0].max())
        # IDM never exceeds a_max: 1.0 m/s² conservative, 3.5 m/s² aggressive
        assert accel["conservative"] <= 1.0 + 1e-3 < accel["aggressive"]
        with pytest.raises(ValueError, match="style must be one of"):
            env.unwrapped.set_ego_driver_style("reckless")
    finally:
        env.close()
    with pytest.raises(ValueError, match="driver_style"):
        BehaviourConfig(driver_style="reckless")


def test_behaviour_takeover_holds_its_acceleration_for_perturb_steps() -> None:
    import envs  # noqa: F401
    from envs.collection import collect_episodes, make_traffic_env

    env = make_traffic_env(env_kwargs={"time_limit": 4.0})
    try:
        behaviour = BehaviourConfig(
            sumo_fraction=1.0, perturb_prob=1.0, perturb_steps=5, accel_noise=0.5, lane_change_prob=0.0
        )
        (ep,) = collect_episodes(env, 1, behaviour, seed=2)
        accel = ep.actions[:, 0]
        # every step starts a takeover when none is running: runs of 5 equal accelerations
        for start in range(0, 15, 5):
            np.testing.assert_array_equal(accel[start : start + 5], np.full(5, accel[start]))
            assert accel[start + 5] != accel[start]
    finally:
        env.close()
    with pytest.raises(ValueError, match="perturb_steps"):
        BehaviourConfig(perturb_steps=0)


TINY = {
    "chunk_size": 3, "history_len": 2, "n_candidates": 4, "n_target_candidates": 2, "flow_steps": 2,
    "batch_size": 16,
    "policy_kwargs": {"net_arch": [32, 32], "critic_kwargs": {"embed_dim": 16, "n_layers": 1, "n_heads": 2,
                                                                     "ff_dim": 32}},
}


def _params(model: UA2C) -> dict[str, th.Tensor]:
    return {k: v.detach().clone() for k, v in model.policy.state_dict().items()}


def test_pretrain_then_finetune_starts_from_loaded_weights(traffic_dataset, tmp_path: Path) -> None:
    from stable_baselines3.common.callbacks import BaseCallback

    from envs.collection import make_traffic_env
    from sb3_ua2c.pipeline import finetune, load_checkpoint, pretrain

    ckpt = pretrain(traffic_dataset, tmp_path / "pre", 5, seed=0, algo_kwargs=TINY)
    assert ckpt == tmp_path / "pre.zip" and ckpt.is_file()
    env = make_traffic_env(env_kwargs=SHORT_ENV)
    try:
        saved = _params(load_checkpoint(ckpt, env))
    finally:
        env.close()
    assert saved, "the checkpoint holds the policy"

    class StartsFromCheckpoint(BaseCallback):
        checked = False

        def _on_training_start(self) -> None:
            for name, value in self.model.policy.state_dict().items():
                assert th.equal(value, saved[name]), name
            StartsFromCheckpoint.checked = True

        def _on_step(self) -> bool:
            StartsFromCheckpoint.targets = self.model.replay_buffer.active_online_targets
            return True

    out = finetune(ckpt, tmp_path / "fine.zip", 30, dataset=traffic_dataset, callback=StartsFromCheckpoint())
    assert StartsFromCheckpoint.checked
    # offline-to-online: the default online_targets="auto" chose Eq. 8 (offline episodes in the buffer)
    assert StartsFromCheckpoint.targets == "prefix"
    env = make_traffic_env(env_kwargs=SHORT_ENV)
    try:
        tuned = load_checkpoint(out, env)
    finally:
        env.close()
    assert tuned.num_timesteps == 30
    assert any(not th.equal(v, saved[k]) for k, v in tuned.policy.state_dict().items()), "online updates ran"


def test_finetune_n_elite_override_reaches_rollouts_and_checkpoint(traffic_dataset, tmp_path: Path, monkeypatch) -> None:
    from sb3_ua2c.pipeline import finetune, pretrain

    ckpt = pretrain(traffic_dataset, tmp_path / "pre.zip", 2, algo_kwargs=TINY)
    stored = UA2C.load(ckpt).policy.n_elite  # the default: all 4 candidates (fewer than 8)
    seen = []
    original = UA2C.learn

    def learn(self, *args, **kwargs):  # the elite mean is set before the first rollout
        seen.append(self.policy.n_elite)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(UA2C, "learn", learn)
    out = finetune(ckpt, tmp_path / "fine.zip", 6, dataset=traffic_dataset, algo_overrides={"n_elite": 2})
    assert seen == [2]
    tuned = UA2C.load(out)
    assert tuned.policy.n_elite == 2 and tuned.policy_kwargs["n_elite"] == 2
    assert stored == 4 and UA2C.load(ckpt).policy.n_elite == stored  # the pre-trained checkpoint is untouched
    with pytest.raises(ValueError, match="n_elite=5 must not exceed n_candidates=4"):
        finetune(ckpt, tmp_path / "bad.zip", 6, dataset=traffic_dataset, algo_overrides={"n_elite": 5})
    assert not (tmp_path / "bad.zip").exists()


def test_mismatched_dataset_or_checkpoint_raises(traffic_dataset, tmp_path: Path) -> None:
    from envs.evaluation import evaluate
    from sb3_ua2c.pipeline import finetune, pretrain

    pendulum_ds = load_dataset(write_dataset([hand_episode()], tmp_path / "pend", PENDULUM_OBS, PENDULUM_ACT,
                                             metadata={"env_id": "MixedTraffic-v0", "env_kwargs": SHORT_ENV}))
    with pytest.raises(OfflineDatasetError, match="observation_space"):
        pretrain(pendulum_ds, tmp_path / "x.zip", 1, algo_kwargs=TINY)
    pendulum_model = UA2C("MlpPolicy", "Pendulum-v1", **TINY)
    pendulum_model.save(tmp_path / "pendulum.zip")
    with pytest.raises(OfflineDatasetError, match="checkpoint .* has observation_space"):
        finetune(tmp_path / "pendulum.zip", tmp_path / "y.zip", 10, dataset=traffic_dataset)
    with pytest.raises(ValueError, match=r"network shapes of a checkpoint: \['chunk_size'\]"):
        finetune(tmp_path / "pendulum.zip", tmp_path / "y.zip", 10, algo_overrides={"chunk_size": 2})
    with pytest.raises(FileNotFoundError, match="does not exist"):
        evaluate(tmp_path / "missing.zip", env_settings_={"env_kwargs": SHORT_ENV})
    (tmp_path / "junk.zip").write_bytes(b"junk")
    with pytest.raises(ValueError, match="not a loadable UA2C"):
        evaluate(tmp_path / "junk.zip", env_settings_={"env_kwargs": SHORT_ENV})
    assert not (tmp_path / "x.zip").exists() and not (tmp_path / "y.zip").exists()


def test_evaluate_reports_every_metric(traffic_dataset, tmp_path: Path) -> None:
    from envs.evaluation import evaluate, summarize
    from sb3_ua2c.pipeline import pretrain

    ckpt = pretrain(traffic_dataset, tmp_path / "pre.zip", 2, algo_kwargs={**TINY, "entropy_threshold": float("inf")})
    results = evaluate(ckpt, n_episodes=1, seeds=(0, 1), env_settings_={"env_kwargs": SHORT_ENV})
    assert [r.seed for r in results] == [0, 1000]
    for r in results:
        assert r.length == 20 and np.isfinite(r.reward) and r.cumulative_jerk >= 0
        # δ = inf executes whole chunks: L_t = k = 3 for every plan
        assert r.mean_executed_length == 3.0
    summary = summarize(results)
    assert summary["episodes"] == 2 and summary["mean_executed_length"] == 3.0
    assert summary["jerk_per_step"] == pytest.approx(np.mean([r.cumulative_jerk / 20 for r in results]))
    # the same checkpoint executed one action per plan: δ below every possible entropy
    results = evaluate(ckpt, n_episodes=1, seeds=(0,), env_settings_={"env_kwargs": SHORT_ENV}, entropy_threshold=-1e9)
    assert results[0].mean_executed_length == 1.0
    with pytest.raises(ValueError, match="entropy_threshold"):
        evaluate(ckpt, n_episodes=1, env_settings_={"env_kwargs": SHORT_ENV}, entropy_threshold=-math.inf)


def test_sampled_evaluation_is_seeded_per_episode(traffic_dataset, tmp_path: Path) -> None:
    from envs.evaluation import evaluate
    from sb3_ua2c.pipeline import pretrain

    ckpt = pretrain(traffic_dataset, tmp_path / "pre.zip", 2, algo_kwargs={**TINY, "entropy_threshold": float("inf")})
    model = UA2C.load(ckpt, device="cpu")  # loading seeds torch (SB3's _setup_model): done once, before

    def run(deterministic: bool) -> list[tuple[float, float]]:
        episodes = evaluate(model, n_episodes=2, seeds=(0,), env_settings_={"env_kwargs": SHORT_ENV},
                            deterministic=deterministic)
        return [(e.reward, e.cumulative_jerk) for e in episodes]

    th.manual_seed(123)
    before = th.random.get_rng_state()
    sampled = run(False)
    assert th.equal(th.random.get_rng_state(), before), "the caller's torch generator is left as it was"
    th.manual_seed(7)  # another global state: the episodes' noise does not depend on it
    assert run(False) == sampled
    # fresh noise per replanning is not the fixed noise of deterministic=True (2 untrained updates:
    # the chunks are nearly noise, so the two rules drive differently)
    assert run(True) != sampled


def test_finetune_writes_a_monitor_log_of_the_online_episodes(traffic_dataset, tmp_path: Path) -> None:
    from sb3_ua2c.pipeline import finetune, pretrain, read_monitor

    ckpt = pretrain(traffic_dataset, tmp_path / "pre.zip", 2, algo_kwargs={**TINY, "entropy_threshold": float("inf")})
    finetune(ckpt, tmp_path / "fine.zip", 45, dataset=traffic_dataset, monitor_file=tmp_path / "fine")
    episodes = read_monitor(tmp_path / "fine")  # ".monitor.csv" is appended, as SB3's Monitor does
    assert episodes == read_monitor(tmp_path / "fine.monitor.csv")
    # 45 steps of 20-step episodes: two finished episodes, each with its return, length and collision flag
    assert [e["l"] for e in episodes] == [20.0, 20.0]
    assert all(set(e) == {"r", "l", "t", "collision"} and e["collision"] in (0.0, 1.0) for e in episodes)


def test_read_monitor_hand_made_and_bad_files(tmp_path: Path) -> None:
    from sb3_ua2c.pipeline import read_monitor

    path = tmp_path / "x.monitor.csv"
    path.write_text('#{"t_start": 0.0, "env_id": "None"}\nr,l,t,collision\n-1.5,20,0.1,True\n3.0,7,0.2,False\n')
    assert read_monitor(path) == [
        {"r": -1.5, "l": 20.0, "t": 0.1, "collision": 1.0},
        {"r": 3.0, "l": 7.0, "t": 0.2, "collision": 0.0},
    ]
    (tmp_path / "bad.monitor.csv").write_text("r,l,t\n1,2,3\n")
    with pytest.raises(ValueError, match="not a Monitor log"):
        read_monitor(tmp_path / "bad.monitor.csv")


def test_format_table_is_95_characters_wide_with_three_decimals() -> None:
    from envs.evaluation import format_table

    row = {"reward": 34.567, "cumulative_jerk": 722.837, "collision": 0.7, "merge_success": 0.3,
           "mean_speed": 25.037, "mean_executed_length": 3.359}
    lines = format_table({"pretrained": row, "dataset": {**row, "collision": math.nan}}).splitlines()
    assert lines[0] == ("     method |      reward |   cum. jerk |   collision |       merge |       speed |"
                        "    mean L_t")
    assert lines[2] == (" pretrained |      34.567 |     722.837 |       0.700 |       0.300 |      25.037 |"
                        "       3.359")
    assert lines[3].split(" | ")[3].strip() == "nan"
    assert {len(line) for line in lines} == {95}


def test_episode_intervals_hand_computed() -> None:
    from envs.evaluation import EpisodeMetrics, episode_intervals, format_table, summarize

    episodes = [EpisodeMetrics(seed=i, reward=float(i + 1), length=200, cumulative_jerk=10.0, collision=i == 0,
                               merge_success=True, mean_speed=20.0, mean_executed_length=2.0) for i in range(4)]
    ci = episode_intervals(episodes)
    # rewards 1..4: mean 2.5, SE 1.29099 / 2 = 0.645497, t(0.975, 3) = 3.182446: 2.5 ± 2.054260
    assert ci["reward"] == pytest.approx((0.445740, 4.554260), abs=1e-5)
    # 1 collision in 4, Wilson: centre 0.730182 / 1.960365 = 0.372473, half-width 0.326886
    assert ci["collision"] == pytest.approx((0.045587, 0.699359), abs=1e-5)
    # 4 merges in 4: Wilson's upper end is 1, its lower end n / (n + z^2) = 4 / 7.841459 = 0.510109
    assert ci["merge_success"] == pytest.approx((0.510109, 1.0), abs=1e-5)
    assert ci["cumulative_jerk"] == (10.0, 10.0)  # no spread: the mean itself
    lines = format_table({"finetuned": summarize(episodes)}, {"finetuned": ci}).splitlines()
    assert lines[3] == ("    95 % CI |  0.45..4.55 |  10.0..10.0 |  0.05..0.70 |  0.51..1.00 |  20.0..20.0 |"
                        "  2.00..2.00")
    assert {len(line) for line in lines} == {95}


def test_generic_stages_refuse_what_they_cannot_build(tmp_path: Path) -> None:
    """The algorithm's own make_env builds any registered env; a dataset that records a setting of
    an application package (the style classifier of ``envs``) needs that package's maker."""
    from sb3_ua2c.offline import make_env as generic_make_env
    from sb3_ua2c.pipeline import env_settings, finetune, pretrain

    env = generic_make_env("Pendulum-v1", None, style_classifier=None)
    assert env.observation_space.shape == (3,)
    env.close()
    with pytest.raises(ValueError, match=r"records the setting\(s\) \['style_classifier'\].*envs.make_traffic_env"):
        generic_make_env("MixedTraffic-v0", None, style_classifier="default")
    styled = load_dataset(write_dataset([hand_episode()], tmp_path / "styled", PENDULUM_OBS, PENDULUM_ACT,
                                        metadata={"env_id": "Pendulum-v1", "style_classifier": "default"}))
    with pytest.raises(ValueError, match="generic make_env cannot apply"):
        pretrain(styled, tmp_path / "x.zip", 1, algo_kwargs=TINY)
    anonymous = load_dataset(write_dataset([hand_episode()], tmp_path / "anon", PENDULUM_OBS, PENDULUM_ACT))
    with pytest.raises(OfflineDatasetError, match="records no env_id"):
        env_settings(anonymous)
    with pytest.raises(ValueError, match="needs a dataset or env_settings_"):
        finetune(tmp_path / "missing.zip", tmp_path / "y.zip", 10)
    assert not (tmp_path / "x.zip").exists()


def test_finetune_takes_a_float_or_auto_entropy_threshold(tmp_path: Path) -> None:
    from sb3_ua2c.pipeline import finetune, pretrain

    env = gym.make("Pendulum-v1")
    ds = load_dataset(write_dataset([hand_episode(8)], tmp_path / "data", env.observation_space, env.action_space,
                                    metadata={"env_id": "Pendulum-v1"}))
    pre = pretrain(ds, tmp_path / "pre.zip", 1, algo_kwargs=TINY)
    for delta in ("auto", 0.5, None):
        fine = finetune(pre, tmp_path / "fine.zip", 4, dataset=ds, entropy_threshold=delta)
        assert UA2C.load(fine, device="cpu").execution.entropy_threshold == (0.0 if delta is None else delta)


def test_the_behaviour_policy_is_evaluated_on_the_scenarios_it_collects():
    # evaluate_behaviour's episode 0 of seed 2 is scenario 2000 with the behaviour's generator seeded 2000:
    # the episode collect_episodes makes with seed 2000, step for step
    from envs.collection import BehaviourConfig, collect_episodes, make_traffic_env
    from envs.evaluation import evaluate_behaviour

    settings = {"env_id": "MixedTraffic-v0", "env_kwargs": {"time_limit": 10.0}}
    behaviour = BehaviourConfig(perturb_prob=0.2, perturb_steps=3)
    (metrics,) = evaluate_behaviour(behaviour, n_episodes=1, seeds=(2,), env_settings_=settings)
    env = make_traffic_env(**settings)
    try:
        (episode,) = collect_episodes(env, 1, behaviour, seed=2000)
    finally:
        env.close()
    assert metrics.seed == 2000 and metrics.length == len(episode) == 50
    assert metrics.reward == pytest.approx(float(episode.rewards.sum()), abs=1e-9)
    assert metrics.plan_lengths == (1,) * 50 and metrics.mean_executed_length == 1.0
    other = evaluate_behaviour(BehaviourConfig(sumo_fraction=0.0), n_episodes=1, seeds=(2,), env_settings_=settings)
    assert other[0].reward != metrics.reward  # the config is used: a random driver scores otherwise
