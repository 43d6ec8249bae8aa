"""Pure maths of MixedTraffic-v0 (envs.mdp) and its configs, against numbers computed by hand. No SUMO."""

import math

import numpy as np
import pytest

from envs.mdp import (
    OBS_HIGH,
    OBS_LOW,
    OBS_NAMES,
    REWARD_TERMS,
    SLOT_FEATURES,
    SLOT_NAMES,
    STYLES,
    RewardConfig,
    collision_penalty,
    find_slots,
    jerk_penalty,
    lane_change_from_action,
    lane_change_penalty,
    lane_distance,
    lane_exists,
    merge_reward,
    observation_vector,
    safety_distance_penalty,
    target_lane_index,
    target_speed_reward,
    weighted_reward,
)
from envs.mixed_traffic import MixedTrafficConfig
from envs.scenario import ScenarioGeometry


def test_contract_constants():
    assert STYLES == ("conservative", "neutral", "aggressive")
    assert SLOT_NAMES == ("l_1", "l_2", "l_3", "f_1", "f_2", "f_3")
    assert SLOT_FEATURES == ("dp", "dv", "accel", "speed", "lane_offset", "gap_to_leader", "lane_density")
    assert len(OBS_NAMES) == 20 and OBS_NAMES[:3] == ("v", "p", "dv_l_1") and OBS_NAMES[-1] == "zeta_3"
    assert OBS_LOW.shape == OBS_HIGH.shape == (20,)
    # the constants are importable from the env module too (contract with style inference)
    from envs import mixed_traffic

    assert mixed_traffic.STYLES is STYLES and mixed_traffic.SLOT_FEATURES is SLOT_FEATURES


@pytest.mark.parametrize(
    "value, expected", [(-1.0, -1), (-0.34, -1), (-1 / 3, 0), (0.0, 0), (0.3333, 0), (1 / 3, 0), (0.34, 1), (1.0, 1)]
)
def test_lane_change_thresholds(value, expected):
    assert lane_change_from_action(value) == expected


def test_target_lane_left_is_higher_index():
    assert target_lane_index(0, -1) == 1  # left
    assert target_lane_index(0, 1) == -1  # right
    assert target_lane_index(2, 0) == 2


def test_lane_existence_and_distance():
    # road 1500 m, acceleration lane ends at 650 m, cap 300 m
    assert lane_exists(-1, 500.0, 650.0) and not lane_exists(-1, 650.0, 650.0)
    assert not lane_exists(3, 10.0, 650.0) and not lane_exists(-2, 10.0, 650.0)
    assert lane_distance(-1, 500.0, 1500.0, 650.0, 300.0) == 150.0
    assert lane_distance(0, 500.0, 1500.0, 650.0, 300.0) == 300.0
    assert lane_distance(2, 1400.0, 1500.0, 650.0, 300.0) == 100.0
    assert lane_distance(-1, 700.0, 1500.0, 650.0, 300.0) == 0.0
    assert lane_distance(3, 700.0, 1500.0, 650.0, 300.0) == 0.0


def test_find_slots_by_hand():
    # AV at x = 100 on lane 0; V = 30
    xs = [110.0, 125.0, 95.0, 131.0, 70.0, 100.0, 105.0]
    lanes = [0, 0, 1, 1, 0, -1, 2]
    slots, counts = find_slots(100.0, 0, xs, lanes, 30.0)
    # l_1 (left=lane 1): none ahead within 30 (131 is 31 m ahead); l_2: 110; l_3 (lane -1): x=100 (d=0 counts as ahead)
    # f_1: 95; f_2: 70 (exactly 30 m behind is inside); f_3: none. Lane 2 is not observed from lane 0.
    assert slots == [-1, 0, 5, 2, 4, -1]
    assert counts == [1, 3, 1]


