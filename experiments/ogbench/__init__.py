"""OGBench single-task benchmark (``python -m experiments ogbench``); registers ``OGBenchSingleTask-v0``."""

from experiments.ogbench.data import TaskName, generate_play_dataset, load_singletask, to_episodes
from experiments.ogbench.env import ENV_ID, OGBenchSingleTask, register

register()

__all__ = ["ENV_ID", "OGBenchSingleTask", "TaskName", "generate_play_dataset", "load_singletask", "to_episodes"]
