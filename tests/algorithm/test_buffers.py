"""Chunk replay buffer: online plans (Eq. 8) and offline windows (Eq. 4) through one sampling path."""

import pickle

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from ua2c_helpers import ACT, OBS

from sb3_ua2c.buffers import ChunkReplayBuffer, ChunkReplaySamples, _StartIndex
from sb3_ua2c.offline import Episode


@pytest.fixture(autouse=True)
def _seed_numpy():
    np.random.seed(0)  # noqa: NPY002 - the buffer samples with NumPy's global RNG (seeded by SB3)


def make_buffer(size=32, n_envs=1, k=3, ell=2, ratio=0.5, targets="prefix"):
    return ChunkReplayBuffer(
        size, OBS, ACT, "cpu", n_envs=n_envs, chunk_size=k, history_len=ell, offline_ratio=ratio,
        online_targets=targets,
    )


def scanned_starts(buf):
    """The valid starts found by ``reindex()``'s scan of the whole ring, on a copy of ``buf``."""
    copy = pickle.loads(pickle.dumps(buf))
    copy.reindex()
    return copy.online_starts().tolist()


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
        out[key] = {
            name: getattr(samples, name)[i].flatten().tolist()
            for name in samples._fields
            if getattr(samples, name) is not None
        }
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
    assert a["chunk_mask"] == [1.0, 1.0, 1.0]  # the tail is the plan's, not padding: the actor learns it
    assert a["observation_history"] == [0.0, 0.0] and a["action_history"] == [0.0, 0.0]
    assert a["next_observation_history"] == [1.0, 2.0]
    assert a["next_action_history"] == pytest.approx([0.1, 0.2])
    b = got[1.0]  # plan at t=2 cut by the terminal step: L = 2, no bootstrap
    assert b["chunks"] == pytest.approx([0.3, 0.4, 1.0])
    assert b["rewards"] == pytest.approx([3.0, 4.0, 0.0])
    assert b["horizons"] == [2.0] and b["bootstrap"] == [0.0]
    assert b["chunk_mask"] == [1.0, 1.0, 1.0]  # even past the terminal step: the planned action
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
    # 5 slots hold t = 2..6; the action history a_{t-2:t-1} of t = 2 and t = 3 reaches the
    # overwritten a_0, a_1
    starts = buf.online_starts()
    assert sorted(buf.online.obs[starts, 0, 0].tolist()) == [4.0, 5.0, 6.0]
    s = rows(buf.sample(64))
    assert set(s) == {0.4, 0.5, 0.6}
    assert s[0.4]["observation_history"] == [3.0, 4.0]
    assert s[0.4]["action_history"] == pytest.approx([0.3, 0.4])


