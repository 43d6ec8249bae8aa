"""OGBench "play" and "navigate" datasets generated locally with OGBench's scripted oracles and procedure, seeded
(``docs/ogbench.md``), and their conversion to UA2C's offline episodes."""

from __future__ import annotations

import os
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from experiments.common.stats import numpy_global_seed
from sb3_ua2c.checks import check_int
from sb3_ua2c.offline import Episode

#: OGBench's published "play" settings (``data_gen_scripts/commands.sh``).
PLAY_EPISODE_STEPS = 1001
PLAY_NOISE = 0.1
PLAY_NOISE_SMOOTHING = 0.5

#: OGBench's "navigate" setting for ``pointmaze`` (``commands.sh``: Gaussian noise 0.5 on the oracle's direction).
NAVIGATE_NOISE = 0.5

MANIPSPACE_DOMAINS = ("cube", "scene", "puzzle")
#: Dataset types generated here, with the domains each covers (``antmaze``/``humanoidmaze`` need
#: OGBench's trained low-level experts, which the package does not ship).
GENERATED = {"play": MANIPSPACE_DOMAINS, "navigate": ("pointmaze",)}


@dataclass(frozen=True)
class TaskName:
    """The parts of an OGBench single-task name such as ``cube-single-play-singletask-task2-v0``."""

    dataset_name: str
    env_name: str
    dataset_type: str
    dataset_file: str

    @classmethod
    def parse(cls, dataset_name: str) -> TaskName:
        if not isinstance(dataset_name, str):
            raise TypeError(f"task must be an OGBench dataset name (str), got {type(dataset_name).__name__}")
        parts = dataset_name.split("-")
        if "singletask" not in parts or parts.index("singletask") < 2 or not parts[-1].startswith("v"):
            raise ValueError("task must be an OGBench single-task dataset name like "
                             f"'cube-single-play-singletask-task2-v0', got {dataset_name!r}")
        pos = parts.index("singletask")
        dataset_type = parts[pos - 1]
        if parts[0] not in GENERATED.get(dataset_type, ()):
            raise ValueError(f"task {dataset_name!r}: only these datasets can be generated here: "
                             + ", ".join(f"'{kind}' of {domains}" for kind, domains in GENERATED.items()))
        env_name = "-".join(parts[: pos - 1] + parts[-1:])
        dataset_file = "-".join(parts[:pos] + parts[-1:]) + ".npz"
        return cls(dataset_name, env_name, dataset_type, dataset_file)


def _make_oracles(env: Any, env_name: str, noise: float, noise_smoothing: float) -> dict[str, Any]:
    """The PlanOracles of ``generate_manipspace.py`` for the 'play' datasets, by subtask."""
    from ogbench.manipspace.oracles.plan.button_plan import ButtonPlanOracle
    from ogbench.manipspace.oracles.plan.cube_plan import CubePlanOracle
    from ogbench.manipspace.oracles.plan.drawer_plan import DrawerPlanOracle
    from ogbench.manipspace.oracles.plan.window_plan import WindowPlanOracle

    kw = {"env": env, "noise": noise, "noise_smoothing": noise_smoothing}
    if env_name.startswith("cube"):
        return {"cube": CubePlanOracle(**kw)}
    if env_name.startswith("scene"):
        return {"cube": CubePlanOracle(**kw), "button": ButtonPlanOracle(**kw),
                "drawer": DrawerPlanOracle(**kw), "window": WindowPlanOracle(**kw)}
    return {"button": ButtonPlanOracle(**kw, gripper_always_closed=True)}


def _stack_probability(env_name: str) -> float:
    """``p_stack`` of an episode, as in ``generate_manipspace.py`` (drawn from NumPy's global generator)."""
    for word, (low, high) in (("single", (0.0, 0.0)), ("double", (0.0, 0.25)), ("triple", (0.05, 0.35)),
                              ("quadruple", (0.1, 0.5)), ("octuple", (0.0, 0.35))):
        if word in env_name:
            return 0.0 if high == 0.0 else float(np.random.uniform(low, high))  # noqa: NPY002  (as OGBench draws it)
    return 0.5


def _scene_episode_healthy(qpos: np.ndarray) -> bool:
    """OGBench's health check of a ``scene`` episode: the cube stays visible unless in the drawer."""
    block = qpos[:, 14:17]
    too_far_right = (block[:, 1] >= 0.29).any()
    too_far_left = ((block[:, 1] <= -0.3) & ((block[:, 2] < 0.06) | (block[:, 2] > 0.08))).any()
    return not (too_far_right or too_far_left)


