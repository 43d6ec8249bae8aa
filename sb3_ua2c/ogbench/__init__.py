"""OGBench single-task benchmark for UA2C: locally generated "play" and "navigate" data, an SB3 env,
one run unit, and the ``python -m sb3_ua2c ogbench`` command (:mod:`~sb3_ua2c.ogbench.cli`).

Needs the optional ``ogbench`` extra (``pip install sb3-ua2c[ogbench]``). Importing this package
registers ``OGBenchSingleTask-v0`` with Gymnasium.
"""

from sb3_ua2c.ogbench.data import TaskName, generate_play_dataset, load_singletask, to_episodes
from sb3_ua2c.ogbench.env import ENV_ID, OGBenchSingleTask, register

register()

__all__ = ["ENV_ID", "OGBenchSingleTask", "TaskName", "generate_play_dataset", "load_singletask", "to_episodes"]
