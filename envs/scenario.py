"""The on-ramp merge scenario of ``MixedTraffic-v0``, generated in code and cached.

The network is a straight three-lane highway with a one-lane on-ramp that joins an
acceleration lane running alongside the right-most highway lane::

                 x = 0            400             650                       1500
    lane 2   ====|================|===============|=========================|====>
    lane 1   ====|================|===============|=========================|====>
    lane 0   ====|================|===============|=========================|====>
    lane -1       \\___ ramp ______|_ accel. lane _|   (ends: merge before x = 650)
                x = 150

Edges (SUMO ids): ``hw_in`` (3 lanes), ``ramp`` (1 lane), ``merge`` (4 lanes, lane 0 is the
acceleration lane, which has no successor), ``hw_out`` (3 lanes). Internal junction links are
disabled, so every vehicle is always on one of these four edges, and the position along the road
is ``offset[edge] + lane position`` (:meth:`ScenarioFiles.road_x`). The ramp and the acceleration
lane only admit the autonomous vehicle (vClass ``custom1``); human-driven vehicles (HDVs) use the
highway lanes.

HDV driving styles are SUMO vehicle types (IDM car following, LC2013 lane changing) whose
parameters are in :data:`STYLE_VTYPES`; the per-driver spread and the fluctuation of their
desired speeds, applied by the environment, are in :data:`STYLE_SPEED_VARIATION`.

The files are built once with the ``netconvert`` binary of the ``eclipse-sumo`` wheel and cached
under :func:`cache_dir` (``$SB3_UA2C_CACHE``, else ``$XDG_CACHE_HOME/sb3-ua2c``, else
``~/.cache/sb3-ua2c``), keyed by a hash of their content, so several processes can share them.
"""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from envs.mdp import STYLES, dataclass_from_dict

#: Environment variable that overrides the cache directory of generated scenario files.
CACHE_ENV_VAR = "SB3_UA2C_CACHE"

#: SUMO edge ids, in driving order along the highway.
HIGHWAY_EDGES = ("hw_in", "merge", "hw_out")
RAMP_EDGE = "ramp"
MERGE_EDGE = "merge"
#: Route ids defined in the route file.
ROUTE_HIGHWAY = "r_hw"  # hw_in -> merge -> hw_out
ROUTE_FROM_MERGE = "r_merge"  # merge -> hw_out
ROUTE_FROM_OUT = "r_out"  # hw_out
ROUTE_RAMP = "r_ramp"  # ramp -> merge -> hw_out
AV_TYPE = "av"
AV_VCLASS = "custom1"

