"""OGBench single-task benchmark for UA2C: locally generated "play" and "navigate" data, an SB3 env,
one run unit, and the ``python -m experiments ogbench`` command (:mod:`~experiments.ogbench.cli`).

Needs the optional ``ogbench`` extra (``pip install sb3-ua2c[ogbench]``). Importing this package
registers ``OGBenchSingleTask-v0`` with Gymnasium.
"""

from experiments.ogbench.data import TaskName, generate_play_dataset, load_singletask, to_episodes
from experiments.ogbench.env import ENV_ID, OGBenchSingleTask, register

register()

__all__ = ["ENV_ID", "OGBenchSingleTask", "TaskName", "generate_play_dataset", "load_singletask", "to_episodes"]