def by_start(samples):
    """Unique samples keyed by their start observation o_t, as plain lists."""
    return {
        samples.observation_history[i, -1, 0].item(): {
            name: getattr(samples, name)[i].flatten().tolist()
            for name in samples._fields
            if getattr(samples, name) is not None
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
    # slots hold t = 2..6; windows complete for t <= 4; t = 2, 3 lost a_0, a_1 to overwriting
    assert sorted(buf.online.obs[buf.online_starts(), 0, 0].tolist()) == [4.0]
    two = make_buffer(n_envs=2, targets="window")
    for t in range(3):  # env 1 terminates after its second step and starts again
        add_two_envs(two, t, terminated=[False, t == 1], start=[t == 0, t in (0, 2)])
    got = by_start(two.sample(256))
    assert set(got) == {0.0, 10.0, 11.0}  # env 0: t = 0 complete; env 1: both starts of its episode
    assert got[10.0]["horizons"] == [2.0] and got[10.0]["bootstrap"] == [0.0]
    assert got[10.0]["rewards"] == [2.0, 2.0, 0.0]


def test_online_targets_is_validated():
    for bad in ("plan", "", None, 1, "Auto"):
        with pytest.raises(ValueError, match="online_targets"):
            make_buffer(targets=bad)


def offline_episode(offset=0.0, terminated=True):
    return Episode(
        observations=np.arange(5, dtype=np.float32).reshape(5, 1) + offset,
        actions=np.array([[0.1], [0.2], [0.3], [0.4]], np.float32),
        rewards=np.array([1.0, 2.0, 3.0, 4.0]),
        terminations=np.array([False, False, False, terminated]),
        truncations=np.array([False, False, False, not terminated]),
    )


def same_samples(a, b, batch=64, seed=5):
    """Two buffers give the same batch, field for field, from the same global NumPy seed."""
    np.random.seed(seed)  # noqa: NPY002
    x = a.sample(batch)
    np.random.seed(seed)  # noqa: NPY002
    y = b.sample(batch)
    for name, u, v in zip(ChunkReplaySamples._fields, x, y, strict=True):
        assert th.equal(u, v), name


@pytest.mark.parametrize(
    ("offline", "ratio", "chosen", "n_online"),
    [(False, 0.5, "window", 5), (True, 0.5, "prefix", 3), (True, 0.0, "window", 5)],
)
def test_auto_online_targets_are_eq8_offline_to_online_and_windows_online_only(offline, ratio, chosen, n_online):
    """online_targets="auto" chooses at the first online step and then is the chosen buffer, sample for sample."""
    auto, explicit = (make_buffer(ratio=ratio, targets=t) for t in ("auto", chosen))
    assert auto.online_targets == "auto" and auto.active_online_targets is None
    assert explicit.active_online_targets == chosen
    for buf in (auto, explicit):
        if offline:
            buf.add_offline_episodes([offline_episode()])
        add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=1, start=True)
        add_step(buf, 1, plan=[0.8, 0.9, 1.0], length=2)
        add_step(buf, 2)
        add_step(buf, 3, plan=[-0.5, -0.5, -0.5], length=3)
        add_step(buf, 4, terminated=True)
    assert auto.active_online_targets == chosen and auto.online_targets == "auto"
    assert (auto.online.plans is not None) == (chosen == "prefix")
    # windows: every step of the 5 starts one; Eq. 8: one per plan (3 plans)
    assert auto.n_samples() == explicit.n_samples() == (n_online, 4 if offline else 0)
    same_samples(auto, explicit)


def test_auto_online_targets_choose_again_after_reset_and_survive_pickling():
    buf = make_buffer(targets="auto")
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=1, start=True)
    assert buf.active_online_targets == "window"
    buf.reset()  # the online part is empty again; offline episodes arrive before the next step
    assert buf.active_online_targets is None
    buf.add_offline_episodes([offline_episode()])
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=2, start=True)
    add_step(buf, 1)
    assert buf.active_online_targets == "prefix" and buf.n_samples() == (1, 4)
    # Eq. 8's sample: the executed a_0 a_1, then the plan's tail
    assert rows(buf.sample(64))[0.7]["chunks"] == pytest.approx([0.1, 0.2, 0.7])
    copy = pickle.loads(pickle.dumps(buf))
    assert copy.active_online_targets == "prefix"
    same_samples(buf, copy)


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
    assert s.chunk_mask[i0].tolist() == [1.0, 1.0, 1.0]
    assert s.next_observation_history[i0].flatten().tolist() == [2.0, 3.0]
    assert s.next_action_history[i0].flatten().tolist() == pytest.approx([0.2, 0.3])
    assert s.observation_history[i0].flatten().tolist() == [0.0, 0.0]
    # t=1: the window reaches the terminal step -> no bootstrap
    assert s.horizons[i1].item() == 3 and s.bootstrap[i1].item() == 0
    # t=2: truncated at the episode end, padded with zero actions
    assert s.chunks[i2].flatten().tolist() == pytest.approx([0.3, 0.4, 0.0])
    assert s.rewards[i2].tolist() == pytest.approx([3.0, 4.0, 0.0])
    assert s.horizons[i2].item() == 2 and s.bootstrap[i2].item() == 0
    assert s.chunk_mask[i2].tolist() == [1.0, 1.0, 0.0]  # the padding is masked out of the flow loss
    assert s.action_history[i2].flatten().tolist() == pytest.approx([0.1, 0.2])
    assert s.next_observation_history[i2].flatten().tolist() == [3.0, 4.0]
    assert s.horizons[i3].item() == 1
    assert s.chunk_mask[i3].tolist() == [1.0, 0.0, 0.0]


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


