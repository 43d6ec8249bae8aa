"""OGBench single-task benchmark for UA2C (``python -m experiments ogbench``; the ``ogbench`` extra); importing it
registers ``OGBenchSingleTask-v0`` with Gymnasium."""

from experiments.ogbench.data import TaskName, generate_play_dataset, load_singletask, to_episodes
from experiments.ogbench.env import ENV_ID, OGBenchSingleTask, register

register()

__all__ = ["ENV_ID", "OGBenchSingleTask", "TaskName", "generate_play_dataset", "load_singletask", "to_episodes"]
