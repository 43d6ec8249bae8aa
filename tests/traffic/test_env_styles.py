"""HDV driving styles of MixedTraffic-v0: vType table, desired-speed variation, warm-up, lane sorting."""

import copy
import math

import numpy as np
import pytest

import envs  # noqa: F401  (registers MixedTraffic-v0)
from envs.mdp import STYLES
from envs.mixed_traffic import AV_ID, MixedTrafficConfig
from envs.scenario import (
    STYLE_SPEED_VARIATION,
    STYLE_VTYPES,
    ScenarioGeometry,
    SpeedVariation,
    route_source,
    speed_fluctuation_step,
)

DT = 0.2


# ---------------------------------------------------------------------------------------------
# pure parts (no SUMO)
# ---------------------------------------------------------------------------------------------
def test_style_table_is_ordered_and_written_to_the_route_file():
    c, n, a = (STYLE_VTYPES[s] for s in STYLES)
    # a conservative driver keeps more headway, accelerates less and drives slower than a neutral
    # one, which does so more than an aggressive one
    assert c["tau"] > n["tau"] > a["tau"] >= DT
    assert c["minGap"] > n["minGap"] > a["minGap"]
    assert c["accel"] < n["accel"] < a["accel"]
    assert c["speedFactor"] < n["speedFactor"] < a["speedFactor"]
    assert c["lcSpeedGain"] < n["lcSpeedGain"] < a["lcSpeedGain"]
    assert c["lcCooperative"] > n["lcCooperative"] > a["lcCooperative"]
    # desired speeds [m/s] at the 30 m/s limit: 22.5, 28.5, 33.6
    assert [round(STYLE_VTYPES[s]["speedFactor"] * 30.0, 1) for s in STYLES] == [22.5, 28.5, 33.6]
    text = route_source(ScenarioGeometry(), 35.0)
    assert 'id="conservative"' in text and 'tau="2"' in text and 'speedFactor="0.75"' in text
    assert 'id="aggressive"' in text and 'tau="0.6"' in text and 'speedDev="0"' in text
    assert "fluctuation" not in text  # env-side parameters are not SUMO attributes


def test_speed_variation_values_and_validation():
    v = STYLE_SPEED_VARIATION["aggressive"]
    assert (v.spread, v.fluctuation, v.correlation_time, v.update_period) == (0.03, 0.04, 3.0, 1.0)
    assert v.autocorrelation == pytest.approx(math.exp(-1.0 / 3.0))  # 0.71653
    assert [STYLE_SPEED_VARIATION[s].fluctuation for s in STYLES] == [0.01, 0.02, 0.04]
    with pytest.raises(ValueError, match="spread"):
        SpeedVariation(spread=-0.1, fluctuation=0.01)
    with pytest.raises(ValueError, match="fluctuation"):
        SpeedVariation(spread=0.01, fluctuation=0.3)
    with pytest.raises(ValueError, match="correlation_time"):
        SpeedVariation(spread=0.01, fluctuation=0.01, correlation_time=0.0)
    with pytest.raises(ValueError, match="update_period"):
        SpeedVariation(spread=0.01, fluctuation=0.01, update_period=True)


def test_speed_fluctuation_step_by_hand():
    eps = np.array([0.01, -0.02, 0.0, 0.03])
    rho = np.array([0.5, 0.5, 1.0, 0.0])
    sigma = np.array([0.02, 0.02, 0.04, 0.01])
    noise = np.array([1.0, -10.0, 3.0, 0.5])
    out = speed_fluctuation_step(eps, rho, sigma, noise)
    # 0.5*0.01 + sqrt(0.75)*0.02*1 = 0.0223205; second clipped at -2σ = -0.04;
    # ρ = 1 keeps ε; ρ = 0 draws afresh: 0.01 * 0.5
    np.testing.assert_allclose(out, [0.005 + math.sqrt(0.75) * 0.02, -0.04, 0.0, 0.005], atol=1e-12)


def test_warmup_config_validation():
    assert MixedTrafficConfig().hdv_warmup == 2.0
    for bad in (-1.0, True, "5", 601.0, float("nan")):
        with pytest.raises(ValueError, match="hdv_warmup"):
            MixedTrafficConfig(hdv_warmup=bad)