def _collect_episode(env: Any, oracles: dict[str, Any], env_name: str, seed: int | None) -> dict[str, list]:
    """One play episode (``generate_manipspace.py``'s inner loop), as lists of per-step rows."""
    ob, info = env.reset(seed=seed)
    p_stack = _stack_probability(env_name)
    agent = oracles[info["privileged/target_task"]]
    agent.reset(ob, info)
    rows: dict[str, list] = defaultdict(list)
    has_buttons = hasattr(env.unwrapped, "_cur_button_states")
    done = False
    while not done:
        action = np.clip(np.asarray(agent.select_action(ob, info)), -1, 1)
        next_ob, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        if agent.done:  # the oracle finished its plan: a new random target
            agent_ob, agent_info = env.unwrapped.set_new_target(p_stack=p_stack)
            agent = oracles[agent_info["privileged/target_task"]]
            agent.reset(agent_ob, agent_info)
        _append_step(rows, ob, action, done, info, has_buttons)
        ob = next_ob
    return rows


def _append_step(rows: dict[str, list], ob: Any, action: Any, done: bool, info: dict[str, Any],
                 buttons: bool = False) -> None:
    """One step of an episode into ``rows``, under the keys of OGBench's files."""
    for key, value in (("observations", ob), ("actions", action), ("terminals", done), ("qpos", info["prev_qpos"]),
                       ("qvel", info["prev_qvel"])):
        rows[key].append(value)
    if buttons:
        rows["button_states"].append(info["prev_button_states"])


def _maze_cells(maze_map: np.ndarray) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """Free cells of a maze and its "vertex" cells, from which ``generate_locomaze.py`` draws the goals."""
    free, vertex = [], []
    for i, j in zip(*np.nonzero(maze_map == 0), strict=True):
        free.append((int(i), int(j)))
        vertical = maze_map[i - 1, j] == 0 and maze_map[i + 1, j] == 0 and maze_map[i, j - 1] == 1 and maze_map[i, j + 1] == 1
        horizontal = maze_map[i, j - 1] == 0 and maze_map[i, j + 1] == 0 and maze_map[i - 1, j] == 1 and maze_map[i + 1, j] == 1
        if not (vertical or horizontal):
            vertex.append((int(i), int(j)))
    return free, vertex


def _collect_navigate_episode(env: Any, noise: float, seed: int | None) -> dict[str, list]:
    """One ``navigate`` episode of ``pointmaze``, as ``generate_locomaze.py`` collects it."""
    maze = env.unwrapped
    free, vertex = _maze_cells(maze.maze_map)
    init_ij = free[np.random.randint(len(free))]  # noqa: NPY002  (as OGBench draws it)
    goal_ij = vertex[np.random.randint(len(vertex))]  # noqa: NPY002
    ob, _ = env.reset(seed=seed, options={"task_info": {"init_ij": init_ij, "goal_ij": goal_ij}})
    rows: dict[str, list] = defaultdict(list)
    done = False
    while not done:
        subgoal_xy, _ = maze.get_oracle_subgoal(maze.get_xy(), maze.cur_goal_xy)
        direction = subgoal_xy - maze.get_xy()
        direction = direction / (np.linalg.norm(direction) + 1e-6)
        action = np.clip(direction + np.random.normal(0, noise, direction.shape), -1, 1)  # noqa: NPY002
        next_ob, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        if info["success"]:
            maze.set_goal(vertex[np.random.randint(len(vertex))])  # noqa: NPY002
        _append_step(rows, ob, action, done, info)
        ob = next_ob
    return rows


def _save_npz(path: Path, rows: dict[str, list]) -> None:
    """Write OGBench's npz layout (dtypes as ``generate_manipspace.py``) through a temporary file."""
    arrays = {key: np.asarray(values, dtype=bool if key == "terminals" else np.int64 if key == "button_states"
                              else np.float32) for key, values in rows.items()}
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")  # units may generate the same file at once
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def val_path(path: str | os.PathLike) -> Path:
    """The validation file OGBench reads next to ``path`` (``x.npz`` -> ``x-val.npz``)."""
    return Path(str(path).replace(".npz", "-val.npz"))


