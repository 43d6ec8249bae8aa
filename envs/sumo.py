"""The single adapter between the environments and SUMO (the only module importing libsumo).

libsumo runs SUMO inside the Python process, about 15× faster than TraCI over a socket, but it
holds ONE simulation per process: a second ``start`` silently replaces the first, so two
environments in one process (e.g. in a ``DummyVecEnv``) would corrupt each other without any
error. :class:`SumoSimulation` therefore tracks which instance owns the process. Creating one
claims nothing (environments are cheap to build and Gymnasium's checker may build several);
:meth:`SumoSimulation.load` claims the process when it starts SUMO. If another instance of the
same process was running, its simulation is stopped first and every later call on it raises
:class:`SumoProcessBusyError`, whose message points to ``SubprocVecEnv``: the last ``reset()``
owns the simulation and an env whose simulation was taken can never read another env's
vehicles. The claim is released by :meth:`SumoSimulation.close` (or when the instance is
garbage collected) and is ignored in a forked child process, which starts its own simulation.

Crashes of the interpreter known for libsumo are avoided here: no neighbour/leader query is
made on a vehicle before it is on the road (``getNeighbors`` on a pending vehicle segfaults;
only setters such as the speed factor are applied to pending vehicles), lane indices are passed
as Python ``int`` (numpy integers are rejected), and every call after :meth:`SumoSimulation.close` raises
instead of reaching libsumo.

Importing this module never fails; :func:`import_libsumo` raises :class:`SumoNotInstalledError`
with installation instructions when SUMO is missing.
"""

from __future__ import annotations

import os
import shutil
import weakref
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

INSTALL_HINT = (
    "SUMO is required for the traffic environments: `pip install eclipse-sumo libsumo` "
    "(the pip wheels need no SUMO_HOME), or install SUMO >= 1.20 and set SUMO_HOME."
)

# TraCI variable ids (libsumo.constants); kept here so that importing needs no SUMO.
VAR_LANE_ID = 0x51
VAR_LANEPOSITION = 0x56
VAR_SPEED = 0x40
CMD_GET_VEHICLE_VARIABLE = 0xA4
#: Variables subscribed for every vehicle (the fewer, the faster each step).
VEHICLE_VARS = (VAR_LANE_ID, VAR_LANEPOSITION, VAR_SPEED)

_libsumo: ModuleType | None = None
# (pid, weak reference to the live simulation) of the simulation owning this process.
_owner: tuple[int, weakref.ref] | None = None


class SumoNotInstalledError(ImportError):
    """SUMO (libsumo / eclipse-sumo) is not installed."""


class SumoProcessBusyError(RuntimeError):
    """A second live SUMO simulation was requested in a process that already runs one."""


def import_libsumo() -> ModuleType:
    """Import and return ``libsumo``, or raise :class:`SumoNotInstalledError` saying how to install it."""
    global _libsumo
    if _libsumo is None:
        try:
            import libsumo
        except ImportError as exc:  # pragma: no cover - exercised only without SUMO
            raise SumoNotInstalledError(INSTALL_HINT) from exc
        _libsumo = libsumo
    return _libsumo


def _sumo_bin_dir() -> Path | None:
    try:
        import sumo  # the eclipse-sumo wheel
    except ImportError:
        sumo = None
    if sumo is not None:
        folder = Path(sumo.__file__).parent / "bin"
        if folder.is_dir():
            return folder
    home = os.environ.get("SUMO_HOME")
    if home and Path(home, "bin").is_dir():
        return Path(home, "bin")
    return None


def netconvert_binary() -> str:
    """Path of ``netconvert`` (eclipse-sumo wheel, ``$SUMO_HOME/bin`` or ``PATH``)."""
    folder = _sumo_bin_dir()
    for candidate in ([str(folder / "netconvert")] if folder else []) + [shutil.which("netconvert") or ""]:
        if candidate and os.access(candidate, os.X_OK):
            return candidate
    raise SumoNotInstalledError("netconvert not found. " + INSTALL_HINT)