def test_one_episode_type_with_or_without_next_observations():
    """An Episode with o_1..o_T given apart, or as a mapping, is stored as the one with T+1 observations."""
    whole = offline_episode()
    split = Episode(whole.observations[:-1], whole.actions, whole.rewards, whole.terminations, whole.truncations,
                    next_observations=whole.observations[1:])
    buffers = [make_buffer(), make_buffer(), make_buffer()]
    for buf, episode in zip(buffers, [whole, split, vars(split)], strict=True):
        assert buf.add_offline_episodes([episode]) == 4
    same_samples(buffers[0], buffers[1])
    same_samples(buffers[0], buffers[2])
    with pytest.raises(ValueError, match="next_observations must have T=4 rows, got 3"):
        Episode(whole.observations[:-1], whole.actions, whole.rewards, whole.terminations, whole.truncations,
                next_observations=whole.observations[2:])


def test_offline_episode_validation():
    buf = make_buffer()
    bad = offline_episode()
    with pytest.raises(ValueError, match="rewards must have T=4 rows, got 3"):
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


# ---------------------------------------------------------------------------------------------
# the ring after it wraps: every sampled field against the true trajectory

ACT2 = spaces.Box(-1.0, 1.0, (2,), np.float32)


def true_action(e, j, t):
    """a_t of episode j of env e (float32, inside [-1, 1])."""
    return np.array([0.01 * (t + 1), 0.1 * e + 0.001 * (j + 1)], np.float32)


def true_reward(e, j, t):
    return np.float32(10_000 * e + 100 * j + t)


def true_plan(e, j, t, k):
    """The plan selected at step t: entries distinct from every executed action."""
    return np.array([[-0.01 * (t + u + 1), -0.1 * e - 0.001 * (j + 1)] for u in range(k)], np.float32)


class RingDriver:
    """
    Feeds a buffer the steps of ``n_envs`` envs whose observation is ``(env, episode, step)`` and keeps the
    truth: every closed sample start (its episode, step, horizon and bootstrap) by global add index.

    Episodes have 1..12 steps and end terminated, truncated or cut without a done flag (a restart, as
    when ``learn()`` resets the envs); the last step's next observation is ``(env, episode, T - 0.5)``.
    Plans have random ``L_t`` in 1..k and start with every episode, as the executor's.
    """

    def __init__(self, buf, seed):
        self.buf, self.n, self.k, self.ell = buf, buf.n_envs, buf.chunk_size, buf.history_len
        self.window = buf.online_targets == "window"
        self.rng = np.random.default_rng(seed)
        self.g = 0  # adds so far
        self.episode = [-1] * self.n
        self.step = [0] * self.n  # next step inside the current episode
        self.plan = [None] * self.n  # open plan per env: [start t, start g, L_t, steps executed]
        self.lengths = {}  # (env, episode) -> T
        self.ends = {}  # (env, episode) -> "terminated" | "truncated" | "restart"
        self.starts = {}  # (g, env) -> (episode, t, L, bootstrap) of every closed sample start

    def add(self):
        n, k = self.n, self.k
        obs, nxt = np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32)
        act = np.zeros((n, 2), np.float32)
        rew, term, trunc = np.zeros(n, np.float32), np.zeros(n, bool), np.zeros(n, bool)
        start, new_plan = np.zeros(n, bool), np.zeros(n, bool)
        plans, lengths = np.zeros((n, k, 2), np.float32), np.zeros(n, np.int64)
        for e in range(n):
            j = self.episode[e]
            if j < 0 or self.step[e] == self.lengths[(e, j)]:
                if self.plan[e] is not None and not self.window:  # a restart: the plan closes, bootstrapped
                    self._close_plan(e, j, True)
                j = self.episode[e] = j + 1
                self.lengths[(e, j)] = int(self.rng.integers(1, 13))
                end = self.rng.choice(["terminated", "truncated", "restart"], p=[0.4, 0.4, 0.2])
                self.ends[(e, j)] = str(end)
                self.step[e], start[e] = 0, True
            t, last = self.step[e], self.step[e] == self.lengths[(e, j)] - 1
            obs[e], nxt[e] = (e, j, t), (e, j, t + 0.5 if last else t + 1)
            act[e], rew[e] = true_action(e, j, t), true_reward(e, j, t)
            term[e] = last and self.ends[(e, j)] == "terminated"
            trunc[e] = last and self.ends[(e, j)] == "truncated"
            if start[e] or self.plan[e] is None:
                new_plan[e], lengths[e], plans[e] = True, self.rng.integers(1, k + 1), true_plan(e, j, t, k)
                self.plan[e] = [t, self.g, int(lengths[e]), 0]
            self.plan[e][3] += 1
            if self.window:
                self._close_windows(e, j, t, term[e] or trunc[e], term[e])
                if self.plan[e][3] == self.plan[e][2] or term[e] or trunc[e]:
                    self.plan[e] = None
            elif self.plan[e][3] == self.plan[e][2] or term[e] or trunc[e]:
                self._close_plan(e, j, not term[e])
            self.step[e] += 1
        self.buf.add(obs, nxt, act, rew, term, trunc, start, new_plan, plans, lengths)
        self.g += 1

    def _close_plan(self, e, j, bootstrap):
        t0, g0, _, executed = self.plan[e]
        self.starts[(g0, e)] = (j, t0, executed, bootstrap)
        self.plan[e] = None

    def _close_windows(self, e, j, t, done, terminated):
        """Step t completes the window starting k - 1 steps earlier; an episode end closes all later ones."""
        first = t - self.k + 1
        for s in range(max(first, 0), t + 1 if done else first + 1):
            self.starts[(self.g - (t - s), e)] = (j, s, t - s + 1, not terminated)

    def available(self):
        """Closed starts whose window and history a_{t-ℓ:t-1} are still in the ring: {(g, env): record}."""
        oldest = self.g - self.buf.buffer_size
        return {key: rec for key, rec in self.starts.items() if key[0] - min(rec[1], self.ell) >= oldest}


