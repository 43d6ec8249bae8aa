"""MixedTraffic-v0 on SUMO: API contracts, determinism, reward terms in controlled situations, safety guards."""

import contextlib
import subprocess
import sys
import warnings

import gymnasium as gym
import libsumo  # noqa: F401  (a required dependency: a broken install must fail, not skip)
import numpy as np
import pytest

import envs
from envs.mdp import SLOT_FEATURES, STYLES
from envs.mixed_traffic import AV_ID, MixedTrafficEnv
from envs.sumo import SumoProcessBusyError, process_owner

A_MAX, A_MIN, DT = 3.0, -4.5, 0.2


def act(accel=0.0, lane_change=0.0):
    return np.array([accel, lane_change], dtype=np.float32)


def drive_to_accel_lane(env, x_min=420.0):
    """Keep speed until the AV is on the acceleration lane past ``x_min``; return the last info."""
    for _ in range(200):
        _, _, terminated, truncated, info = env.step(act())
        assert not (terminated or truncated)
        if info["av_lane"] == -1 and info["av_x"] >= x_min:
            return info
    raise AssertionError("the AV never reached the acceleration lane")


def test_registered_and_spaces(make_env):
    env = make_env()
    assert isinstance(env.unwrapped, MixedTrafficEnv)
    assert env.action_space.shape == (2,) and env.observation_space.shape == (20,)
    np.testing.assert_array_equal(env.action_space.low, [A_MIN, -1.0])
    np.testing.assert_array_equal(env.action_space.high, [A_MAX, 1.0])


def _checker_warnings_are_errors(stack: contextlib.ExitStack) -> None:
    stack.enter_context(warnings.catch_warnings())
    warnings.simplefilter("error")  # any other checker warning fails the test
    # SB3 recommends a [-1, 1] action box; ours is in m/s² (SB3's off-policy algorithms rescale)
    warnings.filterwarnings("ignore", message="We recommend you to use a symmetric")
    warnings.filterwarnings("ignore", message=".*we recommend using a symmetric and normalized space")


@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_gymnasium_and_sb3_check_env_with_their_defaults(make_env, render_mode):
    """Both checkers with default arguments: Gymnasium's builds further envs with ``env.spec.make()``
    (one reset and rendered, one closed twice) while the checked one is open."""
    from gymnasium.utils.env_checker import check_env as gym_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = make_env(render_mode=render_mode)
    with contextlib.ExitStack() as stack:
        _checker_warnings_are_errors(stack)
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped)
    assert process_owner() is env.unwrapped.sim  # SB3's checker reset it last
    env.close()
    assert process_owner() is None


def test_check_env_with_the_style_context_wrapper(make_env):
    """The rl-zoo configs wrap MixedTraffic-v0 in DrivingStyleContext; ``env.spec.make()`` rebuilds both."""
    from gymnasium.utils.env_checker import check_env as gym_check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    from envs.wrappers import DrivingStyleContext

    env = DrivingStyleContext(make_env(render_mode="rgb_array"), update_every=5)
    rebuilt = env.spec.make()
    assert isinstance(rebuilt, DrivingStyleContext) and rebuilt.update_every == 5
    assert rebuilt.observation_space.shape == (38,)
    rebuilt.close()
    with contextlib.ExitStack() as stack:
        _checker_warnings_are_errors(stack)
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version")
        gym_check_env(env)
        sb3_check_env(env)


def test_construction_starts_and_claims_nothing(make_env):
    first = make_env()
    first.reset(seed=0)
    owner = process_owner()
    assert owner is first.unwrapped.sim and owner.running
    second = make_env(num_hdvs=12)
    u = second.unwrapped
    # Spaces at once, no simulation, no scenario files, the live env untouched.
    assert second.observation_space.shape == (20,) and second.action_space.shape == (2,)
    assert u.sim is None and u.scenario is None
    assert process_owner() is owner and owner.running
    obs, *_ = first.step(act())
    assert np.all(np.isfinite(obs))
    second.close()  # before any reset: harmless, and the first env keeps its simulation
    second.close()
    assert process_owner() is owner and owner.running
    with pytest.raises(RuntimeError, match="closed"):
        second.reset(seed=0)
    first.close()
    assert process_owner() is None