BUSY_HINT = (
    "libsumo runs one simulation per process, and another SUMO environment of this process "
    "started its simulation with reset() after this one did: this env's simulation was stopped "
    "so that it can never read the other env's vehicles. Call reset() here to start a new episode "
    "(it stops the other env's simulation in turn), close the other env first, or run several "
    "envs in separate processes with stable_baselines3.common.vec_env.SubprocVecEnv (e.g. "
    "make_vec_env(..., vec_env_cls=SubprocVecEnv))."
)


def process_owner() -> SumoSimulation | None:
    """The simulation that runs SUMO in this process, or ``None`` (nothing claimed here)."""
    if _owner is None or _owner[0] != os.getpid():
        return None
    return _owner[1]()


class SumoSimulation:
    """One libsumo simulation of a network, restarted per episode with :meth:`load`.

    Creating an instance starts nothing and claims nothing; the first :meth:`load` starts SUMO
    and makes this instance the process's owner (stopping the simulation of a previous owner,
    which then raises :class:`SumoProcessBusyError` until it is loaded again).

    :param net_file: SUMO network.
    :param route_file: route file with vehicle types and routes.
    :param step_length: simulation step [s].
    :param extra_args: further ``sumo`` command-line options.
    """

    def __init__(
        self, net_file: str | Path, route_file: str | Path, step_length: float, extra_args: Sequence[str] = ()
    ) -> None:
        self.libsumo = import_libsumo()
        self.net_file, self.route_file = str(net_file), str(route_file)
        self.step_length = float(step_length)
        self.extra_args = list(extra_args)
        self._running = False
        self._closed = False
        self._taken = False  # another instance's load() stopped this simulation

    # -- lifecycle -----------------------------------------------------------------------------
    def _args(self, seed: int) -> list[str]:
        return [
            "-n", self.net_file, "-r", self.route_file,
            "--step-length", repr(self.step_length),
            "--seed", str(int(seed)),
            "--collision.action", "warn",  # collisions are read and handled by the env
            "--collision.check-junctions", "true",
            "--collision.mingap-factor", "0",  # a collision is a physical overlap
            "--time-to-teleport", "-1",  # never teleport (it hides jams and crashes)
            "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
            "--xml-validation", "never",
            *self.extra_args,
        ]

    def load(self, seed: int) -> None:
        """(Re)start the simulation at time 0 with SUMO's random seed ``seed``.

        Claims the process: a simulation another instance runs here is stopped first (that
        instance raises :class:`SumoProcessBusyError` from then on, until its own ``load``).
        """
        global _owner
        self._check_open()
        if self._running:
            self.libsumo.load(self._args(seed))
            return
        previous = process_owner()
        if previous is not None and previous is not self:
            previous._release(taken=True)
        # A weak reference: an instance that was garbage collected frees the process too.
        _owner = (os.getpid(), weakref.ref(self))
        self.libsumo.start(["sumo", *self._args(seed)])
        self._running, self._taken = True, False

    def _release(self, taken: bool) -> None:
        """Stop this instance's simulation and give up the process."""
        global _owner
        if self._running:
            self._running = False
            try:
                self.libsumo.close()
            except Exception:  # noqa: BLE001 - closing a dead connection is not an error
                pass
        self._taken = taken
        if process_owner() is self:
            _owner = None

    def clear(self, known_ids: Sequence[str] = (), context_owner: str | None = None, radius: float = 0.0) -> None:
        """Remove every vehicle (on the road and pending) without reloading; time keeps running.

        :param known_ids: ids that may be pending insertion (removed too, so that they can be re-added).
        :param context_owner: vehicle whose context subscription (of ``radius``) is dropped first
            (stepping with a subscription of a removed vehicle raises).
        """
        self._check_running()
        veh = self.libsumo.vehicle
        on_road = veh.getIDList()
        if context_owner is not None and context_owner in on_road:
            veh.unsubscribeContext(context_owner, CMD_GET_VEHICLE_VARIABLE, float(radius))
        for vid in on_road:
            veh.remove(vid)
        gone = set(on_road)
        for vid in known_ids:
            if vid not in gone:
                try:
                    veh.remove(vid)
                except self.libsumo.TraCIException:
                    pass  # not in the simulation at all
        self.libsumo.simulation.clearPending()

    @property
    def running(self) -> bool:
        """Whether this instance's simulation is started and still owns the process."""
        return self._running

    @property
    def taken(self) -> bool:
        """Whether another instance's :meth:`load` stopped this simulation (until this one loads again)."""
        return self._taken

    def close(self) -> None:
        """Stop the simulation and release the process (idempotent; never touches another owner's simulation)."""
        if self._closed:
            return
        self._closed = True
        self._release(taken=False)

    @property
    def closed(self) -> bool:
        return self._closed

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this SUMO simulation is closed; create a new environment")

    def _check_running(self) -> None:
        if not self._running:
            self._check_open()
            if self._taken:
                raise SumoProcessBusyError(BUSY_HINT)
            raise RuntimeError("the SUMO simulation is not started; call reset() first")

    # -- stepping and reading --------------------------------------------------------------------
    def step(self) -> None:
        """Advance the simulation by one step."""
        self._check_running()
        self.libsumo.simulationStep()

    @property
    def time(self) -> float:
        self._check_running()
        return float(self.libsumo.simulation.getTime())

    def departed_ids(self) -> tuple[str, ...]:
        self._check_running()
        return self.libsumo.simulation.getDepartedIDList()

    def arrived_ids(self) -> tuple[str, ...]:
        self._check_running()
        return self.libsumo.simulation.getArrivedIDList()

    def colliding_ids(self) -> tuple[str, ...]:
        self._check_running()
        return self.libsumo.simulation.getCollidingVehiclesIDList()

    def pending_ids(self) -> tuple[str, ...]:
        self._check_running()
        return self.libsumo.simulation.getPendingVehicles()

    def vehicle_ids(self) -> tuple[str, ...]:
        self._check_running()
        return self.libsumo.vehicle.getIDList()

    def subscribe_context(self, vehicle_id: str, radius: float) -> None:
        """Subscribe to :data:`VEHICLE_VARS` of every vehicle within ``radius`` metres of ``vehicle_id``.

        Must be called when ``vehicle_id`` is on the road (not pending).
        """
        self._check_running()
        self.libsumo.vehicle.subscribeContext(vehicle_id, CMD_GET_VEHICLE_VARIABLE, float(radius), VEHICLE_VARS)

    def context_results(self, vehicle_id: str) -> dict[str, dict[int, Any]]:
        """``{vehicle id: {variable id: value}}`` around ``vehicle_id`` (itself included); {} once it left."""
        self._check_running()
        return self.libsumo.vehicle.getContextSubscriptionResults(vehicle_id)

    def lane_positions(self) -> list[tuple[str, str, float]]:
        """``(vehicle id, lane id, lane position)`` of every vehicle on the road (slow; for drawing)."""
        self._check_running()
        veh = self.libsumo.vehicle
        return [(vid, veh.getLaneID(vid), veh.getLanePosition(vid)) for vid in veh.getIDList()]

    def acceleration(self, vehicle_id: str) -> float:
        """Acceleration of ``vehicle_id`` during the last step [m/s²]."""
        self._check_running()
        return float(self.libsumo.vehicle.getAcceleration(vehicle_id))

    def min_gap(self, vehicle_id: str) -> float:
        """Standstill gap ``minGap`` of ``vehicle_id``'s type [m]."""
        self._check_running()
        return float(self.libsumo.vehicle.getMinGap(vehicle_id))

    def leader(self, vehicle_id: str, distance: float) -> tuple[str, float] | None:
        """``(leader id, gap − minGap [m])`` within ``distance`` on the vehicle's lanes, else ``None``.

        As in TraCI, the returned distance excludes the follower's ``minGap``.
        """
        self._check_running()
        res = self.libsumo.vehicle.getLeader(vehicle_id, float(distance))
        if res is None or not res[0]:
            return None
        return res[0], float(res[1])

    # -- control -------------------------------------------------------------------------------
    def add_vehicle(
        self, vehicle_id: str, route_id: str, type_id: str, depart_pos: str, depart_lane: str, depart_speed: str
    ) -> None:
        """Insert a vehicle at the next step (``depart*`` are SUMO depart attribute strings)."""
        self._check_running()
        self.libsumo.vehicle.add(
            vehicle_id, route_id, typeID=type_id, departPos=depart_pos,
            departLane=depart_lane, departSpeed=depart_speed,
        )

    def try_add_vehicle(
        self, vehicle_id: str, route_id: str, type_id: str, depart_pos: str, depart_lane: str, depart_speed: str
    ) -> bool:
        """:meth:`add_vehicle`, returning ``False`` instead of raising if SUMO refuses (e.g. id in use)."""
        try:
            self.add_vehicle(vehicle_id, route_id, type_id, depart_pos, depart_lane, depart_speed)
        except self.libsumo.TraCIException:
            return False
        return True

    def set_speed_factor(self, vehicle_id: str, factor: float) -> None:
        """Desired speed of ``vehicle_id`` = ``factor`` × the lane speed limit (works on pending vehicles)."""
        self._check_running()
        self.libsumo.vehicle.setSpeedFactor(vehicle_id, float(factor))

    def remove(self, vehicle_id: str) -> None:
        self._check_running()
        self.libsumo.vehicle.remove(vehicle_id)

    def set_driver(self, vehicle_id: str, params: Mapping[str, float]) -> None:
        """Set one vehicle's car-following and lane-change parameters (SUMO vType attribute names:
        ``accel``, ``decel``, ``tau``, ``minGap``, ``speedFactor`` and LC2013's ``lc*``)."""
        self._check_running()
        v = self.libsumo.vehicle
        setters = {"accel": v.setAccel, "decel": v.setDecel, "tau": v.setTau, "minGap": v.setMinGap,
                   "speedFactor": v.setSpeedFactor}
        for key, value in params.items():
            if key in setters:
                setters[key](vehicle_id, float(value))
            elif key.startswith("lc"):
                v.setParameter(vehicle_id, f"laneChangeModel.{key}", str(float(value)))
            else:
                raise ValueError(f"unknown driver parameter {key!r}")

    def set_external_control(self, vehicle_id: str) -> None:
        """Hand all speed and lane decisions of ``vehicle_id`` to the caller.

        Speed mode 32: no safe-speed, acceleration or deceleration limit (the env enforces its
        own bounds); lane-change mode 0: no autonomous lane change and no safety check on
        commanded ones (an unsafe lane change can collide).
        """
        self._check_running()
        self.libsumo.vehicle.setSpeedMode(vehicle_id, 32)
        self.libsumo.vehicle.setLaneChangeMode(vehicle_id, 0)

    def set_sumo_control(self, vehicle_id: str) -> None:
        """Let SUMO's own car-following and lane-change models drive ``vehicle_id``."""
        self._check_running()
        self.libsumo.vehicle.setSpeed(vehicle_id, -1.0)
        self.libsumo.vehicle.setSpeedMode(vehicle_id, 31)
        self.libsumo.vehicle.setLaneChangeMode(vehicle_id, 1621)

    def set_speed(self, vehicle_id: str, speed: float) -> None:
        """Speed [m/s] the vehicle will have after the next step (external control)."""
        self._check_running()
        self.libsumo.vehicle.setSpeed(vehicle_id, float(speed))

    def change_lane(self, vehicle_id: str, lane_index: int, duration: float) -> None:
        """Request a change to ``lane_index`` of the current edge, executed at the next step."""
        self._check_running()
        self.libsumo.vehicle.changeLane(vehicle_id, int(lane_index), float(duration))

    def __del__(self) -> None:  # pragma: no cover - best effort at interpreter shutdown
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