# ---------------------------------------------------------------------------------------------
# in SUMO
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("warmup, steps", [(0.0, 0), (5.0, 25), (1.0, 5)])
def test_warmup_runs_before_the_av_enters(make_env, warmup, steps):
    u = make_env(hdv_warmup=warmup).unwrapped
    _, info = u.reset(seed=3)
    # warm-up steps, then one step that inserts the AV; the episode clock starts after them
    assert u.sim.time == pytest.approx((steps + 1) * DT)
    assert info["time"] == 0.0 and 15.0 <= info["av_speed"] <= 20.0
    assert AV_ID in u.sim.vehicle_ids()


def test_desired_speeds_follow_the_styles_and_fluctuate_every_second(make_env):
    u = make_env().unwrapped
    u.reset(seed=5)
    lib = u.sim.libsumo
    base = np.array([STYLE_VTYPES[STYLES[u._styles[v]]]["speedFactor"] for v in u._hdv_ids])
    sigma = np.array([STYLE_SPEED_VARIATION[STYLES[u._styles[v]]].fluctuation for v in u._hdv_ids])
    ratio = u._factors / base
    # (1 ± 2·3 %) per driver × (1 ± 2σ) fluctuation
    assert np.all(ratio >= 0.94 * (1 - 2 * sigma) - 1e-12) and np.all(ratio <= 1.06 * (1 + 2 * sigma) + 1e-12)
    on_road = set(u.sim.vehicle_ids())
    for i, vid in enumerate(u._hdv_ids):
        if vid in on_road:
            assert lib.vehicle.getSpeedFactor(vid) == pytest.approx(u._factors[i])
    # 10 warm-up steps + 1 insertion step: the clock is at 11, the next update (every 5 steps) at 15
    assert u._hdv_clock == 11
    before, eps = u._factors.copy(), u._fluct.copy()
    for _ in range(3):
        u.step(np.zeros(2, dtype=np.float32))
    np.testing.assert_array_equal(u._factors, before)
    rng = copy.deepcopy(u.np_random)  # the update draws its 34 normals from np_random, nothing else does
    u.step(np.zeros(2, dtype=np.float32))
    rho = np.full(len(eps), math.exp(-1.0 / 3.0))
    expected = speed_fluctuation_step(eps, rho, sigma, rng.standard_normal(len(eps)))
    np.testing.assert_allclose(u._fluct, expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(u._factors, before / (1 + eps) * (1 + expected), rtol=1e-12)
    assert (u._factors != before).sum() > len(eps) // 2


def test_styles_start_sorted_by_lane(make_env):
    """Keep-right start: the conservative HDVs' mean lane is right of the aggressive ones'."""
    u = make_env(hdv_warmup=0.0).unwrapped
    means = np.zeros((5, 3))
    for seed in range(5):
        u.reset(seed=seed)
        lib = u.sim.libsumo  # the simulation exists from the first reset on
        lanes = {s: [] for s in range(3)}
        for vid in u.sim.vehicle_ids():
            if vid in u._styles:
                edge_shift = 1 if lib.vehicle.getRoadID(vid) == "merge" else 0
                lanes[u._styles[vid]].append(lib.vehicle.getLaneIndex(vid) - edge_shift)
        means[seed] = [np.mean(lanes[s]) for s in range(3)]
    assert np.all(means[:, 0] < means[:, 2])
    assert means[:, 0].mean() < means[:, 1].mean() < means[:, 2].mean()


def test_aggressive_drivers_vary_their_speed_more(make_env):
    """The per-style temporal signature: acceleration spread grows from conservative to aggressive."""
    u = make_env().unwrapped
    u.reset(seed=2, options={"ego_controller": "sumo"})
    lib = u.sim.libsumo
    acc = {s: [] for s in range(3)}
    for _ in range(100):
        _, _, terminated, truncated, _ = u.step(np.zeros(2, dtype=np.float32))
        for vid in u.sim.vehicle_ids():
            if vid in u._styles:
                acc[u._styles[vid]].append(lib.vehicle.getAcceleration(vid))
        if terminated or truncated:
            break
    spread = [float(np.std(acc[s])) for s in range(3)]
    assert spread[0] < spread[1] < spread[2], spread