def expected_batch(driver, identities):
    """The true fields of samples starting at ``identities`` [(env, episode, t)], as ChunkReplaySamples."""
    k, ell = driver.k, driver.ell
    available = {(e, rec[0], rec[1]): rec for (_, e), rec in driver.available().items()}
    out = {name: [] for name in ChunkReplaySamples._fields}
    for e, j, t in identities:
        assert (e, j, t) in available, f"sampled start (env {e}, episode {j}, step {t}) is not available"
        _, _, horizon, bootstrap = available[(e, j, t)]

        def o(i, e=e, j=j):  # repeat-first-observation padding
            return [e, j, max(i, 0)]

        def a(i, e=e, j=j):  # zero-action padding
            return true_action(e, j, i) if i >= 0 else np.zeros(2, np.float32)

        out["observation_history"].append([o(t - ell + 1 + i) for i in range(ell)])
        out["action_history"].append([a(t - ell + i) for i in range(ell)])
        tail = np.zeros((k, 2), np.float32) if driver.window else true_plan(e, j, t, k)
        out["chunks"].append([a(t + u) if u < horizon else tail[u] for u in range(k)])
        out["rewards"].append([true_reward(e, j, t + u) if u < horizon else 0.0 for u in range(k)])
        out["horizons"].append(horizon)
        out["chunk_mask"].append([float(u < horizon or not driver.window) for u in range(k)])
        out["bootstrap"].append(float(bootstrap))
        end = t + horizon
        history = [o(end - ell + 1 + i) for i in range(ell)]
        if end == driver.lengths[(e, j)]:
            history[-1] = [e, j, end - 0.5]  # the next observation of the episode's last step
        out["next_observation_history"].append(history)
        out["next_action_history"].append([a(end - ell + i) for i in range(ell)])
    return {name: np.array(v, np.float32) for name, v in out.items()}