def test_observation_vector_by_hand():
    obs = observation_vector(
        speed=15.0, x=300.0, road_length=1500.0,
        dv=np.array([3.0, 0.0, -6.0, 0.0, 0.0, 0.0]),
        dp=np.array([15.0, 30.0, 30.0, -30.0, -7.5, -30.0]),
        density=np.array([0.0, 50.0, 1000.0 / 7.5]),
        zeta=np.array([300.0, 150.0, 0.0]),
        window=30.0, zeta_cap=300.0,
    )
    expected = [0.5, 0.2, 0.1, 0.0, -0.2, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, -1.0, -0.25, -1.0,
                0.0, 0.375, 1.0, 1.0, 0.5, 0.0]
    assert obs.dtype == np.float32 and obs.shape == (20,)
    np.testing.assert_allclose(obs, expected, rtol=0, atol=1e-6)
    # clipped into the bounds: 60 m/s -> 2.0 -> 1.5
    fast = observation_vector(60.0, 300.0, 1500.0, np.zeros(6), np.zeros(6), np.zeros(3), np.zeros(3), 30.0, 300.0)
    assert fast[0] == pytest.approx(1.5)


def test_reward_terms_by_hand():
    assert target_speed_reward(20.0, 25.0) == pytest.approx(0.8)
    assert target_speed_reward(25.0, 25.0) == 1.0
    assert target_speed_reward(0.0, 25.0) == 0.0
    assert target_speed_reward(100.0, 25.0) == -1.0  # clipped
    # gap 10 m at 20 m/s, d_safe = 2 + 1 * 20 = 22 -> -(1 - 10/22)
    assert safety_distance_penalty(10.0, 20.0, 1.0, 2.0) == pytest.approx(-(1 - 10 / 22))
    assert safety_distance_penalty(30.0, 20.0, 1.0, 2.0) == 0.0
    assert safety_distance_penalty(-3.0, 20.0, 1.0, 2.0) == -1.0
    assert safety_distance_penalty(None, 20.0, 1.0, 2.0) == 0.0
    assert merge_reward(True, 125.0, 250.0) == pytest.approx(0.75)
    assert merge_reward(True, 0.0, 250.0) == pytest.approx(0.5)
    assert merge_reward(False, 125.0, 250.0) == 0.0
    # a: -0.5 -> 1.0 in 0.2 s: j = 7.5 m/s^3; j_max = (3 + 4.5) / 0.2 = 37.5 -> -(0.2)^2
    r, j = jerk_penalty(1.0, -0.5, 0.2, -4.5, 3.0)
    assert j == pytest.approx(7.5) and r == pytest.approx(-0.04)
    assert lane_change_penalty(1, False) == -1.0
    assert lane_change_penalty(-1, False) == -1.0
    assert lane_change_penalty(-1, True) == 0.0  # the merge is not penalised
    assert lane_change_penalty(0, False) == 0.0
    assert collision_penalty(True) == -1.0 and collision_penalty(False) == 0.0


def test_weighted_reward_by_hand():
    raw = {"speed": 0.8, "leader_distance": -0.5, "follower_distance": -0.2, "merge": 0.75,
           "jerk": -0.04, "lane_change": -1.0, "collision": 0.0}
    total, weighted = weighted_reward(raw, RewardConfig())
    # 1*0.8 + 1*(-0.5) + 0.5*(-0.2) + 10*0.75 + 0.5*(-0.04) + 0.5*(-1) + 100*0
    assert total == pytest.approx(0.8 - 0.5 - 0.1 + 7.5 - 0.02 - 0.5)
    assert weighted["merge"] == pytest.approx(7.5) and tuple(weighted) == REWARD_TERMS
    total, _ = weighted_reward(dict(raw, collision=-1.0), RewardConfig(collision=50.0))
    assert total == pytest.approx(0.8 - 0.5 - 0.1 + 7.5 - 0.02 - 0.5 - 50.0)


@pytest.mark.parametrize(
    "values, match",
    [
        ({"colision": 1.0}, "colision"),
        ({"speed": -1.0}, "RewardConfig.speed"),
        ({"jerk": float("nan")}, "RewardConfig.jerk"),
        ({"merge": "10"}, "RewardConfig.merge"),
        ({"collision": True}, "RewardConfig.collision"),
        ({"safe_time_headway": 0.0}, "RewardConfig.safe_time_headway"),
    ],
)
def test_reward_config_rejects_bad_values(values, match):
    with pytest.raises(ValueError, match=match):
        RewardConfig.from_dict(values)


