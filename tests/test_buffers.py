"""Chunk replay buffer: online plans (Eq. 8) and offline windows (Eq. 4) through one sampling path."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_ua2c.buffers import ChunkReplayBuffer, OfflineEpisode

OBS = spaces.Box(-np.inf, np.inf, (1,), np.float32)
ACT = spaces.Box(-1.0, 1.0, (1,), np.float32)


@pytest.fixture(autouse=True)
def _seed_numpy():
    np.random.seed(0)  # noqa: NPY002 - the buffer samples with NumPy's global RNG (seeded by SB3)


def make_buffer(size=32, n_envs=1, k=3, ell=2, ratio=0.5, targets="prefix"):
    return ChunkReplayBuffer(
        size, OBS, ACT, "cpu", n_envs=n_envs, chunk_size=k, history_len=ell, offline_ratio=ratio,
        online_targets=targets,
    )


def add_step(buf, t, plan=None, length=0, terminated=False, truncated=False, start=False, next_obs=None):
    """Step t of an episode: o_t = t, a_t = 0.1 (t + 1), r_t = t + 1."""
    new_plan = plan is not None
    plans = (
        np.zeros((1, buf.chunk_size, 1), np.float32)
        if plan is None
        else np.array(plan, np.float32).reshape(1, -1, 1)
    )
    buf.add(
        np.array([[t]], np.float32),
        np.array([[t + 1 if next_obs is None else next_obs]], np.float32),
        np.array([[0.1 * (t + 1)]], np.float32),
        np.array([t + 1.0]),
        np.array([terminated]),
        np.array([truncated]),
        np.array([start]),
        np.array([new_plan]),
        plans,
        np.array([length]),
    )


def add_two_envs(buf, t, terminated, start, length=3):
    """Step t of two envs: o = t and 10 + t, a = 0.1 and -0.1, r = 1 and 2; a plan starts with each episode."""
    buf.add(
        np.array([[t], [10 + t]], np.float32),
        np.array([[t + 1], [11 + t]], np.float32),
        np.array([[0.1], [-0.1]], np.float32),
        np.array([1.0, 2.0]),
        np.array(terminated),
        np.array([False, False]),
        np.array(start),
        np.array(start),
        np.zeros((2, buf.chunk_size, 1), np.float32),
        np.array([length, length]),
    )


def rows(samples):
    """Unique samples keyed by the last chunk entry, as plain lists."""
    out = {}
    for i in range(samples.chunks.shape[0]):
        key = round(samples.chunks[i, -1, 0].item(), 4)
        out[key] = {name: getattr(samples, name)[i].flatten().tolist() for name in samples._fields}
    return out


def test_online_plans_with_prefix_and_terminal_inside():
    buf = make_buffer()
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=2, start=True)
    add_step(buf, 1)
    add_step(buf, 2, plan=[0.8, 0.9, 1.0], length=3)
    add_step(buf, 3, terminated=True)  # the episode ends after 2 of the 3 planned steps
    add_step(buf, 0, plan=[-0.5, -0.5, -0.5], length=3, start=True)  # open plan: not a sample yet
    assert buf.n_samples() == (2, 0)
    got = rows(buf.sample(64))
    assert set(got) == {0.7, 1.0}
    a = got[0.7]  # plan at t=0, L_t = 2: executed actions, then the plan's tail
    assert a["chunks"] == pytest.approx([0.1, 0.2, 0.7])
    assert a["rewards"] == pytest.approx([1.0, 2.0, 0.0])
    assert a["horizons"] == [2.0] and a["bootstrap"] == [1.0]
    assert a["observation_history"] == [0.0, 0.0] and a["action_history"] == [0.0, 0.0]
    assert a["next_observation_history"] == [1.0, 2.0]
    assert a["next_action_history"] == pytest.approx([0.1, 0.2])
    b = got[1.0]  # plan at t=2 cut by the terminal step: L = 2, no bootstrap
    assert b["chunks"] == pytest.approx([0.3, 0.4, 1.0])
    assert b["rewards"] == pytest.approx([3.0, 4.0, 0.0])
    assert b["horizons"] == [2.0] and b["bootstrap"] == [0.0]
    assert b["observation_history"] == [1.0, 2.0]
    assert b["action_history"] == pytest.approx([0.1, 0.2])
    assert b["next_observation_history"] == [3.0, 4.0]
    assert b["next_action_history"] == pytest.approx([0.3, 0.4])


def test_online_truncation_bootstraps_from_terminal_observation():
    buf = make_buffer()
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=3, start=True)
    add_step(buf, 1, truncated=True, next_obs=99.0)
    s = rows(buf.sample(4))[0.7]
    assert s["horizons"] == [2.0] and s["bootstrap"] == [1.0]
    assert s["next_observation_history"] == [1.0, 99.0]


def test_restarted_episode_closes_open_plan_with_bootstrap():
    buf = make_buffer()
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=3, start=True)
    add_step(buf, 0, plan=[0.1, 0.1, 0.1], length=1, start=True)  # e.g. learn() reset the env
    s = rows(buf.sample(16))
    assert s[0.7]["horizons"] == [1.0] and s[0.7]["bootstrap"] == [1.0]
    assert s[0.1]["observation_history"] == [0.0, 0.0]  # the history restarted


def test_ring_overwrite_invalidates_old_plans():
    buf = make_buffer(size=5)
    for t in range(7):
        add_step(buf, t, plan=[t / 10, t / 10, t / 10], length=1, start=(t == 0))
    # 5 slots, the 2 oldest plans overwritten; the oldest surviving start (t=2) lost o_1 to overwriting
    starts = buf._online_starts()
    assert sorted(buf.online.obs[starts, 0, 0].tolist()) == [3.0, 4.0, 5.0, 6.0]
    s = rows(buf.sample(64))
    assert s[0.3]["observation_history"] == [2.0, 3.0]


def by_start(samples):
    """Unique samples keyed by their start observation o_t, as plain lists."""
    return {
        samples.observation_history[i, -1, 0].item(): {
            name: getattr(samples, name)[i].flatten().tolist() for name in samples._fields
        }
        for i in range(samples.chunks.shape[0])
    }


@pytest.mark.parametrize("terminated", [True, False])
def test_online_windows_cross_plan_boundaries(terminated):
    """online_targets="window": every step starts a window of the next k executed actions (Eq. 4)."""
    buf = make_buffer(targets="window")
    assert buf.online.plans is None
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=1, start=True)  # the plans and L_t play no part
    add_step(buf, 1, plan=[0.8, 0.9, 1.0], length=2)
    add_step(buf, 2)
    add_step(buf, 3, plan=[-0.5, -0.5, -0.5], length=3)
    assert buf.n_samples() == (2, 0)  # the windows at t = 0, 1 are complete; t = 2, 3 are open
    add_step(buf, 4, terminated=terminated, truncated=not terminated)
    assert buf.n_samples() == (5, 0)  # the episode end closes the windows at t = 2, 3, 4
    got = by_start(buf.sample(256))
    assert set(got) == {0.0, 1.0, 2.0, 3.0, 4.0}
    a = got[1.0]  # a_1 of the first plan, a_2 a_3 of the second: r = 2, 3, 4, bootstrap from h_4
    assert a["chunks"] == pytest.approx([0.2, 0.3, 0.4])
    assert a["rewards"] == pytest.approx([2.0, 3.0, 4.0])
    assert a["horizons"] == [3.0] and a["bootstrap"] == [1.0]
    assert a["observation_history"] == [0.0, 1.0] and a["action_history"] == pytest.approx([0.0, 0.1])
    assert a["next_observation_history"] == [3.0, 4.0]
    assert a["next_action_history"] == pytest.approx([0.3, 0.4])
    end = 0.0 if terminated else 1.0  # a time limit bootstraps from the last observation
    assert got[2.0]["horizons"] == [3.0] and got[2.0]["bootstrap"] == [end]
    b = got[3.0]  # two steps to the episode end: the tail is zeros, as offline
    assert b["chunks"] == pytest.approx([0.4, 0.5, 0.0])
    assert b["rewards"] == pytest.approx([4.0, 5.0, 0.0])
    assert b["horizons"] == [2.0] and b["bootstrap"] == [end]
    assert b["next_observation_history"] == [4.0, 5.0]
    assert got[4.0]["horizons"] == [1.0] and got[4.0]["chunks"] == pytest.approx([0.5, 0.0, 0.0])
    # the next episode's windows do not reach back into this one
    add_step(buf, 10, start=True)
    add_step(buf, 11)
    assert buf.n_samples() == (5, 0)


def test_online_windows_in_the_ring_and_several_envs():
    buf = make_buffer(size=5, targets="window")
    for t in range(7):
        add_step(buf, t, plan=[0.0, 0.0, 0.0], length=1, start=(t == 0))
    # slots hold t = 2..6; windows complete for t <= 4; t = 2 lost o_1 to overwriting
    assert sorted(buf.online.obs[buf._online_starts(), 0, 0].tolist()) == [3.0, 4.0]
    two = make_buffer(n_envs=2, targets="window")
    for t in range(3):  # env 1 terminates after its second step and starts again
        add_two_envs(two, t, terminated=[False, t == 1], start=[t == 0, t in (0, 2)])
    got = by_start(two.sample(256))
    assert set(got) == {0.0, 10.0, 11.0}  # env 0: t = 0 complete; env 1: both starts of its episode
    assert got[10.0]["horizons"] == [2.0] and got[10.0]["bootstrap"] == [0.0]
    assert got[10.0]["rewards"] == [2.0, 2.0, 0.0]


def test_online_targets_is_validated():
    for bad in ("plan", "", None, 1):
        with pytest.raises(ValueError, match="online_targets"):
            make_buffer(targets=bad)


def offline_episode(offset=0.0, terminated=True):
    return OfflineEpisode(
        observations=np.arange(5, dtype=np.float32).reshape(5, 1) + offset,
        actions=np.array([[0.1], [0.2], [0.3], [0.4]], np.float32),
        rewards=np.array([1.0, 2.0, 3.0, 4.0]),
        terminations=np.array([False, False, False, terminated]),
        truncations=np.array([False, False, False, not terminated]),
    )


def test_offline_windows_from_any_start():
    buf = make_buffer()
    assert buf.add_offline_episodes([offline_episode()]) == 4
    assert buf.n_samples() == (0, 4)
    s = buf.sample(200)
    by_start = {}
    for i in range(200):
        by_start[s.observation_history[i, -1, 0].item()] = i
    assert sorted(by_start) == [0.0, 1.0, 2.0, 3.0]
    i0, i1, i2, i3 = (by_start[float(t)] for t in range(4))
    # t=0: full window, bootstraps from h_3
    assert s.chunks[i0].flatten().tolist() == pytest.approx([0.1, 0.2, 0.3])
    assert s.horizons[i0].item() == 3 and s.bootstrap[i0].item() == 1
    assert s.next_observation_history[i0].flatten().tolist() == [2.0, 3.0]
    assert s.next_action_history[i0].flatten().tolist() == pytest.approx([0.2, 0.3])
    assert s.observation_history[i0].flatten().tolist() == [0.0, 0.0]
    # t=1: the window reaches the terminal step -> no bootstrap
    assert s.horizons[i1].item() == 3 and s.bootstrap[i1].item() == 0
    # t=2: truncated at the episode end, padded with zero actions
    assert s.chunks[i2].flatten().tolist() == pytest.approx([0.3, 0.4, 0.0])
    assert s.rewards[i2].tolist() == pytest.approx([3.0, 4.0, 0.0])
    assert s.horizons[i2].item() == 2 and s.bootstrap[i2].item() == 0
    assert s.action_history[i2].flatten().tolist() == pytest.approx([0.1, 0.2])
    assert s.next_observation_history[i2].flatten().tolist() == [3.0, 4.0]
    assert s.horizons[i3].item() == 1


def test_offline_time_limit_bootstraps():
    buf = make_buffer()
    buf.add_offline_episodes([offline_episode(terminated=False)])
    s = buf.sample(100)
    assert th.all(s.bootstrap == 1)


def test_offline_ratio_mixes_batches():
    buf = make_buffer(ratio=0.25)
    buf.add_offline_episodes([offline_episode(offset=100.0)])
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=1, start=True)
    s = buf.sample(8)
    offline_rows = (s.observation_history[:, -1, 0] >= 100).sum().item()
    assert offline_rows == 2


def test_offline_episode_validation():
    buf = make_buffer()
    bad = offline_episode()
    with pytest.raises(ValueError, match="rewards has shape"):
        buf.add_offline_episodes([{**bad.__dict__, "rewards": np.zeros(3)}])
    with pytest.raises(ValueError, match="normalised"):
        buf.add_offline_episodes([{**bad.__dict__, "actions": np.full((4, 1), 2.0)}])
    with pytest.raises(ValueError, match="only the last step"):
        buf.add_offline_episodes([{**bad.__dict__, "terminations": np.array([True, False, False, True])}])
    with pytest.raises(ValueError, match="unknown offline episode key"):
        buf.add_offline_episodes([{**bad.__dict__, "reward": np.zeros(4)}])
    with pytest.raises(ValueError, match="T\\+1"):
        buf.add_offline_episodes([{**bad.__dict__, "observations": np.zeros((4, 1))}])


def test_several_envs_keep_their_own_episodes():
    buf = make_buffer(n_envs=2)
    for t in range(2):
        add_two_envs(buf, t, terminated=[False, False], start=[t == 0, t == 0], length=2)
    s = buf.sample(32)
    for i in range(32):
        first = s.observation_history[i, -1, 0].item()
        assert s.next_observation_history[i].flatten().tolist() == [first + 1, first + 2]
        assert s.rewards[i].tolist() == ([1.0, 1.0, 0.0] if first == 0 else [2.0, 2.0, 0.0])


def test_empty_buffer_and_bad_arguments():
    with pytest.raises(ValueError, match="no complete chunk"):
        make_buffer().sample(4)
    with pytest.raises(ValueError, match="offline_ratio"):
        make_buffer(ratio=1.5)
    with pytest.raises(ValueError, match="buffer_size"):
        make_buffer(size=3)