@pytest.mark.parametrize("targets", ["prefix", "window"])
@pytest.mark.parametrize(("size", "n_envs"), [(25, 1), (40, 1), (29, 3), (37, 3)])
def test_ring_samples_are_the_true_trajectory_after_wrapping(size, n_envs, targets):
    """
    Each sample's every field equals the env's true trajectory in the current episode (with the
    documented padding before its start) while the ring wraps six times; the starts offered are
    exactly the closed ones whose history a_{t-ℓ:t-1} has not been overwritten.
    """
    buf = ChunkReplayBuffer(
        size, spaces.Box(-np.inf, np.inf, (3,), np.float32), ACT2, "cpu", n_envs=n_envs,
        chunk_size=5, history_len=4, offline_ratio=0.5, online_targets=targets,
    )
    driver = RingDriver(buf, seed=size + n_envs)
    n_checked = 0
    while driver.g < 6 * size:
        driver.add()
        available = driver.available()
        want = sorted((g % size) * n_envs + e for g, e in available)
        assert buf.online_starts().tolist() == want == scanned_starts(buf)
        assert buf.n_samples() == (len(available), 0)
        if driver.g % 3 or not available:
            continue
        samples = buf.sample(64)
        identities = [tuple(int(x) for x in row) for row in samples.observation_history[:, -1].numpy()]
        want = expected_batch(driver, identities)
        for name in ChunkReplaySamples._fields:
            np.testing.assert_array_equal(getattr(samples, name).numpy(), want[name], err_msg=name)
        n_checked += 64
    assert n_checked >= 2000


@pytest.mark.parametrize("targets", ["prefix", "window"])
def test_reset_forgets_the_ring(targets):
    """After reset() an episode that goes on is a sample start only once its history is stored again."""
    buf = make_buffer(size=8, targets=targets)
    for t in range(5):
        add_step(buf, t, plan=[0.0, 0.0, 0.0], length=1, start=(t == 0))
    buf.reset()
    assert buf.n_samples() == (0, 0)
    for t in range(5, 9):  # the episode goes on in slots 0..3; a_{t-2} of t = 5, 6 is not stored
        add_step(buf, t, plan=[0.0, 0.0, 0.0], length=1, terminated=(t == 8))
    assert buf.n_samples() == (2, 0)
    got = by_start(buf.sample(64))
    assert set(got) == {7.0, 8.0}
    assert got[7.0]["observation_history"] == [6.0, 7.0]
    assert got[7.0]["action_history"] == pytest.approx([0.6, 0.7])


def test_episode_start_closes_an_open_plan():
    """An episode restarted without a done flag ends the open plan there, even without a new plan."""
    buf = make_buffer()
    add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=3, start=True)
    add_step(buf, 1)
    add_step(buf, 0, start=True)  # no plan starts here
    add_step(buf, 1)
    assert buf.n_samples() == (1, 0)
    s = rows(buf.sample(8))[0.7]
    assert s["horizons"] == [2.0] and s["bootstrap"] == [1.0]
    assert s["chunks"] == pytest.approx([0.1, 0.2, 0.7])
    assert s["next_observation_history"] == [1.0, 2.0]


@pytest.mark.parametrize("length", [0, 4])
def test_plan_lengths_are_validated(length):
    buf = make_buffer()  # k = 3
    with pytest.raises(ValueError, match="plan_lengths"):
        add_step(buf, 0, plan=[0.5, 0.6, 0.7], length=length, start=True)


def wrapped_buffer(targets="prefix"):
    buf = ChunkReplayBuffer(
        29, spaces.Box(-np.inf, np.inf, (3,), np.float32), ACT2, "cpu", n_envs=3, chunk_size=5, history_len=4,
        offline_ratio=0.5, online_targets=targets,
    )
    driver = RingDriver(buf, seed=1)
    for _ in range(100):
        driver.add()
    return buf


def test_pickled_buffer_keeps_its_starts():
    buf = wrapped_buffer()
    starts = buf.online_starts().tolist()
    assert len(starts) > 10
    copy = pickle.loads(pickle.dumps(buf))
    assert copy.online_starts().tolist() == starts
    same_samples(buf, copy, batch=32, seed=3)


def test_start_index_is_a_set():
    """Random insertions and removals: the members are those of a Python set, samples are members."""
    rng = np.random.default_rng(0)
    index, truth = _StartIndex(50), set()
    for _ in range(300):
        flat = rng.choice(50, size=int(rng.integers(0, 6)), replace=False)
        if rng.random() < 0.5:
            index.insert(flat)
            truth |= set(flat.tolist())
        else:
            index.remove(flat)
            truth -= set(flat.tolist())
        assert index.members().tolist() == sorted(truth)
        assert index.size == len(truth)
        assert sorted(np.flatnonzero(index.place >= 0).tolist()) == sorted(truth)
        if truth:
            assert set(index.sample(20).tolist()) <= truth