def test_reward_config_is_frozen():
    cfg = RewardConfig()
    with pytest.raises(AttributeError):
        cfg.speed = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_hdv": 3}, "num_hdv"),
        ({"num_hdvs": -1}, "num_hdvs"),
        ({"num_hdvs": 3.5}, "num_hdvs"),
        ({"style_mix": (0.5, 0.5, 0.5)}, "style_mix"),
        ({"style_mix": (0.5, 0.5)}, "style_mix"),
        ({"style_mix": (1.2, -0.2, 0.0)}, r"style_mix\[1\]"),
        ({"a_min": 1.0}, "a_min"),
        ({"a_max": -1.0}, "a_max"),
        ({"step_length": 1.0}, "step_length"),
        ({"step_length": float("inf")}, "step_length"),
        ({"time_limit": 0.0}, "time_limit"),
        ({"target_speed": 40.0}, "target_speed"),
        ({"ego_controller": "human"}, "ego_controller"),
        ({"num_hdvs": 120}, "num_hdvs=120 do not fit"),
        ({"hdv_spawn_length": 2000.0}, "hdv_spawn_length"),
        ({"reward": {"speeed": 1.0}}, "speeed"),
        ({"geometry": {"ramp_length": 500.0}}, "ramp_length"),
        ({"geometry": {"lanes": 4}}, "lanes"),
        ({"geometry": "merge"}, "geometry"),
    ],
)
def test_env_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MixedTrafficConfig.from_kwargs(**kwargs)


def test_env_config_defaults_and_counts():
    cfg = MixedTrafficConfig()
    assert cfg.num_hdvs == 34 and cfg.max_episode_steps == 200 and cfg.step_length == 0.2
    assert cfg.style_counts() == (12, 11, 11)  # 34/3 = 11.33 each; the remainder goes to the first
    assert MixedTrafficConfig(style_mix=(0.5, 0.5, 0.0)).style_counts() == (17, 17, 0)
    assert MixedTrafficConfig(num_hdvs=10, style_mix=(0.2, 0.3, 0.5)).style_counts() == (2, 3, 5)
    cfg = MixedTrafficConfig.from_kwargs(reward={"collision": 200.0}, target_speed=20.0)
    assert isinstance(cfg.reward, RewardConfig) and cfg.reward.collision == 200.0 and cfg.target_speed == 20.0
    assert math.isclose(cfg.geometry.road_length, 1500.0)
    cfg = MixedTrafficConfig.from_kwargs(geometry={"highway_out_length": 600.0})
    assert cfg.geometry == ScenarioGeometry(highway_out_length=600.0) and cfg.geometry.road_length == 1250.0


def test_geometry_rejects_bad_values():
    with pytest.raises(ValueError, match="ramp_length"):
        ScenarioGeometry(ramp_length=500.0)
    with pytest.raises(ValueError, match="speed_limit"):
        ScenarioGeometry(speed_limit=0.0)


def test_scenario_cache_dir_override_and_reuse(tmp_path, monkeypatch):
    from envs.scenario import CACHE_ENV_VAR, build_scenario, cache_dir

    monkeypatch.setenv(CACHE_ENV_VAR, str(tmp_path))
    assert cache_dir() == tmp_path
    files = build_scenario()
    assert files.net_file.parent.parent == tmp_path and files.net_file.exists() and files.route_file.exists()
    net = files.net_file.read_text()
    assert 'id="merge_0"' in net and 'allow="custom1"' in net  # the acceleration lane, AV only
    assert '<connection from="merge" to="hw_out" fromLane="0"' not in net  # it ends
    mtime = files.net_file.stat().st_mtime_ns
    again = build_scenario()
    assert again.net_file == files.net_file and again.net_file.stat().st_mtime_ns == mtime  # cached
    assert files.road_x("merge", 10.0) == 410.0 and files.road_x("ramp", 0.0) == 150.0
    other = build_scenario(ScenarioGeometry(highway_out_length=600.0))
    assert other.net_file != files.net_file  # keyed by content
