"""Pure maths of the mixed-traffic POMDP (paper §2.2): slots, observation (Eq. 1), action, reward.

Nothing here touches SUMO: every function takes plain numbers / arrays and is unit-tested
against values computed by hand. :class:`envs.mixed_traffic.MixedTrafficEnv` wires them.

Conventions
-----------
* Road coordinate ``x`` [m]: position of a vehicle's front bumper along the highway, measured
  from the highway entry (the ramp is measured parallel to the road).
* Lane index ``g``: 0, 1, 2 = highway lanes from right to left; -1 = on-ramp / acceleration lane.
* Observed lanes ``h = 1, 2, 3`` (index 0, 1, 2) = LEFT (``g + 1``), CURRENT (``g``), RIGHT
  (``g - 1``) of the AV; slots ``l_1, l_2, l_3`` are the nearest vehicles ahead (``dp >= 0``) and
  ``f_1, f_2, f_3`` the nearest behind (``dp < 0``) within ``V`` metres, on those lanes.
* Lane-change action (paper §2.2): ``-1`` = change LEFT, ``0`` = keep, ``+1`` = change RIGHT.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

#: Driving-style labels; the label index is the position in this tuple.
STYLES = ("conservative", "neutral", "aggressive")
#: Observed slots; h = 1, 2, 3 are the LEFT, CURRENT and RIGHT lane relative to the AV (Eq. 1 order).
SLOT_NAMES = ("l_1", "l_2", "l_3", "f_1", "f_2", "f_3")
#: Per-slot features of ``info["slots"]["features"]`` (units: the table of :mod:`envs.style.sequences`).
SLOT_FEATURES = ("dp", "dv", "accel", "speed", "lane_offset", "gap_to_leader", "lane_density")
#: Number of observed lanes H.
NUM_OBSERVED_LANES = 3
#: Names of the 20 observation entries (Eq. 1 with H = 3).
OBS_NAMES = (
    ("v", "p")
    + tuple(f"dv_{s}" for s in SLOT_NAMES)
    + tuple(f"dp_{s}" for s in SLOT_NAMES)
    + tuple(f"rho_{h}" for h in (1, 2, 3))
    + tuple(f"zeta_{h}" for h in (1, 2, 3))
)
#: Speed scale of the observation [m/s]: v and Δv are divided by it.
SPEED_SCALE = 30.0
#: Jam density [veh/km] (one 5 m car + 2.5 m gap every 7.5 m); ρ is divided by it.
JAM_DENSITY = 1000.0 / 7.5
#: gap_to_leader of a slot occupant without a leader within this distance [m].
GAP_CAP = 100.0
#: Lower / upper bounds of the normalised observation (values are clipped into them).
OBS_LOW = np.array([0.0, -0.1] + [-1.5] * 6 + [-1.0] * 6 + [0.0] * 3 + [0.0] * 3, dtype=np.float32)
OBS_HIGH = np.array([1.5, 1.1] + [1.5] * 6 + [1.0] * 6 + [1.5] * 3 + [1.0] * 3, dtype=np.float32)
#: Thresholds mapping the continuous lane-change action to {-1, 0, +1}.
LANE_CHANGE_THRESHOLD = 1.0 / 3.0


def lane_change_from_action(value: float) -> int:
    """Map the continuous lane-change action to the paper's discrete ``a_lc ∈ {-1, 0, 1}``.

    :param value: action component in [-1, 1].
    :return: ``-1`` (left) if ``value < -1/3``, ``+1`` (right) if ``value > 1/3``, else ``0`` (keep).
    """
    if value < -LANE_CHANGE_THRESHOLD:
        return -1
    if value > LANE_CHANGE_THRESHOLD:
        return 1
    return 0


def target_lane_index(lane: int, lane_change: int) -> int:
    """Lane index ``g`` after ``lane_change`` (-1 left → ``g + 1``; +1 right → ``g - 1``)."""
    return lane - lane_change


def lane_exists(lane: int, x: float, merge_end: float, num_lanes: int = 3) -> bool:
    """Whether lane ``g`` exists at road position ``x``: highway lanes always, lane -1 before ``merge_end``."""
    if 0 <= lane < num_lanes:
        return True
    return lane == -1 and x < merge_end


def lane_distance(lane: int, x: float, road_length: float, merge_end: float, cap: float) -> float:
    """ζ: the length [m] of lane ``g`` still available ahead of ``x`` (0 for an absent lane), capped.

    :param lane: lane index ``g``.
    :param x: road position of the AV [m].
    :param road_length: end of the highway lanes [m].
    :param merge_end: end of the acceleration lane (lane -1) [m].
    :param cap: ζ is at most ``cap`` (the distance that matters for a decision) [m].
    """
    if not lane_exists(lane, x, merge_end):
        return 0.0
    end = merge_end if lane == -1 else road_length
    return float(min(max(end - x, 0.0), cap))


def find_slots(
    av_x: float, av_lane: int, xs: Sequence[float], lanes: Sequence[int], window: float
) -> tuple[list[int], list[int]]:
    """Nearest leader and follower on the LEFT, CURRENT and RIGHT lanes, and the window counts.

    :param av_x: road position of the AV [m].
    :param av_lane: lane index ``g`` of the AV.
    :param xs: road positions of the other vehicles (the AV excluded), length n.
    :param lanes: their lane indices ``g``, length n.
    :param window: V: observation half-range [m].
    :return: ``(slots, counts)``: ``slots`` (6,) = indices into ``xs`` for
        ``l_1, l_2, l_3, f_1, f_2, f_3`` (-1 = empty); ``counts`` (3,) = number of vehicles with
        ``|x - av_x| <= window`` on the left, current and right lane.
    """
    best = [math.inf] * 6
    slots = [-1] * 6
    counts = [0, 0, 0]
    for i, (x, lane) in enumerate(zip(xs, lanes, strict=True)):
        h = av_lane + 1 - lane  # left lane -> 0, current -> 1, right -> 2
        if h < 0 or h > 2:
            continue
        d = x - av_x
        if d >= 0.0:
            if d <= window:
                counts[h] += 1
                if d < best[h]:
                    best[h], slots[h] = d, i
        elif d >= -window:
            counts[h] += 1
            if -d < best[3 + h]:
                best[3 + h], slots[3 + h] = -d, i
    return slots, counts


def observation_vector(
    speed: float,
    x: float,
    road_length: float,
    dv: Sequence[float],
    dp: Sequence[float],
    density: Sequence[float],
    zeta: Sequence[float],
    window: float,
    zeta_cap: float,
) -> np.ndarray:
    """Eq. 1, normalised: ``[v, p, Δv(l_1..l_3, f_1..f_3), Δp(...), ρ_1..ρ_3, ζ_1..ζ_3]``.

    Scaling: ``v / 30``, ``p = x / road_length``, ``Δv / 30``, ``Δp / V``, ``ρ / 133.3 veh/km``,
    ``ζ / zeta_cap``; each entry is then clipped into ``[OBS_LOW, OBS_HIGH]``. Empty slots must
    be passed as ``Δv = 0`` and ``Δp = +V`` (leaders) / ``-V`` (followers); absent lanes as
    ``ρ = 0``, ``ζ = 0``.

    :param speed: AV speed [m/s].
    :param x: AV road position [m].
    :param road_length: highway length [m].
    :param dv: (6,) speed of the slot occupant minus AV speed [m/s].
    :param dp: (6,) position of the slot occupant minus AV position [m].
    :param density: (3,) vehicles per km in the window on the left, current, right lane.
    :param zeta: (3,) available lane distance [m].
    :param window: V [m].
    :param zeta_cap: ζ scale [m].
    :return: (20,) float32.
    """
    obs = np.array(
        [speed / SPEED_SCALE, x / road_length]
        + [float(d) / SPEED_SCALE for d in dv]
        + [float(d) / window for d in dp]
        + [float(r) / JAM_DENSITY for r in density]
        + [float(z) / zeta_cap for z in zeta],
        dtype=np.float32,
    )
    if obs.shape != (20,):
        raise ValueError(f"dv, dp need 6 entries and density, zeta 3; got an observation of shape {obs.shape}")
    np.maximum(obs, OBS_LOW, out=obs)  # (much cheaper than np.clip on 20 numbers)
    np.minimum(obs, OBS_HIGH, out=obs)
    return obs


# ----------------------------------------------------------------------------------------------
# Reward (paper §2.2: r_t = Σ_α η_α R_{t,α}, seven terms)
# ----------------------------------------------------------------------------------------------
REWARD_TERMS = ("speed", "leader_distance", "follower_distance", "merge", "jerk", "lane_change", "collision")


def dataclass_from_dict(cls: type, values: Mapping[str, Any]) -> Any:
    """Build the dataclass ``cls`` from a mapping; an unknown key raises ``ValueError`` naming it."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} key(s) {unknown}; valid keys: {sorted(known)}")
    return cls(**dict(values))