def test_close_is_idempotent(make_env):
    env = make_env()
    env.close()
    env.close()
    env = make_env()
    env.reset(seed=0)
    assert len(env.unwrapped.hdv_styles()) == 34
    env.close()
    env.close()
    assert env.unwrapped.hdv_styles() == {}  # no libsumo call on a closed simulation


def test_random_rollout_obs_finite_and_info_contract(make_env):
    env = make_env()
    obs, info = env.reset(seed=0)
    env.action_space.seed(0)
    rng_steps = 0
    for _ in range(300):
        assert obs.dtype == np.float32 and env.observation_space.contains(obs) and np.all(np.isfinite(obs))
        slots = info["slots"]
        assert len(slots["ids"]) == 6 and slots["styles"].dtype == np.int64 and slots["styles"].shape == (6,)
        assert slots["features"].dtype == np.float32 and slots["features"].shape == (6, len(SLOT_FEATURES))
        assert slots["present"].dtype == bool
        styles = env.unwrapped.hdv_styles()
        assert len(styles) <= 34 and set(styles.values()) <= {0, 1, 2}
        for k in range(6):
            vid = slots["ids"][k]
            if slots["present"][k]:
                assert styles[vid] == slots["styles"][k]
                dp, lane_offset = slots["features"][k, 0], slots["features"][k, 4]
                assert (dp >= 0) if k < 3 else (dp < 0)
                assert lane_offset == [1, 0, -1][k % 3]  # l_1/f_1 left (+1), l_2/f_2 current, l_3/f_3 right
                assert 0.0 <= slots["features"][k, 5] <= 100.0
            else:
                assert vid == "" and slots["styles"][k] == -1 and not slots["features"][k].any()
        assert set(info["reward_terms"]) == set(info["reward_terms_raw"]) == {
            "speed", "leader_distance", "follower_distance", "merge", "jerk", "lane_change", "collision"}
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert reward == pytest.approx(sum(info["reward_terms"].values()))
        # follower / leader terms follow from the reported slots (same formula as by hand)
        f2, l2 = info["slots"]["features"][4], info["slots"]["features"][1]
        expected_f = -min(1.0, max(0.0, 1 - (-f2[0] - 5.0) / (2.0 + f2[3]))) if info["slots"]["present"][4] else 0.0
        expected_l = (-min(1.0, max(0.0, 1 - (l2[0] - 5.0) / (2.0 + info["av_speed"])))
                      if info["slots"]["present"][1] else 0.0)
        if not info["left_network"]:
            assert info["reward_terms_raw"]["follower_distance"] == pytest.approx(expected_f, abs=1e-5)
            assert info["reward_terms_raw"]["leader_distance"] == pytest.approx(expected_l, abs=1e-5)
        rng_steps += 1
        if terminated or truncated:
            obs, info = env.reset()
    assert rng_steps == 300


def test_determinism_same_seed_bit_identical(make_env):
    env = make_env()
    actions = np.random.default_rng(3).uniform([A_MIN, -1.0], [A_MAX, 1.0], size=(150, 2)).astype(np.float32)

    def rollout():
        out = []
        for a in actions:
            obs, reward, terminated, truncated, info = env.step(a)
            out.append((obs.copy(), reward, info["slots"]["ids"]))
            if terminated or truncated:
                break
        return out

    obs_a, _ = env.reset(seed=7)
    traj_a = rollout()
    env.reset()  # another episode in between must not matter
    rollout()
    obs_b, _ = env.reset(seed=7)
    traj_b = rollout()
    assert np.array_equal(obs_a, obs_b) and len(traj_a) == len(traj_b)
    for (oa, ra, ia), (ob, rb, ib) in zip(traj_a, traj_b, strict=True):
        assert np.array_equal(oa, ob) and ra == rb and ia == ib
    obs_c, _ = env.reset(seed=8)
    assert not np.array_equal(obs_a, obs_c)


def test_fast_reset_equals_reload(make_env):
    """reset() without a seed reuses the simulation; it must give what a reload gives."""
    from gymnasium.utils import seeding

    env = make_env()
    u = env.unwrapped
    actions = [act(0.5 * np.sin(t / 7.0), 0.0) for t in range(120)]
    u.reset(seed=11)
    ref = [u.step(a)[0].copy() for a in actions]
    u.np_random, _ = seeding.np_random(11)
    u.reset()  # soft path, same np_random state as reset(seed=11)
    soft = [u.step(a)[0].copy() for a in actions]
    assert all(np.array_equal(a, b) for a, b in zip(ref, soft, strict=True))


