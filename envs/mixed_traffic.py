"""``MixedTraffic-v0``: one autonomous vehicle merging into mixed traffic, simulated by SUMO."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.mdp import (
    GAP_CAP,
    OBS_HIGH,
    OBS_LOW,
    OBS_NAMES,
    REWARD_TERMS,
    SLOT_FEATURES,
    SLOT_NAMES,
    STYLES,
    RewardConfig,
    _check_number,
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
    target_speed_reward,
    weighted_reward,
)
from envs.scenario import (
    AV_TYPE,
    MERGE_EDGE,
    RAMP_EDGE,
    ROUTE_FROM_MERGE,
    ROUTE_FROM_OUT,
    ROUTE_HIGHWAY,
    ROUTE_RAMP,
    STYLE_COLORS,
    STYLE_SPEED_VARIATION,
    STYLE_VTYPES,
    ScenarioFiles,
    ScenarioGeometry,
    build_scenario,
    speed_fluctuation_step,
)

if TYPE_CHECKING:
    from envs.sumo import SumoSimulation

__all__ = [
    "STYLES", "SLOT_NAMES", "SLOT_FEATURES", "OBS_NAMES", "REWARD_TERMS",
    "RewardConfig", "MixedTrafficConfig", "MixedTrafficEnv", "AV_ID", "VEHICLE_LENGTH",
]

#: SUMO id of the autonomous vehicle.
AV_ID = "av"
#: Length of every vehicle [m] (SUMO lane positions are front bumpers).
VEHICLE_LENGTH = 5.0
EGO_CONTROLLERS = ("agent", "sumo")
#: HDVs start at least this far apart on a lane [m], from this road position on [m].
SPAWN_MIN_SPACING = 25.0
SPAWN_START = 10.0
#: Lane sorting of the start state (keep-right traffic): HDV i gets the lane rank of
#: ``style_i + SPAWN_LANE_MIXING · N(0, 1)`` (style 0 = conservative ... 2 = aggressive) among
#: the HDVs, each lane receiving a third of them. With 1.2, about 63 % of the conservative
#: drivers start in the right lane (8 % in the left one) and 62 % of the aggressive ones in the
#: left lane; with 0 the lanes would be fully sorted by style, with a large value mixed at
#: random. Without this sorting every lane holds slow drivers and the faster ones queue behind
#: them at the same speed, which on a keep-right motorway is the exception rather than the rule.
SPAWN_LANE_MIXING = 1.2
#: The context subscription around the AV reaches V + this margin [m] (Euclidean range; covers
#: the ramp's lateral offset and its slightly shorter geometry).
CONTEXT_MARGIN = 30.0


@dataclass(frozen=True)
class MixedTrafficConfig:
    """Configuration of :class:`MixedTrafficEnv` (every field is a constructor keyword).

    :param num_hdvs: number of human-driven vehicles (paper: 34).
    :param style_mix: fractions of conservative, neutral, aggressive HDVs (sum 1); the counts
        are the largest-remainder rounding of ``num_hdvs × style_mix``.
    :param a_min: lowest acceleration action [m/s²].
    :param a_max: highest acceleration action [m/s²].
    :param target_speed: v* of the target-speed reward [m/s].
    :param max_speed: the AV's speed is clipped to ``[0, max_speed]`` [m/s].
    :param step_length: simulation and decision step [s].
    :param time_limit: episode length before truncation [s] (``time_limit / step_length`` steps).
    :param observation_range: V: leaders / followers and densities are observed within
        ``±V`` metres [m] (paper: 30).
    :param zeta_cap: the lane distance ζ is capped at (and normalised by) this length [m].
    :param hdv_spawn_length: HDVs start spread over the first ``hdv_spawn_length`` metres of the
        highway [m].
    :param hdv_warmup: the HDVs drive alone for this long before the AV enters and the episode
        starts [s] (rounded to whole steps), so that the transient of their simultaneous
        insertion is over; 0 disables it.
    :param ego_controller: ``"agent"`` (the action drives the AV) or ``"sumo"`` (SUMO's own
        car-following and lane-change models drive it; the action is ignored and the performed
        one is reported in ``info["applied_action"]``).
    :param geometry: network dimensions (a :class:`~envs.scenario.ScenarioGeometry` or a mapping of its fields).
    :param reward: reward weights (a :class:`RewardConfig` or a mapping of its fields).
    """

    num_hdvs: int = 34
    style_mix: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)
    a_min: float = -4.5
    a_max: float = 3.0
    target_speed: float = 25.0
    max_speed: float = 35.0
    step_length: float = 0.2
    time_limit: float = 40.0
    observation_range: float = 30.0
    zeta_cap: float = 300.0
    hdv_spawn_length: float = 800.0
    hdv_warmup: float = 2.0
    ego_controller: str = "agent"
    geometry: ScenarioGeometry = field(default_factory=ScenarioGeometry)
    reward: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        name = "MixedTrafficConfig"
        if isinstance(self.num_hdvs, bool) or not isinstance(self.num_hdvs, (int, np.integer)) or not (
            0 <= self.num_hdvs <= 200
        ):
            raise ValueError(f"{name}.num_hdvs must be an int in [0, 200], got {self.num_hdvs!r}")
        mix = tuple(self.style_mix) if isinstance(self.style_mix, (tuple, list, np.ndarray)) else None
        if mix is None or len(mix) != len(STYLES):
            raise ValueError(f"{name}.style_mix must be {len(STYLES)} fractions {STYLES}, got {self.style_mix!r}")
        for i, frac in enumerate(mix):
            _check_number(name, f"style_mix[{i}]", frac)
        if abs(sum(mix) - 1.0) > 1e-6:
            raise ValueError(f"{name}.style_mix must sum to 1, got {self.style_mix!r} (sum {sum(mix)})")
        object.__setattr__(self, "style_mix", tuple(float(f) for f in mix))
        for key in ("a_max", "target_speed", "max_speed", "step_length", "time_limit",
                    "observation_range", "zeta_cap", "hdv_spawn_length"):
            _check_number(name, key, getattr(self, key), strict=True)
        if not isinstance(self.a_min, (int, float)) or not (math.isfinite(self.a_min) and self.a_min < 0):
            raise ValueError(f"{name}.a_min must be a finite negative number, got {self.a_min!r}")
        min_tau = min(params["tau"] for params in STYLE_VTYPES.values())
        if self.step_length > min_tau:
            raise ValueError(
                f"{name}.step_length must be <= {min_tau:g} s (the smallest HDV time headway), got {self.step_length!r}"
            )
        if isinstance(self.hdv_warmup, bool) or not (
            isinstance(self.hdv_warmup, (int, float)) and 0.0 <= self.hdv_warmup <= 600.0
        ):
            raise ValueError(f"{name}.hdv_warmup must be a number of seconds in [0, 600], got {self.hdv_warmup!r}")
        if self.time_limit < self.step_length:
            raise ValueError(f"{name}.time_limit must be >= step_length, got {self.time_limit!r}")
        if self.target_speed > self.max_speed:
            raise ValueError(f"{name}.target_speed ({self.target_speed}) must not exceed max_speed ({self.max_speed})")
        if self.ego_controller not in EGO_CONTROLLERS:
            raise ValueError(f"{name}.ego_controller must be one of {EGO_CONTROLLERS}, got {self.ego_controller!r}")
        if isinstance(self.geometry, Mapping):
            object.__setattr__(self, "geometry", ScenarioGeometry.from_dict(self.geometry))
        if not isinstance(self.geometry, ScenarioGeometry):
            raise ValueError(f"{name}.geometry must be a ScenarioGeometry, got {type(self.geometry).__name__}")
        if self.hdv_spawn_length > self.geometry.road_length - 10.0:
            raise ValueError(f"{name}.hdv_spawn_length must be shorter than the road, got {self.hdv_spawn_length!r}")
        per_lane = -(-self.num_hdvs // 3)
        if SPAWN_START + per_lane * SPAWN_MIN_SPACING > self.hdv_spawn_length:
            raise ValueError(
                f"{name}.num_hdvs={self.num_hdvs} do not fit on hdv_spawn_length={self.hdv_spawn_length} m "
                f"({per_lane} per lane, {SPAWN_MIN_SPACING:g} m apart)"
            )
        if isinstance(self.reward, Mapping):
            object.__setattr__(self, "reward", RewardConfig.from_dict(self.reward))
        if not isinstance(self.reward, RewardConfig):
            raise ValueError(f"{name}.reward must be a RewardConfig or a mapping, got {type(self.reward).__name__}")

    @classmethod
    def from_kwargs(cls, base: MixedTrafficConfig | None = None, **kwargs: Any) -> MixedTrafficConfig:
        """``base`` (default config) with ``kwargs`` replaced; an unknown key raises ``ValueError``."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise ValueError(f"unknown MixedTrafficEnv argument(s) {unknown}; valid: {sorted(known)}")
        if base is not None and not isinstance(base, MixedTrafficConfig):
            raise ValueError(f"config must be a MixedTrafficConfig, got {type(base).__name__}")
        return replace(base or cls(), **kwargs)

    @property
    def max_episode_steps(self) -> int:
        return int(round(self.time_limit / self.step_length))

    def style_counts(self) -> tuple[int, ...]:
        """Number of HDVs per style: largest-remainder rounding of ``num_hdvs × style_mix``."""
        raw = [self.num_hdvs * f for f in self.style_mix]
        counts = [int(math.floor(r)) for r in raw]
        order = sorted(range(len(raw)), key=lambda i: (counts[i] - raw[i], i))
        for i in order[: self.num_hdvs - sum(counts)]:
            counts[i] += 1
        return tuple(counts)