def generate_play_dataset(task: str, path: str | os.PathLike, n_episodes: int,
                          episode_steps: int = PLAY_EPISODE_STEPS, seed: int = 0, noise: float | None = None,
                          noise_smoothing: float = PLAY_NOISE_SMOOTHING) -> dict[str, Any]:
    """Generate the dataset of ``task``'s domain into ``path`` and :func:`val_path`; return its measurements."""
    import gymnasium as gym
    import ogbench.locomaze  # noqa: F401  (registers the environments)
    import ogbench.manipspace  # noqa: F401

    name = TaskName.parse(task)
    navigate = name.dataset_type == "navigate"
    if noise is None:
        noise = NAVIGATE_NOISE if navigate else PLAY_NOISE
    check_int("n_episodes", n_episodes)
    check_int("episode_steps", episode_steps, low=2)
    for label, value in (("noise", noise), ("noise_smoothing", noise_smoothing)):
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value < np.inf:
            raise ValueError(f"{label} must be a finite number >= 0, got {value!r}")
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"path must end with .npz (OGBench's format), got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = {} if navigate else {"mode": "data_collection"}
    env = gym.make(name.env_name, terminate_at_goal=False, max_episode_steps=episode_steps, **mode)
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        oracles = {} if navigate else _make_oracles(env, name.env_name, noise, noise_smoothing)
        splits: list[dict[str, list]] = [defaultdict(list), defaultdict(list)]
        with numpy_global_seed(seed):
            for i in range(n_episodes + n_episodes // 10):
                while True:
                    first = seed if i == 0 else None
                    rows = (_collect_navigate_episode(env, noise, first) if navigate
                            else _collect_episode(env, oracles, name.env_name, first))
                    if not name.env_name.startswith("scene") or _scene_episode_healthy(np.asarray(rows["qpos"])):
                        break
                split = splits[0 if i < n_episodes else 1]
                for key, values in rows.items():
                    split[key].extend(values)
    finally:
        env.close()
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    # validation first: a training file on disk implies its validation file (see ensure_dataset)
    _save_npz(val_path(path), splits[1] or splits[0])  # a tiny dataset validates on its training data
    _save_npz(path, splits[0])
    steps = len(splits[0]["actions"]) + len(splits[1]["actions"])
    return {
        "path": str(path), "steps": steps, "seconds": wall, "cpu_seconds": cpu,
        "steps_per_cpu_second": steps / max(cpu, 1e-9), "bytes": path.stat().st_size + val_path(path).stat().st_size,
    }


def load_singletask(task: str, path: str | os.PathLike, sparse: bool = False) -> tuple[Any, dict, dict]:
    """``ogbench.make_env_and_datasets(task, dataset_path=path)``: env, train and validation data."""
    import ogbench

    TaskName.parse(task)
    path = Path(path)
    if not path.is_file() or not val_path(path).is_file():
        raise FileNotFoundError(f"no OGBench dataset at {path} (and {val_path(path).name}): generate it first")
    env, train, val = ogbench.make_env_and_datasets(task, dataset_path=str(path), compact_dataset=False)
    if sparse:
        for data in (train, val):
            data["rewards"] = sparse_reward(data["rewards"])
    return env, train, val


def sparse_reward(rewards: np.ndarray) -> np.ndarray:
    """Q-chunking's sparse reward: 0 when every subtask is solved (dense reward 0), else -1."""
    return np.where(np.asarray(rewards) == 0.0, 0.0, -1.0).astype(np.float32)


def to_episodes(dataset: dict[str, np.ndarray]) -> list[Episode]:
    """Cut a loaded single-task dataset into UA2C offline episodes: terminated where the task is solved
    (``mask == 0``), truncated at an OGBench trajectory's end."""
    required = ("observations", "next_observations", "actions", "rewards", "masks", "terminals")
    missing = [k for k in required if k not in dataset]
    if missing:
        raise ValueError(f"dataset lacks {missing}: load it with compact_dataset=False through load_singletask")
    solved = np.asarray(dataset["masks"]) == 0.0  # (N,)
    ends = np.asarray(dataset["terminals"]) > 0.5  # (N,)
    if len(ends) == 0 or not ends[-1]:
        raise ValueError("dataset must end with a trajectory end (terminals[-1] == 1)")
    cuts = np.flatnonzero(solved | ends)  # last index of every segment
    episodes, start = [], 0
    for stop in cuts + 1:
        sl, last = slice(start, stop), np.arange(start, stop) == stop - 1  # last: (n,), the segment's end
        episodes.append(Episode(
            observations=np.concatenate([dataset["observations"][sl], dataset["next_observations"][stop - 1:stop]]),
            actions=np.asarray(dataset["actions"][sl]), rewards=np.asarray(dataset["rewards"][sl], dtype=np.float64),
            terminations=last & solved[stop - 1], truncations=last & ~solved[stop - 1]))
        start = stop
    return episodes