def test_speed_jerk_terms_by_hand(make_env):
    env = make_env(num_hdvs=0)
    _, info = env.reset(seed=1)
    v0 = info["av_speed"]
    assert 15.0 <= v0 <= 20.0
    _, r, _, _, info = env.step(act(1.0))
    assert info["av_speed"] == pytest.approx(v0 + 0.2, abs=1e-9)
    raw = info["reward_terms_raw"]
    assert raw["speed"] == pytest.approx(1 - abs(v0 + 0.2 - 25.0) / 25.0, abs=1e-9)
    # a: 0 -> 1 in 0.2 s: j = 5 m/s^3, j_max = 7.5 / 0.2 = 37.5
    assert info["jerk"] == pytest.approx(5.0, abs=1e-6)
    assert raw["jerk"] == pytest.approx(-((5.0 / 37.5) ** 2), abs=1e-9)
    assert raw["leader_distance"] == raw["follower_distance"] == raw["lane_change"] == raw["collision"] == 0.0
    assert r == pytest.approx(raw["speed"] + 0.5 * raw["jerk"], abs=1e-9)
    np.testing.assert_allclose(info["applied_action"], [1.0, 0.0], atol=1e-5)
    _, _, _, _, info = env.step(act(-2.0))
    assert info["jerk"] == pytest.approx(-15.0, abs=1e-6)
    assert info["reward_terms_raw"]["jerk"] == pytest.approx(-0.16, abs=1e-9)
    # out-of-range acceleration is clipped to a_max
    _, _, _, _, info = env.step(act(100.0))
    assert info["applied_action"][0] == pytest.approx(A_MAX, abs=1e-5)


def test_merge_and_lane_change_terms_by_hand(make_env):
    env = make_env(num_hdvs=0)
    env.reset(seed=2)
    # a left change on the ramp edge is impossible: nothing happens, no penalty
    _, _, _, _, info = env.step(act(0.0, -1.0))
    assert info["av_lane"] == -1 and info["lane_change"] == 0 and info["reward_terms_raw"]["lane_change"] == 0.0
    info = drive_to_accel_lane(env)
    x_before = info["av_x"]
    _, r, _, _, info = env.step(act(0.0, -1.0))  # merge (left)
    assert info["av_lane"] == 0 and info["lane_change"] == -1 and info["merge_done"]
    remaining = 650.0 - info["av_x"]
    assert info["av_x"] > x_before
    assert info["reward_terms_raw"]["merge"] == pytest.approx(0.5 + 0.5 * remaining / 250.0, abs=1e-9)
    assert info["reward_terms"]["merge"] == pytest.approx(10.0 * (0.5 + 0.5 * remaining / 250.0), abs=1e-9)
    assert info["reward_terms_raw"]["lane_change"] == 0.0  # the merge is not "unnecessary"
    np.testing.assert_allclose(info["applied_action"], [0.0, -1.0], atol=1e-5)
    _, _, _, _, info = env.step(act(0.0, -0.9))  # discretionary change left: lane 1
    assert info["av_lane"] == 1 and info["lane_change"] == -1
    assert info["reward_terms_raw"]["lane_change"] == -1.0 and info["reward_terms"]["lane_change"] == -0.5
    assert info["reward_terms_raw"]["merge"] == 0.0  # paid once
    _, _, _, _, info = env.step(act(0.0, 0.9))  # right: back to lane 0
    assert info["av_lane"] == 0 and info["lane_change"] == 1 and info["reward_terms_raw"]["lane_change"] == -1.0
    _, _, _, _, info = env.step(act(0.0, 0.9))  # right of lane 0 after the merge area: no lane
    if info["av_x"] >= 650.0:
        assert info["av_lane"] == 0 and info["lane_change"] == 0 and info["reward_terms_raw"]["lane_change"] == 0.0


