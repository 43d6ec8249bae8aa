"""UA2C as the paper writes it, in rl-zoo3's ``.py`` hyperparameter format.

    python -m sb3_ua2c.zoo train --env Pendulum-v1 --conf-file zoo_configs/ua2c_paper.py
    python -m sb3_ua2c.zoo train --env MixedTraffic-v0 --gym-packages envs --vec-env subproc \\
      --conf-file zoo_configs/ua2c_paper.py

Each entry is the problem part of ``ua2c.yml``'s entry (budget, buffer, observation, action
space, wrapper) with the preset ``sb3_ua2c.presets.PAPER`` on top, read from the package, so the
two never differ. In Python: ``UA2C("MlpPolicy", env, **sb3_ua2c.presets.preset("paper"))``.
rl-zoo3 runs this file with ``exec``: it has no ``__file__``, hence the problem part is repeated
here (a test keeps it equal to ``ua2c.yml``'s).
"""

from sb3_ua2c.presets import preset

PROBLEMS = {
    "Pendulum-v1": {"n_timesteps": 20000, "policy": "MlpPolicy", "buffer_size": 100000, "history_len": 1},
    "MixedTraffic-v0": {
        "n_timesteps": 2e4,
        "policy": "MlpPolicy",
        "buffer_size": 100000,
        "discrete_action_dims": {1: [-1, 0, 1]},
        "env_wrapper": [{"envs.wrappers.DrivingStyleContext": {"update_every": 10}}],
    },
}

hyperparams = {env_id: {**problem, **preset("paper")} for env_id, problem in PROBLEMS.items()}