def _check_number(owner: str, name: str, value: Any, low: float = 0.0, strict: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ValueError(f"{owner}.{name} must be a number, got {value!r}")
    if not math.isfinite(float(value)) or float(value) < low or (strict and float(value) == low):
        cmp = ">" if strict else ">="
        raise ValueError(f"{owner}.{name} must be finite and {cmp} {low}, got {value!r}")


@dataclass(frozen=True)
class RewardConfig:
    """Weights η_α of the seven reward terms and the parameters of the safety distance.

    Every term ``R_α`` is dimensionless and bounded (the functions below, :func:`target_speed_reward` to
    :func:`collision_penalty`); the weights are
    non-negative, so penalties enter with their sign. With the defaults a random policy's
    per-step reward mixes speed (+), jerk, lane-change and distance terms of comparable size,
    while one collision (-100) outweighs a whole episode of speed reward.

    :param speed: η of the target-speed reward.
    :param leader_distance: η of the safety-distance penalty w.r.t. the leader in the AV's lane.
    :param follower_distance: η of the safety-distance penalty w.r.t. the follower in the AV's lane.
    :param merge: η of the proactive-merge-completion reward (paid once, at the merge).
    :param jerk: η of the jerk penalty.
    :param lane_change: η of the unnecessary-lane-change penalty.
    :param collision: η of the collision penalty.
    :param safe_time_headway: T in the safety distance ``d_safe = s_0 + T · v`` [s].
    :param safe_min_gap: s_0 in the safety distance [m].
    """

    speed: float = 1.0
    leader_distance: float = 1.0
    follower_distance: float = 0.5
    merge: float = 10.0
    jerk: float = 0.5
    lane_change: float = 0.5
    collision: float = 100.0
    safe_time_headway: float = 1.0
    safe_min_gap: float = 2.0

    def __post_init__(self) -> None:
        for f in fields(self):
            _check_number("RewardConfig", f.name, getattr(self, f.name), strict=f.name == "safe_time_headway")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> RewardConfig:
        """Build from a mapping; an unknown key raises ``ValueError`` naming it."""
        return dataclass_from_dict(cls, values)

    def weights(self) -> dict[str, float]:
        """``{term: η}`` in :data:`REWARD_TERMS` order."""
        return {name: float(getattr(self, name)) for name in REWARD_TERMS}


def target_speed_reward(speed: float, target_speed: float) -> float:
    """R_1 = 1 − ``|v − v*|`` / v*, clipped to [-1, 1]: 1 at the target speed, 0 at standstill."""
    return float(max(-1.0, 1.0 - abs(speed - target_speed) / target_speed))


def safety_distance_penalty(gap: float | None, speed: float, time_headway: float, min_gap: float) -> float:
    """R_2 / R_3 = −max(0, 1 − gap / d_safe), d_safe = s_0 + T · v; in [-1, 0].

    :param gap: bumper-to-bumper gap [m] (``None`` = no vehicle in the window → 0).
    :param speed: speed of the rear vehicle of the pair (AV for the leader, follower for the
        follower) [m/s].
    :param time_headway: T [s].
    :param min_gap: s_0 [m].
    """
    if gap is None:
        return 0.0
    d_safe = min_gap + time_headway * max(speed, 0.0)
    return float(-min(1.0, max(0.0, 1.0 - gap / d_safe)))


def merge_reward(merged_now: bool, remaining: float, accel_lane_length: float) -> float:
    """R_4: paid once when the AV reaches a highway lane: ``0.5 + 0.5 · ζ_acc / L_acc``.

    Half for completing the merge, half for doing it proactively (the unused fraction of the
    acceleration lane, ``remaining`` metres of ``accel_lane_length``); 0 on every other step.
    """
    if not merged_now:
        return 0.0
    return float(0.5 + 0.5 * min(max(remaining / accel_lane_length, 0.0), 1.0))


def jerk_penalty(accel: float, prev_accel: float, dt: float, a_min: float, a_max: float) -> tuple[float, float]:
    """R_5 = −(j / j_max)², j = (a_t − a_{t−1}) / dt, j_max = (a_max − a_min) / dt; in [-1, 0].

    :return: ``(R_5, j)`` with the jerk ``j`` [m/s³].
    """
    jerk = (accel - prev_accel) / dt
    j_max = (a_max - a_min) / dt
    return float(-min(1.0, (jerk / j_max) ** 2)), float(jerk)


def lane_change_penalty(executed: int, is_merge: bool) -> float:
    """R_6 = −1 for an executed lane change that is not the merge (discretionary changes cost)."""
    return -1.0 if executed != 0 and not is_merge else 0.0


def collision_penalty(collided: bool) -> float:
    """R_7 = −1 on the step of a collision."""
    return -1.0 if collided else 0.0


def weighted_reward(raw_terms: Mapping[str, float], config: RewardConfig) -> tuple[float, dict[str, float]]:
    """r_t = Σ_α η_α R_{t,α} (paper §2.2).

    :param raw_terms: ``{term: R_α}`` for every name of :data:`REWARD_TERMS`.
    :param config: weights.
    :return: ``(r_t, {term: η_α R_α})``.
    """
    weighted = {name: float(getattr(config, name)) * float(raw_terms[name]) for name in REWARD_TERMS}
    return float(sum(weighted.values())), weighted