def test_lane_end_is_a_collision(make_env):
    env = make_env(num_hdvs=0)
    env.reset(seed=3)
    for _ in range(300):
        _, r, terminated, truncated, info = env.step(act(1.0))
        if terminated:
            break
    assert terminated and not truncated
    assert info["collision"] and info["collision_type"] == "lane_end"
    assert info["reward_terms"]["collision"] == -100.0 and r < -90.0
    with pytest.raises(RuntimeError, match="reset"):
        env.step(act())


def test_driving_into_leader_collides_with_penalty(make_env):
    env = make_env(num_hdvs=0)
    u = env.unwrapped
    env.reset(seed=4)
    # a stopped car on highway lane 0 at x = 550 m (merge edge, SUMO lane 1), inserted on the empty road
    u.sim.add_vehicle("blocker", "r_merge", "neutral", "150", "1", "0")
    env.step(act(0.0))
    veh = u.sim.libsumo.vehicle
    assert "blocker" in u.sim.vehicle_ids()
    veh.setSpeed("blocker", 0.0)
    veh.setLaneChangeMode("blocker", 0)
    drive_to_accel_lane(env, x_min=420.0)
    _, _, _, _, info = env.step(act(0.0, -1.0))
    assert info["av_lane"] == 0 and info["av_x"] < 520.0
    saw_penalty = False
    for _ in range(100):
        _, r, terminated, truncated, info = env.step(act(A_MAX))
        if terminated:
            break
        slots = info["slots"]
        if not slots["present"][1]:  # still more than V = 30 m ahead
            assert info["reward_terms_raw"]["leader_distance"] == 0.0
            continue
        assert slots["ids"][1] == "blocker" and slots["styles"][1] == -1  # not an HDV of the scenario
        gap = slots["features"][1, 0] - 5.0
        expected = -min(1.0, max(0.0, 1.0 - gap / (2.0 + 1.0 * info["av_speed"])))
        assert info["reward_terms_raw"]["leader_distance"] == pytest.approx(expected, abs=1e-5)
        saw_penalty |= expected < -0.1
    assert saw_penalty
    assert terminated and info["collision"] and info["collision_type"] == "vehicle"
    assert info["reward_terms_raw"]["collision"] == -1.0 and info["reward_terms"]["collision"] == -100.0


def test_follower_distance_term(make_env):
    env = make_env(num_hdvs=0)
    u = env.unwrapped
    env.reset(seed=5)
    drive_to_accel_lane(env, x_min=440.0)
    _, _, _, _, info = env.step(act(0.0, -1.0))
    merge_pos = info["av_x"] - 400.0
    assert merge_pos > 30.0  # the chaser starts 25 m behind, still on the merge edge
    u.sim.add_vehicle("chaser", "r_merge", "aggressive", f"{merge_pos - 25.0:.2f}", "1", "max")
    env.step(act(0.0))
    veh = u.sim.libsumo.vehicle
    veh.setSpeedMode("chaser", 0)  # closes in at 4 m/s on the AV's lane, ignoring the AV
    veh.setLaneChangeMode("chaser", 0)
    veh.setSpeed("chaser", info["av_speed"] + 4.0)
    seen = []
    for _ in range(10):
        _, _, _, _, info = env.step(act(0.0))
        if info["slots"]["present"][4]:
            f2 = info["slots"]["features"][4]
            gap = -f2[0] - 5.0
            expected = -min(1.0, max(0.0, 1.0 - gap / (2.0 + 1.0 * f2[3])))
            assert info["reward_terms_raw"]["follower_distance"] == pytest.approx(expected, abs=1e-5)
            assert info["reward_terms"]["follower_distance"] == pytest.approx(0.5 * expected, abs=1e-5)
            seen.append(expected)
    assert seen and min(seen) < -0.05


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [0.0, np.inf], [1.0, 0.0, 0.0], [[1.0, 0.0]], "fast"])
def test_bad_actions_raise(make_env, bad):
    env = make_env()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(bad)


def test_bad_kwargs_and_options_raise(make_env):
    with pytest.raises(ValueError, match="num_hdv"):
        gym.make("MixedTraffic-v0", num_hdv=3)
    with pytest.raises(ValueError, match="render_mode"):
        MixedTrafficEnv(render_mode="rgb")  # raised before any simulator is started
    env = make_env()
    with pytest.raises(ValueError, match="reload"):
        env.reset(seed=0, options={"reload": True})
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(act())