#: SUMO vehicle-type attributes of each HDV driving style (index = label in ``STYLES``).
#:
#: Car following is IDM (Treiber et al., 2000) with maximum acceleration ``accel`` [m/s²],
#: comfortable deceleration ``decel`` [m/s²], desired time headway ``tau`` [s] and standstill
#: gap ``minGap`` [m]; the desired speed is ``speedFactor`` × the 30 m/s speed limit. Lane
#: changing is LC2013 (Erdmann, 2014): ``lcSpeedGain`` (eagerness to change lane for speed),
#: ``lcKeepRight`` (eagerness to return to the right), ``lcAssertive`` (>1 accepts smaller gaps
#: in the target lane), ``lcCooperative`` (willingness to make room for others, in [0, 1]).
#:
#: ============== ======= ======= ====== ====== ============ ========= ========= ========== ==========
#: style          a_max   b       T      s_0    v0 / limit   speed     keep      assertive  cooperative
#:                [m/s²]  [m/s²]  [s]    [m]    (km/h)       gain      right
#: ============== ======= ======= ====== ====== ============ ========= ========= ========== ==========
#: conservative   1.0     1.8     2.0    4.0    0.75 (81)    0.2       2.0       0.5        1.0
#: neutral        2.0     3.0     1.2    2.5    0.95 (103)   1.0       1.0       1.0        0.5
#: aggressive     3.5     4.5     0.6    1.0    1.12 (121)   3.0       0.3       3.0        0.1
#: ============== ======= ======= ====== ====== ============ ========= ========= ========== ==========
#:
#: Conservative and neutral lie in the usual ranges of IDM drivers calibrated on motorway data
#: (a_max about 1-2 m/s², b 1.5-3 m/s², T 1-2 s, s_0 2-5 m; Treiber & Kesting, *Traffic Flow
#: Dynamics*, 2013, ch. 11): the conservative driver is a slow right-lane driver keeping the
#: recommended 2 s. The aggressive driver deliberately exceeds the comfortable values: a_max
#: 3.5 m/s² (0-100 km/h in about 8 s), firm braking at 4.5 m/s² (still below the 9 m/s²
#: emergency deceleration), tailgating at 0.6 s and 12 % above the limit. Desired speeds are
#: 6 m/s and 5 m/s apart, several times the spread within one style (see
#: :data:`STYLE_SPEED_VARIATION`), so a free-flowing driver's style shows in its speed and a
#: following driver's in its gap (2.0 s vs 1.2 s vs 0.6 s of headway).
#: SUMO's own random numbers are never used (``speedDev`` is 0; IDM has no noise term): the
#: per-driver spread and the desired-speed fluctuation come from the env's seeded generator.
STYLE_VTYPES: dict[str, dict[str, float]] = {
    "conservative": {
        "accel": 1.0, "decel": 1.8, "tau": 2.0, "minGap": 4.0, "speedFactor": 0.75,
        "lcSpeedGain": 0.2, "lcKeepRight": 2.0, "lcAssertive": 0.5, "lcCooperative": 1.0,
    },
    "neutral": {
        "accel": 2.0, "decel": 3.0, "tau": 1.2, "minGap": 2.5, "speedFactor": 0.95,
        "lcSpeedGain": 1.0, "lcKeepRight": 1.0, "lcAssertive": 1.0, "lcCooperative": 0.5,
    },
    "aggressive": {
        "accel": 3.5, "decel": 4.5, "tau": 0.6, "minGap": 1.0, "speedFactor": 1.12,
        "lcSpeedGain": 3.0, "lcKeepRight": 0.3, "lcAssertive": 3.0, "lcCooperative": 0.1,
    },
}


@dataclass(frozen=True)
class SpeedVariation:
    """How the desired speed of the HDVs of one style varies (drawn by the env, never by SUMO).

    Each HDV's speed factor is ``speedFactor × (1 + δ_i) × (1 + ε_i(t))``: ``δ_i`` is fixed per
    driver (drawn at reset, ``N(0, spread²)`` clipped to ``±2·spread``); ``ε_i(t)`` is an
    Ornstein-Uhlenbeck fluctuation of stationary standard deviation ``fluctuation`` and
    correlation time ``correlation_time``, updated every ``update_period`` seconds (the
    discrete-time AR(1) ``ε ← ρ ε + sqrt(1 − ρ²) · fluctuation · ξ``, ``ρ = exp(−period / T)``)
    and clipped to ``±2·fluctuation``. IDM then follows the moving desired speed with the
    style's own acceleration and deceleration, which gives every style a temporal signature
    in speed and acceleration even in free flow (a calm driver holds its speed; an aggressive
    one keeps speeding up and braking, cf. the speed-variance findings on driving styles).

    :param spread: per-driver relative spread of the desired speed.
    :param fluctuation: stationary relative standard deviation of the fluctuation.
    :param correlation_time: correlation time ``T`` of the fluctuation [s].
    :param update_period: time between two updates of the fluctuation [s].
    """

    spread: float
    fluctuation: float
    correlation_time: float = 3.0
    update_period: float = 1.0

    def __post_init__(self) -> None:
        for name in ("spread", "fluctuation"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0.0 <= float(value) < 0.25):
                raise ValueError(f"SpeedVariation.{name} must be a number in [0, 0.25), got {value!r}")
        for name in ("correlation_time", "update_period"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0.0 < float(value) < 1e4):
                raise ValueError(f"SpeedVariation.{name} must be a positive number, got {value!r}")

    @property
    def autocorrelation(self) -> float:
        """``ρ = exp(−update_period / correlation_time)`` of the AR(1) update."""
        return math.exp(-self.update_period / self.correlation_time)