class _Vehicle(NamedTuple):
    x: float  # road position of the front bumper [m]
    lane: int  # lane index g
    speed: float  # [m/s]


class MixedTrafficEnv(gym.Env[np.ndarray, np.ndarray]):
    r"""One autonomous vehicle (AV) merges from an on-ramp into a 3-lane highway with 34 HDVs.

    The road (``envs.scenario``) is a 1.5 km three-lane highway; a 250 m on-ramp joins a 250 m
    acceleration lane at x = 400 m that ends at x = 650 m. Human-driven vehicles (HDVs) are
    SUMO vehicles of three driving styles, ``conservative`` / ``neutral`` / ``aggressive``
    (IDM car following and LC2013 lane changing with the parameters of
    ``envs.scenario.STYLE_VTYPES``: time headway 2.0 / 1.2 / 0.6 s, acceleration 1.0 / 2.0 /
    3.5 m/s², desired speed 0.75 / 0.95 / 1.12 × the 30 m/s limit, growing lane-change
    eagerness and assertiveness, decreasing cooperation). Each driver's desired speed has its
    own offset and fluctuates in time, by 1 / 2 / 4 % (``envs.scenario.STYLE_SPEED_VARIATION``),
    so that each style has a temporal signature. HDVs that reach the end of the road re-enter
    at its start, so the density holds. Paper: §2 and §4.1.

    **Action space**: ``Box([a_min, -1], [a_max, 1], (2,), float32)``:

    ===  ============  =====  ==========================================================================
    idx  action        unit   meaning
    ===  ============  =====  ==========================================================================
    0    acceleration  m/s²   in [a_min, a_max] = [-4.5, 3.0] by default
    1    lane change   —      ``< -1/3`` → -1 = change LEFT, ``> 1/3`` → +1 = change RIGHT, else 0 = keep
    ===  ============  =====  ==========================================================================

    Out-of-range values are clipped; a NaN / inf or wrongly shaped action raises ``ValueError``.
    The AV's speed after the step is ``clip(v + a · dt, 0, max_speed)``. A lane change is
    executed at once (SUMO lane-change mode 0: no safety check, so a change into an occupied
    gap collides) if the target lane exists on the AV's current edge; otherwise it is ignored.
    The merge is the left change from the acceleration lane to highway lane 0.

    **Observation space** (Eq. 1, 20 numbers, float32, normalised and clipped into the bounds):

    =====  ========  ========  ==============  ==========================================================
    idx    symbol    raw unit  scaled by       meaning
    =====  ========  ========  ==============  ==========================================================
    0      v         m/s       1/30            AV speed
    1      p         m         1/1500          AV position along the road from the highway entry
    2-7    Δv        m/s       1/30            speed of l_1, l_2, l_3, f_1, f_2, f_3 minus AV speed
    8-13   Δp        m         1/V = 1/30      position of the same vehicles minus AV position
    14-16  ρ_1..ρ_3  veh/km    1/133.3 (jam)   vehicles per km within ±V on the left, current, right lane
    17-19  ζ_1..ζ_3  m         1/300 (capped)  length of that lane still available ahead (end of the
                                               acceleration lane or of the road)
    =====  ========  ========  ==============  ==========================================================

    Lanes h = 1, 2, 3 are LEFT, CURRENT and RIGHT of the AV; ``l_h`` is the nearest vehicle
    ahead and ``f_h`` the nearest behind on lane h within V = 30 m. Sentinels (never NaN): an
    empty slot has Δv = 0 and Δp = +V for leaders (+1 scaled) / -V for followers (-1 scaled);
    an absent lane (left of lane 2, right of lane 0, lane -1 after the merge area) also has
    ρ = 0 and ζ = 0. On the ramp, the left lane is highway lane 0 (observed, not reachable).

    **Reward** (paper §2.2: r = Σ_α η_α R_α; weights in :class:`envs.mdp.RewardConfig`):

    =================  =========  ==========================================================================
    term               η default  R_α
    =================  =========  ==========================================================================
    speed              1.0        1 − ``|v − v*|`` / v*, v* = 25 m/s, in [-1, 1]
    leader_distance    1.0        −max(0, 1 − gap / (2 m + 1 s · v)) w.r.t. l_2, in [-1, 0]
    follower_distance  0.5        same w.r.t. f_2, with the follower's speed
    merge              10         once at the merge: 0.5 + 0.5 × unused fraction of the acceleration lane
    jerk               0.5        −(j / j_max)², j = Δa / dt of the performed acceleration,
                                  j_max = (a_max − a_min) / dt
    lane_change        0.5        −1 per executed lane change other than the merge
    collision          100        −1 on a collision
    =================  =========  ==========================================================================

    ``info["reward_terms"]`` holds the weighted terms (they sum to the reward) and
    ``info["reward_terms_raw"]`` the R_α.

    **Start state**: all randomness comes from ``np_random``. The HDVs (style counts from ``style_mix``,
    shuffled) are spread uniformly over the first 800 m of the three highway lanes at least
    25 m apart, a third of them per lane, sorted keep-right style with some mixing (about 63 %
    of the conservative drivers start in the right lane and 62 % of the aggressive ones in the
    left lane, see ``SPAWN_LANE_MIXING``). Each has a desired speed of its style's factor ×
    (1 + per-driver offset, 3 % std) × (1 + fluctuation) × 30 m/s and is inserted front to back
    at the largest safe speed up to it. The HDVs then drive alone for ``hdv_warmup`` = 2 s (10
    simulation steps), so that the insertion transient (vehicles inserted below their desired
    speed accelerate, those inserted too close drop back) is over; only then does the AV enter
    the ramp, 5–25 m after its start at 15–20 m/s, and the episode (time 0) begin. (A longer
    warm-up moves the HDVs further downstream of the AV, which then meets fewer of them.)
    ``reset(seed=...)`` restarts SUMO (``load``, SUMO seed drawn from ``np_random``); ``reset()``
    without a seed removes and re-inserts all vehicles in the running simulation (≈ 4 ms instead
    of ≈ 12 ms). Both give the same trajectories: the scenario never uses SUMO's own random
    numbers (IDM has no noise term; the speed fluctuation is drawn from ``np_random``), so the
    same seed gives a bit-identical episode.

    **Episode end**:

    * terminated: collision of the AV (SUMO collision detection: overlap, junctions checked,
      no teleporting), the AV running into the end of the acceleration lane (a collision too,
      ``info["collision_type"] == "lane_end"``), or the AV leaving the road at its end;
    * truncated: after ``time_limit`` = 40 s (200 steps of ``step_length`` = 0.2 s).

    **Info** (every ``reset`` and ``step``): ``slots`` (the style-inference contract: ``ids``, ``styles``, ``features`` (6, 7) with
    :data:`SLOT_FEATURES`, ``present``), ``applied_action`` (performed acceleration and lane
    change in action units, float32 (2,)), ``reward_terms``, ``reward_terms_raw``, ``jerk``
    [m/s³], ``collision``, ``collision_type``, ``lane_change`` (executed, -1 left / +1 right),
    ``merge_done``, ``left_network``, ``av_speed``, ``av_x``, ``av_lane``, ``time``.

    Slot features: ``dp``, ``dv`` as in the observation but in m and m/s; ``accel`` [m/s²];
    ``speed`` [m/s]; ``lane_offset`` = occupant lane − AV lane (+1 = left, -1 = right);
    ``gap_to_leader`` = bumper gap to its own leader [m] (100 when none within 100 m);
    ``lane_density`` = ρ of its lane [veh/km]. Empty slot: zeros, id ``""``, style -1.

    ## Arguments
    ``gym.make("MixedTraffic-v0", render_mode=None, **kwargs)`` with the fields of
    :class:`MixedTrafficConfig` as keywords (``reward`` may be a dict), or ``config=``.
    ``render_mode="rgb_array"`` draws a top-down frame with numpy (no display needed).
    Constructing the env starts nothing (spaces are available at once); SUMO starts at the
    first ``reset()`` and ``close()`` stops it. libsumo holds one simulation per process, owned
    by the env that called ``reset()`` last: an env whose simulation another env's ``reset()``
    took raises :class:`envs.sumo.SumoProcessBusyError` at its next ``step()`` (its own
    ``reset()`` takes the simulation back). Use ``SubprocVecEnv`` for several envs at once, e.g.
    ``make_vec_env("envs:MixedTraffic-v0", n_envs=4, vec_env_cls=SubprocVecEnv)`` (the
    ``envs:`` prefix imports the package, and so registers the id, in every worker).

    Control of the AV can be handed to SUMO for an episode with
    ``reset(options={"ego_controller": "sumo"})`` or at any step with
    :meth:`set_ego_controller` (data collection reads the performed action in
    ``info["applied_action"]``).
    """

    # process_exclusive: one live instance per process (libsumo). ua2c-zoo reads it and refuses a
    # dummy vec env that would hold two (n_envs > 1, or an evaluation env): pass --vec-env subproc.
    metadata = {"render_modes": ["rgb_array"], "render_fps": 5, "process_exclusive": True}

    def __init__(self, render_mode: str | None = None, config: MixedTrafficConfig | None = None, **kwargs: Any):
        super().__init__()
        self.config = MixedTrafficConfig.from_kwargs(config, **kwargs)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.config.step_length))}
        cfg = self.config
        self.action_space = spaces.Box(
            low=np.array([cfg.a_min, -1.0], dtype=np.float32),
            high=np.array([cfg.a_max, 1.0], dtype=np.float32),
            dtype=np.float32,
        )
        self.observation_space = spaces.Box(low=OBS_LOW.copy(), high=OBS_HIGH.copy(), dtype=np.float32)
        from envs.sumo import import_libsumo

        import_libsumo()  # raises SumoNotInstalledError saying how to install SUMO
        # Built by the first reset(): constructing the env starts nothing and claims nothing.
        self.scenario: ScenarioFiles | None = None
        self.sim: SumoSimulation | None = None
        self._closed = False
        g = cfg.geometry
        # edge -> (road offset [m], lane index shift to g); SUMO lane id -> (offset, g, edge)
        self._edges = {
            "hw_in": (0.0, 0), RAMP_EDGE: (g.ramp_start, -1), MERGE_EDGE: (g.merge_start, -1),
            "hw_out": (g.merge_end, 0),
        }
        self._edge_lanes = {"hw_in": 3, RAMP_EDGE: 1, MERGE_EDGE: 4, "hw_out": 3}
        self._lanes_map = {
            f"{edge}_{i}": (off, i + shift, edge)
            for edge, (off, shift) in self._edges.items()
            for i in range(self._edge_lanes[edge])
        }
        self._min_gaps = tuple(float(STYLE_VTYPES[style]["minGap"]) for style in STYLES)
        self._av_subscribed = False
        self._context_radius = cfg.observation_range + CONTEXT_MARGIN
        self._hdv_ids = tuple(f"hdv_{i:02d}" for i in range(cfg.num_hdvs))
        self._styles: dict[str, int] = {}
        self._ego_controller = cfg.ego_controller
        self._needs_reset = True
        self._ids: list[str] = []
        self._xs: list[float] = []
        self._gs: list[int] = []
        self._speeds: list[float] = []
        self._av: _Vehicle | None = None

    # ------------------------------------------------------------------------------------------
    # public API
    # ------------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        controller = options.pop("ego_controller", self.config.ego_controller)
        if options:
            raise ValueError(f"unknown reset option(s) {sorted(options)}; valid: ['ego_controller']")
        if controller not in EGO_CONTROLLERS:
            raise ValueError(f"options['ego_controller'] must be one of {EGO_CONTROLLERS}, got {controller!r}")
        self._ego_controller = controller
        sumo_seed = int(self.np_random.integers(0, 2**31 - 1))
        sim = self._simulation()
        if seed is not None or not sim.running:
            sim.load(sumo_seed)  # claims the process (see envs.sumo)
        else:  # ~10x faster than a reload, same dynamics (SUMO's own RNG is never used)
            self.sim.clear((*self._hdv_ids, AV_ID), AV_ID if self._av_subscribed else None, self._context_radius)
        self._av_subscribed = False
        self._populate()
        for _ in range(int(round(self.config.hdv_warmup / self.config.step_length))):
            self.sim.step()  # HDVs only: the AV is added afterwards
            self._after_sim_step()
        av_pos, av_speed = self._av_start
        self.sim.add_vehicle(AV_ID, ROUTE_RAMP, AV_TYPE, f"{av_pos:.2f}", "0", f"{av_speed:.2f}")
        for _ in range(50):  # the AV is inserted at the first step; never touch it before
            self.sim.step()
            if AV_ID in self.sim.departed_ids():
                # Context subscription: the vehicles around the AV in one call per step.
                self.sim.subscribe_context(AV_ID, self._context_radius)
                self._av_subscribed = True
            self._after_sim_step()
            if self._av_subscribed:
                break
        else:
            raise RuntimeError("the autonomous vehicle could not be inserted into the simulation")
        self._apply_controller()
        self._step_count = 0
        self._prev_accel = 0.0
        self._merge_done = False
        self._needs_reset = False
        self._read_state()
        obs, slots = self._observe()
        self._last_obs = obs
        info = self._base_info(slots)
        info.update(
            applied_action=np.zeros(2, dtype=np.float32),
            reward_terms=dict.fromkeys(REWARD_TERMS, 0.0),
            reward_terms_raw=dict.fromkeys(REWARD_TERMS, 0.0),
            jerk=0.0, collision=False, collision_type="", lane_change=0, left_network=False,
        )
        return obs, info

    def step(self, action: np.ndarray):
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (and after an episode ended)")
        accel_cmd, lc_cmd = self._validate_action(action)
        prev = self._av
        assert prev is not None
        lane_end_crash = self._apply_action(prev, accel_cmd, lc_cmd)
        self._simulate()
        self._read_state()
        terminated, truncated, left, collision_type = self._episode_end(lane_end_crash)
        av = self._av if self._av is not None else prev
        obs, slots = self._observe() if self._av is not None else (self._last_obs, self._empty_slots())
        raw, extras = self._reward_terms(prev, av, slots, collision_type != "", left)
        reward, weighted = weighted_reward(raw, self.config.reward)
        self._last_obs = obs
        self._needs_reset = terminated or truncated
        info = self._base_info(slots)
        info.update(
            applied_action=np.array(
                [min(max(extras["accel"], self.config.a_min), self.config.a_max), extras["lane_change"]],
                dtype=np.float32,
            ),
            reward_terms=weighted, reward_terms_raw=raw, jerk=extras["jerk"],
            collision=collision_type != "", collision_type=collision_type,
            lane_change=extras["lane_change"], left_network=left,
        )
        return obs, reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode; use render_mode='rgb_array'")
            return None
        if self.sim is None:
            raise RuntimeError("call reset() before render()")
        from envs.rendering import draw_frame

        av = self._av
        vehicles = []
        for vid, lane_id, pos in self.sim.lane_positions():
            lane = self._lanes_map.get(lane_id)
            if lane is not None and vid in self._styles:
                vehicles.append((lane[0] + pos, lane[1], STYLE_COLORS[STYLES[self._styles[vid]]]))
        return draw_frame(self.config.geometry, av.x if av else 0.0, av.lane if av else 0, vehicles)

    def close(self) -> None:
        """Stop SUMO and release the process (harmless before any reset and when repeated)."""
        self._closed = True
        sim = getattr(self, "sim", None)
        if sim is not None:
            sim.close()
        self._needs_reset = True
        super().close()

    def _simulation(self) -> SumoSimulation:
        """The env's :class:`~envs.sumo.SumoSimulation`, created (scenario files included) on first use."""
        if self._closed:
            raise RuntimeError("this environment is closed; create a new one")
        if self.sim is None:
            from envs.sumo import SumoSimulation

            self.scenario = build_scenario(self.config.geometry, self.config.max_speed)
            self.sim = SumoSimulation(self.scenario.net_file, self.scenario.route_file, self.config.step_length)
        return self.sim

    def hdv_styles(self) -> dict[str, int]:
        """Every HDV id currently in the simulation → its style label (index into ``STYLES``)."""
        if self.sim is None or not self.sim.running or not self._styles:
            return {}
        return {vid: self._styles[vid] for vid in self.sim.vehicle_ids() if vid in self._styles}

    def set_ego_controller(self, controller: str) -> None:
        """Who drives the AV from the next step: ``"agent"`` (the action) or ``"sumo"``."""
        if controller not in EGO_CONTROLLERS:
            raise ValueError(f"controller must be one of {EGO_CONTROLLERS}, got {controller!r}")
        self._ego_controller = controller
        if not self._needs_reset:
            self._apply_controller()

    def set_ego_driver_style(self, style: str) -> None:
        """Give SUMO's driver model of the AV the parameters of an HDV style (``STYLES``) until the
        next reset; it matters while ``ego_controller == "sumo"`` (human-like offline data)."""
        if style not in STYLES:
            raise ValueError(f"style must be one of {STYLES}, got {style!r}")
        if self._needs_reset:
            raise RuntimeError("call reset() before set_ego_driver_style()")
        self.sim.set_driver(AV_ID, STYLE_VTYPES[style])

    @property
    def ego_controller(self) -> str:
        return self._ego_controller

    # ------------------------------------------------------------------------------------------
    # template-method steps (override in subclasses to change one stage)
    # ------------------------------------------------------------------------------------------
    def _validate_action(self, action: Any) -> tuple[float, float]:
        try:
            arr = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"action must be a numeric array of shape (2,), got {action!r}") from exc
        if arr.shape != (2,):
            raise ValueError(f"action must have shape (2,) [acceleration, lane change], got shape {arr.shape}")
        a0, a1 = float(arr[0]), float(arr[1])
        if not (math.isfinite(a0) and math.isfinite(a1)):
            raise ValueError(f"action must be finite, got {[a0, a1]}")
        cfg = self.config
        return min(max(a0, cfg.a_min), cfg.a_max), min(max(a1, -1.0), 1.0)

    def _apply_action(self, av: _Vehicle, accel: float, lane_change_value: float) -> bool:
        """Command speed and lane change; return whether the AV runs into the acceleration-lane end."""
        if self._ego_controller == "sumo":
            return False
        dt = self.config.step_length
        speed = min(max(av.speed + accel * dt, 0.0), self.config.max_speed)
        self.sim.set_speed(AV_ID, speed)
        lane_end_crash = av.lane == -1 and speed * dt > self.config.geometry.merge_end - av.x + 1e-6
        lc = lane_change_from_action(lane_change_value)
        if lc != 0:
            target = av.lane - lc
            edge = self._av_edge
            sumo_lane = target - self._edges[edge][1]
            if (
                edge != RAMP_EDGE  # the ramp has one lane and no neighbour on its edge
                and 0 <= sumo_lane < self._edge_lanes[edge]
                and lane_exists(target, av.x, self.config.geometry.merge_end)
            ):
                self.sim.change_lane(AV_ID, sumo_lane, dt)
        return lane_end_crash

    def _simulate(self) -> None:
        self.sim.step()
        self._after_sim_step()
        self._step_count += 1

    def _episode_end(self, lane_end_crash: bool) -> tuple[bool, bool, bool, str]:
        """``(terminated, truncated, left_network, collision_type)``."""
        collision_type = ""
        if AV_ID in self._colliding:
            collision_type = "vehicle"
        elif lane_end_crash:
            collision_type = "lane_end"
        left = self._av is None
        terminated = bool(collision_type) or left
        truncated = not terminated and self._step_count >= self.config.max_episode_steps
        return terminated, truncated, left, collision_type

    def _reward_terms(
        self, prev: _Vehicle, av: _Vehicle, slots: dict[str, Any], collided: bool, left: bool
    ) -> tuple[dict[str, float], dict[str, Any]]:
        cfg, rc = self.config, self.config.reward
        dt = cfg.step_length
        accel = (av.speed - prev.speed) / dt
        lane_change = min(max(prev.lane - av.lane, -1), 1)  # g grows to the left; action -1 = left
        merged_now = not self._merge_done and prev.lane == -1 and av.lane >= 0
        self._merge_done = self._merge_done or merged_now
        r_jerk, jerk = jerk_penalty(accel, self._prev_accel, dt, cfg.a_min, cfg.a_max)
        self._prev_accel = accel
        feats, present = slots["features"], slots["present"]
        lead_gap = feats[1, 0] - VEHICLE_LENGTH if present[1] else None
        follow_gap = -feats[4, 0] - VEHICLE_LENGTH if present[4] else None
        raw = {
            "speed": target_speed_reward(av.speed, cfg.target_speed),
            "leader_distance": safety_distance_penalty(lead_gap, av.speed, rc.safe_time_headway, rc.safe_min_gap),
            "follower_distance": safety_distance_penalty(
                follow_gap, float(feats[4, 3]), rc.safe_time_headway, rc.safe_min_gap
            ),
            "merge": merge_reward(merged_now, cfg.geometry.merge_end - av.x, cfg.geometry.accel_lane_length),
            "jerk": r_jerk,
            "lane_change": lane_change_penalty(lane_change, merged_now),
            "collision": collision_penalty(collided),
        }
        return raw, {"accel": accel, "lane_change": lane_change, "jerk": jerk}

    # ------------------------------------------------------------------------------------------
    # simulation bookkeeping
    # ------------------------------------------------------------------------------------------
    def _populate(self) -> None:
        """Insert the HDVs (styles, desired speeds, positions from ``np_random``); draw the AV's start."""
        cfg, rng = self.config, self.np_random
        n = cfg.num_hdvs
        labels = np.repeat(np.arange(len(STYLES)), cfg.style_counts())
        rng.shuffle(labels)
        self._styles = {vid: int(s) for vid, s in zip(self._hdv_ids, labels, strict=True)}
        self._hdv_index = {vid: i for i, vid in enumerate(self._hdv_ids)}
        # Desired speed factor of HDV i: speedFactor × (1 + δ_i) × (1 + ε_i(t)) (envs.scenario.SpeedVariation).
        var = [STYLE_SPEED_VARIATION[STYLES[s]] for s in labels]
        spread = np.array([v.spread for v in var])
        sigma = np.array([v.fluctuation for v in var])
        dt = cfg.step_length
        self._fluct_sigma = sigma
        self._fluct_rho = np.array([v.autocorrelation for v in var])
        period = np.array([max(1, int(round(v.update_period / dt))) for v in var], dtype=np.int64)
        # (update period in steps, indices and ids of the HDVs with that period); usually one group
        self._fluct_groups = [
            (int(k), idx, [self._hdv_ids[i] for i in idx.tolist()])
            for k in np.unique(period)
            for idx in (np.flatnonzero(period == k),)
        ]
        delta = np.clip(spread * rng.standard_normal(n), -2.0 * spread, 2.0 * spread)
        self._base_factors = np.array([STYLE_VTYPES[STYLES[s]]["speedFactor"] for s in labels]) * (1.0 + delta)
        self._fluct = np.clip(sigma * rng.standard_normal(n), -2.0 * sigma, 2.0 * sigma)  # stationary start
        self._factors = self._base_factors * (1.0 + self._fluct)
        self._hdv_clock = 0
        # Lanes: a third of the HDVs each, slow styles mostly right (see SPAWN_LANE_MIXING).
        rank = np.argsort(labels + SPAWN_LANE_MIXING * rng.standard_normal(n), kind="stable")
        lane_of = np.empty(n, dtype=np.int64)
        lane_of[rank] = np.arange(n) * 3 // n  # (n,) lane 0 (right) .. 2 (left) of each HDV
        # Spread HDVs over their lane, >= min_gap apart: sorted uniforms + i * min_gap.
        min_gap, start = SPAWN_MIN_SPACING, SPAWN_START
        placed: list[tuple[float, int, str]] = []
        for lane in range(3):
            ids = [vid for vid, ln in zip(self._hdv_ids, lane_of, strict=True) if ln == lane]
            free = cfg.hdv_spawn_length - start - len(ids) * min_gap
            xs = np.sort(rng.uniform(0.0, free, size=len(ids))) + start + np.arange(len(ids)) * min_gap
            placed += [(float(x), lane, vid) for x, vid in zip(xs, ids, strict=True)]
        placed.sort(reverse=True)  # front to back, so that every follower sees its leader
        g = cfg.geometry
        for x, lane, vid in placed:
            if x < g.merge_start:
                route, pos, sumo_lane = ROUTE_HIGHWAY, x, lane
            elif x < g.merge_end:
                route, pos, sumo_lane = ROUTE_FROM_MERGE, x - g.merge_start, lane + 1
            else:
                route, pos, sumo_lane = ROUTE_FROM_OUT, x - g.merge_end, lane
            self.sim.add_vehicle(vid, route, STYLES[self._styles[vid]], f"{pos:.2f}", str(sumo_lane), "max")
            self.sim.set_speed_factor(vid, float(self._factors[self._hdv_index[vid]]))
        self._av_start = (float(rng.uniform(5.0, 25.0)), float(rng.uniform(15.0, 20.0)))  # ramp position, speed
        self._reenter: list[str] = []

    def _update_speed_fluctuation(self) -> None:
        """Advance the desired-speed fluctuation ε of the HDVs due at this step (AR(1), ``np_random``)."""
        self._hdv_clock += 1
        for period, due, ids in self._fluct_groups:
            if self._hdv_clock % period == 0 and due.size:
                self._update_fluctuation_of(due, ids)

    def _update_fluctuation_of(self, due: np.ndarray, ids: list[str]) -> None:
        """Draw the next fluctuation of the HDVs ``due`` (indices; ``ids`` their ids) and set their factors."""
        eps = speed_fluctuation_step(
            self._fluct[due], self._fluct_rho[due], self._fluct_sigma[due], self.np_random.standard_normal(due.size)
        )
        self._fluct[due] = eps
        factors = self._base_factors[due] * (1.0 + eps)
        self._factors[due] = factors
        set_factor, waiting = self.sim.set_speed_factor, self._reenter
        for vid, factor in zip(ids, factors.tolist(), strict=True):
            if not waiting or vid not in waiting:  # waiting ones get their factor when re-added
                set_factor(vid, factor)

    def _after_sim_step(self) -> None:
        sim = self.sim
        self._colliding = sim.colliding_ids()
        for vid in self._colliding:  # HDV-HDV crashes: remove both; they re-enter
            if vid != AV_ID and vid in self._styles:
                sim.remove(vid)
                self._reenter.append(vid)
        pending, self._reenter = self._reenter, []
        for vid in pending + [v for v in sim.arrived_ids() if v in self._styles and v not in pending]:
            if sim.try_add_vehicle(vid, ROUTE_HIGHWAY, STYLES[self._styles[vid]], "base", "free", "max"):
                sim.set_speed_factor(vid, float(self._factors[self._hdv_index[vid]]))
            else:
                self._reenter.append(vid)  # not yet released by SUMO: retry next step
        self._update_speed_fluctuation()
        self._results = sim.context_results(AV_ID) if self._av_subscribed else {}

    def _read_state(self) -> None:
        """Convert the subscription results to road coordinates (x, lane g) in parallel lists."""
        lanes_map = self._lanes_map
        ids: list[str] = []
        xs: list[float] = []
        gs: list[int] = []
        speeds: list[float] = []
        av = None
        for vid, res in self._results.items():
            lane = lanes_map.get(res[0x51])
            if lane is None:  # not on the road (e.g. being inserted)
                continue
            if vid == AV_ID:
                av = _Vehicle(lane[0] + res[0x56], lane[1], res[0x40])
                self._av_edge = lane[2]
            else:
                ids.append(vid)
                xs.append(lane[0] + res[0x56])
                gs.append(lane[1])
                speeds.append(res[0x40])
        self._ids, self._xs, self._gs, self._speeds = ids, xs, gs, speeds
        self._av = av

    def _apply_controller(self) -> None:
        if self._ego_controller == "sumo":
            self.sim.set_sumo_control(AV_ID)
        else:
            self.sim.set_external_control(AV_ID)

    def _observe(self) -> tuple[np.ndarray, dict[str, Any]]:
        cfg = self.config
        g = cfg.geometry
        av = self._av
        assert av is not None
        ids, xs, gs, speeds = self._ids, self._xs, self._gs, self._speeds
        V = cfg.observation_range
        slot_idx, counts = find_slots(av.x, av.lane, xs, gs, V)
        exists = [lane_exists(av.lane + 1 - h, av.x, g.merge_end) for h in range(3)]
        density = [c / (2.0 * V / 1000.0) if e else 0.0 for c, e in zip(counts, exists, strict=True)]
        zeta = [lane_distance(av.lane + 1 - h, av.x, g.road_length, g.merge_end, cfg.zeta_cap) for h in range(3)]
        dv = [0.0] * 6
        dp = [V, V, V, -V, -V, -V]
        features = np.zeros((6, len(SLOT_FEATURES)), dtype=np.float32)
        styles = np.full(6, -1, dtype=np.int64)
        present = np.zeros(6, dtype=bool)
        slot_ids = [""] * 6
        for k, i in enumerate(slot_idx):
            if i < 0:
                continue
            x, lane, speed, vid = xs[i], gs[i], speeds[i], ids[i]
            leader = self.sim.leader(vid, GAP_CAP)
            if leader is None:
                gap = GAP_CAP
            else:
                style = self._styles.get(vid)
                gap = leader[1] + (self._min_gaps[style] if style is not None else self.sim.min_gap(vid))
            dv[k] = speed - av.speed
            dp[k] = x - av.x
            features[k] = (dp[k], dv[k], self.sim.acceleration(vid), speed, lane - av.lane,
                           min(gap, GAP_CAP), density[k % 3])
            styles[k] = self._styles.get(vid, -1)
            present[k] = True
            slot_ids[k] = vid
        obs = observation_vector(av.speed, av.x, g.road_length, dv, dp, density, zeta, V, cfg.zeta_cap)
        slots = {"ids": tuple(slot_ids), "styles": styles, "features": features, "present": present}
        return obs, slots

    @staticmethod
    def _empty_slots() -> dict[str, Any]:
        return {
            "ids": ("",) * 6,
            "styles": np.full(6, -1, dtype=np.int64),
            "features": np.zeros((6, len(SLOT_FEATURES)), dtype=np.float32),
            "present": np.zeros(6, dtype=bool),
        }

    def _base_info(self, slots: dict[str, Any]) -> dict[str, Any]:
        av = self._av
        return {
            "slots": slots,
            "merge_done": self._merge_done,
            "av_speed": av.speed if av else 0.0,
            "av_x": av.x if av else self.config.geometry.road_length,
            "av_lane": av.lane if av else 0,
            "time": self._step_count * self.config.step_length,
            "ego_controller": self._ego_controller,
        }