def test_the_last_reset_owns_the_process_simulation(make_env):
    """libsumo holds one simulation per process: a reset takes it, and the env it was taken from
    raises the busy error instead of ever reading the other env's vehicles."""
    actions = [act(2.0 * np.sin(t / 3.0), 0.0) for t in range(12)]

    def rollout(env, seed):
        obs, _ = env.reset(seed=seed)
        return np.array([obs] + [env.step(a)[0] for a in actions])

    reference = {}
    for seed in (0, 1):  # each env alone
        env = make_env()
        reference[seed] = rollout(env, seed)
        env.close()
    a, b = make_env(render_mode="rgb_array"), make_env()
    np.testing.assert_array_equal(rollout(a, 0)[:3], reference[0][:3])  # a mid-episode
    np.testing.assert_array_equal(rollout(b, 1), reference[1])  # b's reset took the simulation
    assert process_owner() is b.unwrapped.sim and a.unwrapped.sim.taken
    for call in (lambda: a.step(act()), a.render, lambda: a.unwrapped.set_ego_controller("sumo")):
        with pytest.raises(SumoProcessBusyError, match="SubprocVecEnv"):
            call()
    assert a.unwrapped.hdv_styles() == {}
    # b's own second reset is an ordinary reset; a's reset takes the simulation back.
    np.testing.assert_array_equal(rollout(b, 1), reference[1])
    np.testing.assert_array_equal(rollout(a, 0), reference[0])
    with pytest.raises(SumoProcessBusyError, match="reset"):
        b.step(act())
    # Closing the env that lost the simulation leaves the owner's running.
    b.close()
    assert process_owner() is a.unwrapped.sim
    assert np.all(np.isfinite(a.step(act())[0]))
    a.close()
    assert process_owner() is None
    with pytest.raises(RuntimeError, match="closed"):
        a.reset(seed=0)
    other = make_env()  # a fresh env after close
    np.testing.assert_array_equal(rollout(other, 1), reference[1])


def test_dummy_vec_env_of_two_refused():
    from stable_baselines3.common.env_util import make_vec_env

    vec = make_vec_env("envs:MixedTraffic-v0", n_envs=2, seed=0)  # building them starts nothing
    try:
        vec.reset()  # the second env's reset takes the process's simulation from the first
        with pytest.raises(SumoProcessBusyError, match="SubprocVecEnv"):
            vec.step(np.zeros((2, 2), dtype=np.float32))
    finally:
        vec.close()
    assert process_owner() is None