def speed_fluctuation_step(
    eps: np.ndarray, rho: np.ndarray, sigma: np.ndarray, noise: np.ndarray
) -> np.ndarray:
    """One update of the desired-speed fluctuation (see :class:`SpeedVariation`).

    ``ε' = clip(ρ ε + sqrt(1 − ρ²) σ ξ, −2σ, 2σ)``: the exact discretisation of an
    Ornstein-Uhlenbeck process of stationary standard deviation σ, clipped at two σ.

    :param eps: (n,) current relative fluctuations ε.
    :param rho: (n,) autocorrelation ρ per update, in [0, 1].
    :param sigma: (n,) stationary standard deviations σ.
    :param noise: (n,) standard normal draws ξ.
    :return: (n,) the new fluctuations.
    """
    new = rho * eps + np.sqrt(1.0 - rho**2) * sigma * noise
    return np.clip(new, -2.0 * sigma, 2.0 * sigma)


#: Desired-speed variation of each style (relative to its ``speedFactor``): per-driver spread 3 %,
#: fluctuation 1 % / 2 % / 4 % (correlation time 3 s, updated every second).
STYLE_SPEED_VARIATION: dict[str, SpeedVariation] = {
    "conservative": SpeedVariation(spread=0.03, fluctuation=0.01),
    "neutral": SpeedVariation(spread=0.03, fluctuation=0.02),
    "aggressive": SpeedVariation(spread=0.03, fluctuation=0.04),
}
#: RGB colour of each style (also used by the renderer): blue, green, orange.
STYLE_COLORS: dict[str, tuple[int, int, int]] = {
    "conservative": (60, 120, 230),
    "neutral": (60, 180, 90),
    "aggressive": (245, 150, 30),
}
assert tuple(STYLE_VTYPES) == STYLES and tuple(STYLE_COLORS) == STYLES and tuple(STYLE_SPEED_VARIATION) == STYLES


@dataclass(frozen=True)
class ScenarioGeometry:
    """Lengths [m] and speed limit [m/s] of the merge network (defaults: a 1.5 km highway).

    :param highway_in_length: highway before the merge area (edge ``hw_in``).
    :param ramp_length: on-ramp (edge ``ramp``), ending where the acceleration lane starts.
    :param accel_lane_length: merge area with the acceleration lane (edge ``merge``).
    :param highway_out_length: highway after the merge area (edge ``hw_out``).
    :param speed_limit: speed limit of every lane.
    :param lane_width: lane width (only used for drawing and the SUMO geometry).
    """

    highway_in_length: float = 400.0
    ramp_length: float = 250.0
    accel_lane_length: float = 250.0
    highway_out_length: float = 850.0
    speed_limit: float = 30.0
    lane_width: float = 3.2

    def __post_init__(self) -> None:
        for name in ("highway_in_length", "ramp_length", "accel_lane_length", "highway_out_length",
                     "speed_limit", "lane_width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and 0.0 < float(value) < 1e5):
                raise ValueError(f"ScenarioGeometry.{name} must be a positive number, got {value!r}")
        if self.ramp_length > self.highway_in_length:
            raise ValueError(
                f"ScenarioGeometry.ramp_length ({self.ramp_length}) must not exceed "
                f"highway_in_length ({self.highway_in_length}): the ramp starts on the road"
            )

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> ScenarioGeometry:
        """Build from a mapping; an unknown key raises ``ValueError`` naming it."""
        return dataclass_from_dict(cls, values)

    @property
    def road_length(self) -> float:
        """Length of the highway from its entry to its end [m]."""
        return self.highway_in_length + self.accel_lane_length + self.highway_out_length

    @property
    def merge_start(self) -> float:
        """Road position where the acceleration lane begins [m]."""
        return self.highway_in_length

    @property
    def merge_end(self) -> float:
        """Road position where the acceleration lane ends [m]."""
        return self.highway_in_length + self.accel_lane_length

    @property
    def ramp_start(self) -> float:
        """Road position of the ramp's beginning (the ramp is measured parallel to the road) [m]."""
        return self.highway_in_length - self.ramp_length


@dataclass(frozen=True)
class ScenarioFiles:
    """Paths of a generated scenario and the road coordinates of its edges."""

    net_file: Path
    route_file: Path
    geometry: ScenarioGeometry
    edge_offsets: dict[str, float] = field(default_factory=dict)

    def road_x(self, edge: str, lane_position: float) -> float:
        """Position along the road [m] of a vehicle front at ``lane_position`` on ``edge``."""
        return self.edge_offsets[edge] + lane_position


def cache_dir() -> Path:
    """Directory of generated scenario files: ``$SB3_UA2C_CACHE``, else the user cache dir."""
    override = os.environ.get(CACHE_ENV_VAR)
    if override:
        return Path(override).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sb3-ua2c"


def _fmt(value: float) -> str:
    return f"{float(value):g}"


def network_sources(geometry: ScenarioGeometry) -> dict[str, str]:
    """Plain-XML node, edge and connection files of the network (input of netconvert).

    :param geometry: lengths and speed limit.
    :return: ``{"nod": ..., "edg": ..., "con": ...}`` XML texts.
    """
    g = geometry
    w = g.lane_width
    x_in, x_merge_end, x_end = g.merge_start, g.merge_end, g.road_length
    # The ramp approaches at a shallow angle from the right; its declared length is authoritative.
    ramp_x0 = x_in - 0.97 * g.ramp_length
    nod = (
        "<nodes>\n"
        f'  <node id="start" x="0" y="0" type="priority"/>\n'
        f'  <node id="merge_a" x="{_fmt(x_in)}" y="0" type="priority"/>\n'
        f'  <node id="merge_b" x="{_fmt(x_merge_end)}" y="0" type="priority"/>\n'
        f'  <node id="end" x="{_fmt(x_end)}" y="0" type="priority"/>\n'
        f'  <node id="ramp_start" x="{_fmt(ramp_x0)}" y="{_fmt(-6 * w)}" type="priority"/>\n'
        "</nodes>\n"
    )
    v = _fmt(g.speed_limit)
    edg = (
        "<edges>\n"
        f'  <edge id="hw_in" from="start" to="merge_a" numLanes="3" speed="{v}" '
        f'length="{_fmt(g.highway_in_length)}" width="{_fmt(w)}"/>\n'
        f'  <edge id="ramp" from="ramp_start" to="merge_a" numLanes="1" speed="{v}" '
        f'length="{_fmt(g.ramp_length)}" width="{_fmt(w)}">\n'
        f'    <lane index="0" allow="{AV_VCLASS}"/>\n'
        "  </edge>\n"
        f'  <edge id="merge" from="merge_a" to="merge_b" numLanes="4" speed="{v}" '
        f'length="{_fmt(g.accel_lane_length)}" width="{_fmt(w)}">\n'
        f'    <lane index="0" allow="{AV_VCLASS}"/>\n'
        "  </edge>\n"
        f'  <edge id="hw_out" from="merge_b" to="end" numLanes="3" speed="{v}" '
        f'length="{_fmt(g.highway_out_length)}" width="{_fmt(w)}"/>\n'
        "</edges>\n"
    )
    con = (
        "<connections>\n"
        '  <connection from="ramp" to="merge" fromLane="0" toLane="0"/>\n'
        + "".join(f'  <connection from="hw_in" to="merge" fromLane="{i}" toLane="{i + 1}"/>\n' for i in range(3))
        + "".join(f'  <connection from="merge" to="hw_out" fromLane="{i + 1}" toLane="{i}"/>\n' for i in range(3))
        + "</connections>\n"
    )
    return {"nod": nod, "edg": edg, "con": con}


def route_source(geometry: ScenarioGeometry, av_max_speed: float) -> str:
    """Route file text: the AV and HDV-style vehicle types and the four routes (no vehicles).

    :param geometry: used for the HDVs' maximum speed (``1.25 ×`` the speed limit).
    :param av_max_speed: maximum speed of the AV type [m/s] (the env clips its commands to it).
    """
    hdv_max = _fmt(1.25 * geometry.speed_limit)
    lines = ["<routes>"]
    for style, params in STYLE_VTYPES.items():
        attrs = " ".join(f'{k}="{_fmt(val)}"' for k, val in params.items())
        r, g_, b = STYLE_COLORS[style]
        lines.append(
            f'  <vType id="{style}" vClass="passenger" carFollowModel="IDM" laneChangeModel="LC2013" '
            f'length="5" maxSpeed="{hdv_max}" emergencyDecel="9" speedDev="0" {attrs} color="{r},{g_},{b}"/>'
        )
    lines.append(
        # Under the env's control the AV ignores these; when SUMO drives it (data collection) it
        # is a moderate IDM driver. IDM has no random term, so runs stay deterministic.
        f'  <vType id="{AV_TYPE}" vClass="{AV_VCLASS}" carFollowModel="IDM" laneChangeModel="LC2013" '
        f'length="5" minGap="2.5" accel="2.6" decel="4.5" emergencyDecel="9" tau="1" '
        f'maxSpeed="{_fmt(av_max_speed)}" speedFactor="1" speedDev="0" color="220,30,30"/>'
    )
    lines += [
        f'  <route id="{ROUTE_HIGHWAY}" edges="hw_in merge hw_out"/>',
        f'  <route id="{ROUTE_FROM_MERGE}" edges="merge hw_out"/>',
        f'  <route id="{ROUTE_FROM_OUT}" edges="hw_out"/>',
        f'  <route id="{ROUTE_RAMP}" edges="ramp merge hw_out"/>',
        "</routes>",
    ]
    return "\n".join(lines) + "\n"


def _atomic_write(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def build_scenario(
    geometry: ScenarioGeometry | None = None, av_max_speed: float = 35.0, directory: Path | None = None
) -> ScenarioFiles:
    """Generate (or reuse from the cache) the network and route files of the merge scenario.

    :param geometry: network dimensions; defaults to :class:`ScenarioGeometry()`.
    :param av_max_speed: maximum speed of the AV vehicle type [m/s].
    :param directory: where to cache the files; defaults to :func:`cache_dir`.
    :return: the file paths and the road offset of each edge.
    """
    from envs.sumo import netconvert_binary

    geometry = geometry or ScenarioGeometry()
    sources = network_sources(geometry)
    routes = route_source(geometry, av_max_speed)
    key = hashlib.sha256(("".join(sources.values()) + routes).encode()).hexdigest()[:16]
    folder = Path(directory) if directory is not None else cache_dir()
    folder = folder / f"merge-{key}"
    folder.mkdir(parents=True, exist_ok=True)
    net_file, route_file = folder / "merge.net.xml", folder / "merge.rou.xml"
    if not net_file.exists():
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            for ext, text in sources.items():
                Path(tmp, f"merge.{ext}.xml").write_text(text)
            out = Path(tmp, "merge.net.xml")
            cmd = [
                netconvert_binary(),
                "--node-files", str(Path(tmp, "merge.nod.xml")),
                "--edge-files", str(Path(tmp, "merge.edg.xml")),
                "--connection-files", str(Path(tmp, "merge.con.xml")),
                "--no-internal-links", "true", "--no-turnarounds", "true",
                "--xml-validation", "never", "--no-warnings", "true",
                "--output-file", str(out),
            ]
            proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if proc.returncode != 0 or not out.exists():
                raise RuntimeError(f"netconvert failed ({proc.returncode}): {proc.stderr.strip()}")
            os.replace(out, net_file)
    if not route_file.exists():
        _atomic_write(route_file, routes)
    offsets = {
        "hw_in": 0.0,
        RAMP_EDGE: geometry.ramp_start,
        MERGE_EDGE: geometry.merge_start,
        "hw_out": geometry.merge_end,
    }
    return ScenarioFiles(net_file=net_file, route_file=route_file, geometry=geometry, edge_offsets=offsets)