def test_subproc_vec_env_steps_independently():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    actions = [act(0.4 * np.cos(t / 5.0), 0.0) for t in range(25)]
    reference = []
    for seed in (0, 1):  # in-process reference trajectories, one env at a time
        env = gym.make("MixedTraffic-v0")
        obs, _ = env.reset(seed=seed)
        traj = [obs] + [env.step(a)[0] for a in actions]
        env.close()
        reference.append(np.array(traj))
    # "envs:" makes gymnasium import the package (and so register the id) in each worker process
    vec = make_vec_env("envs:MixedTraffic-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    try:
        traj = [vec.reset()]
        for a in actions:
            obs, _, dones, _ = vec.step(np.stack([a, a]))
            assert not dones.any()
            traj.append(obs)
        traj = np.array(traj)  # (steps, n_envs, 20)
    finally:
        vec.close()
    assert not np.array_equal(traj[:, 0], traj[:, 1])
    np.testing.assert_array_equal(traj[:, 0], reference[0])
    np.testing.assert_array_equal(traj[:, 1], reference[1])


def test_style_headways_are_ordered(make_env):
    """Measured time headways of car-following HDVs: aggressive < neutral < conservative."""
    env = make_env(ego_controller="sumo")
    u = env.unwrapped
    env.reset(seed=0)
    veh = u.sim.libsumo.vehicle
    min_gap = {0: 3.5, 1: 2.5, 2: 1.0}
    headways = {0: [], 1: [], 2: []}
    for _ in range(200):
        _, _, terminated, truncated, _ = env.step(act())
        for vid, style in u.hdv_styles().items():
            speed = veh.getSpeed(vid)
            leader = veh.getLeader(vid, 60.0)
            if speed > 10.0 and leader and leader[0]:
                headways[style].append((leader[1] + min_gap[style]) / speed)
        if terminated or truncated:
            break
    med = [float(np.median(headways[s])) for s in range(3)]
    assert all(len(headways[s]) > 50 for s in range(3)), [len(h) for h in headways.values()]
    assert med[2] < med[1] < med[0], dict(zip(STYLES, med, strict=True))


def test_sumo_controller_reports_applied_action(make_env):
    env = make_env()
    _, info = env.reset(seed=6, options={"ego_controller": "sumo"})
    assert info["ego_controller"] == "sumo"
    merged = False
    for _ in range(200):
        prev_speed = info["av_speed"]
        _, _, terminated, truncated, info = env.step(act(A_MIN, 1.0))  # ignored under SUMO control
        accel = (info["av_speed"] - prev_speed) / DT
        assert info["applied_action"][0] == pytest.approx(np.clip(accel, A_MIN, A_MAX), abs=1e-4)
        assert info["applied_action"][1] == info["lane_change"]
        assert env.action_space.contains(info["applied_action"])
        merged |= info["lane_change"] == -1 and info["merge_done"]
        if terminated or truncated:
            break
    assert merged and not info["collision"]
    # back to agent control for the next episode by default
    _, info = env.reset(seed=6)
    assert info["ego_controller"] == "agent"
    env.unwrapped.set_ego_controller("sumo")
    assert env.unwrapped.ego_controller == "sumo"
    with pytest.raises(ValueError, match="controller"):
        env.unwrapped.set_ego_controller("robot")


def test_render_rgb_array(make_env):
    from envs.rendering import HEIGHT, WIDTH
    from envs.scenario import STYLE_COLORS

    env = make_env(render_mode="rgb_array")
    env.reset(seed=0)
    env.step(act())
    frame = env.render()
    assert frame.shape == (HEIGHT, WIDTH, 3) and frame.dtype == np.uint8
    colours = {tuple(c) for c in frame.reshape(-1, 3)}
    assert (220, 30, 30) in colours  # the AV
    assert sum(c in colours for c in STYLE_COLORS.values()) >= 2  # HDVs coloured by style
    assert AV_ID == "av"


def test_import_without_sumo_and_clear_error():
    code = (
        "import sys; sys.modules['libsumo'] = None\n"
        "import envs, sb3_ua2c, gymnasium as gym\n"
        "from envs.sumo import SumoNotInstalledError\n"
        "try:\n"
        "    gym.make('MixedTraffic-v0')\n"
        "except SumoNotInstalledError as e:\n"
        "    print('OK', e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("OK") and "pip install eclipse-sumo libsumo" in out.stdout


def test_envs_package_exports():
    assert envs.STYLES == STYLES
    assert envs.MixedTrafficEnv is MixedTrafficEnv


def test_hdvs_reenter_and_av_leaves_the_road(make_env):
    """Over a long episode the HDV count holds (leavers re-enter at the start); the AV leaving ends the episode."""
    env = make_env(time_limit=120.0, ego_controller="sumo")
    u = env.unwrapped
    env.reset(seed=0)
    seen_positions = {}
    for _ in range(600):
        _, _, terminated, truncated, info = env.step(act())
        for vid, lane_id, pos in u.sim.lane_positions():
            if vid.startswith("hdv_"):
                seen_positions.setdefault(vid, []).append(lane_id.startswith("hw_in") and pos < 20.0)
        if terminated or truncated:
            break
    assert terminated and not truncated and info["left_network"] and not info["collision"]
    assert info["av_x"] == 1500.0 and info["slots"]["ids"] == ("",) * 6
    assert len(u.hdv_styles()) + len(u.sim.pending_ids()) == 34
    reentered = [vid for vid, near_start in seen_positions.items() if any(near_start[10:])]
    assert len(reentered) >= 5  # vehicles seen again at the highway entry after the start


def test_record_video(tmp_path):
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(
        gym.make("MixedTraffic-v0", render_mode="rgb_array", time_limit=2.0),
        str(tmp_path / "videos"), episode_trigger=lambda _: True, disable_logger=True,
    )
    try:
        env.reset(seed=0)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(act())
            done = terminated or truncated
    finally:
        env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 1000
