"""UA2C in rl-baselines3-zoo: ``ua2c-zoo train|enjoy|optimize ...`` (or ``python -m sb3_ua2c.zoo``).

The command line, the vec-env choice (``--vec-env``), the Optuna study and its storage
(``--storage``: a journal file ``*.log`` or a database URL) are rl-zoo3's own. This module adds what
rl-zoo3 2.9.2 lacks:

* Registration: rl-zoo3 has no plugin mechanism, and ``--algo`` checks its choices against
  ``rl_zoo3.ALGOS`` at parse time (``--gym-packages`` comes too late for an algorithm).
  :func:`register` adds ``ua2c`` there, its sampler to ``HYPERPARAMS_SAMPLER`` and its converter
  (for ``--trial-id``) to ``HYPERPARAMS_CONVERTER``; :func:`main` registers and runs rl-zoo3's
  ``train`` / ``enjoy`` with ``--algo ua2c`` unless given another, ``optimize`` being ``train --optimize-hyperparameters``.
* The UA2C search space (:data:`SEARCH_SPACE`, Optuna distributions; :func:`sample_ua2c_params`).
  A plug-in critic's own settings are searched as ``critic_kwargs.<name>`` in a space of your own.
* ``train -i model.zip`` keeps counting timesteps (``learn(reset_num_timesteps=False)``): ``-n`` means
  "this many more steps". rl-zoo3 restarts the count at 0.
* Environments that allow one live instance per process (``metadata["process_exclusive"]``, e.g.
  ``MixedTraffic-v0``: libsumo runs one simulation per process) stop before any env is built when
  ``--vec-env dummy`` (rl-zoo3's default) would put two of them in this process (``n_envs > 1``, or
  an evaluation env next to the training env): pass ``--vec-env subproc``.
* :class:`OfflineDatasetCallback` (YAML ``callback:``) puts an offline dataset in UA2C's replay buffer.

``UA2C.load`` itself refuses a checkpoint whose networks do not fit the hyperparameters of ``-i``.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution
from stable_baselines3.common.callbacks import BaseCallback

COMMANDS = ("train", "enjoy", "optimize")

#: Keys of an rl-zoo3 hyperparameter entry that rl-zoo3 consumes itself; every other key is passed
#: to the algorithm's constructor.
ZOO_KEYS = frozenset({"n_timesteps", "n_envs", "normalize", "env_wrapper", "vec_env_wrapper", "frame_stack",
                      "callback", "env_kwargs", "monitor_kwargs", "noise_type", "noise_std"})  # fmt: skip

#: Velocity-field architectures the sampler chooses from by name (``net_arch``).
NET_ARCHS: dict[str, tuple[int, ...]] = {"small": (64, 64), "medium": (256, 256), "large": (256, 256, 256)}

#: The UA2C search space of ``--optimize``: one Optuna distribution per UA2C constructor argument,
#: or :class:`~sb3_ua2c.policies.UA2CPolicy` argument (``net_arch``, a :data:`NET_ARCHS` name,
#: ``critic_arch``, ``n_elite``: they go into ``policy_kwargs``); ``gamma`` is drawn as
#: ``one_minus_gamma`` on a log scale, as rl-zoo3 does for SAC, TD3 and TQC.
SEARCH_SPACE: dict[str, BaseDistribution] = {
    "one_minus_gamma": FloatDistribution(1e-4, 0.05, log=True),
    "learning_rate": FloatDistribution(1e-5, 2e-3, log=True),
    "batch_size": CategoricalDistribution((64, 128, 256)),
    "tau": FloatDistribution(1e-3, 0.08, log=True),
    "chunk_size": CategoricalDistribution((3, 5, 8, 10)),
    "history_len": CategoricalDistribution((1, 2, 4)),
    "flow_steps": IntDistribution(2, 10),
    "target_flow_steps": IntDistribution(1, 6),
    "n_candidates": CategoricalDistribution((8, 16, 32)),
    "n_target_candidates": CategoricalDistribution((1, 2, 4)),
    "entropy_threshold": FloatDistribution(-3.0, 1.5),
    "q_weight": FloatDistribution(0.01, 3.0, log=True),
    "smooth_weight": CategoricalDistribution((0.0, 10.0, 100.0, 300.0)),
    "discrete_entropy": CategoricalDistribution((True, False)),
    "commit_discrete": CategoricalDistribution((False, True)),
    "online_targets": CategoricalDistribution(("prefix", "window")),
    "net_arch": CategoricalDistribution(tuple(NET_ARCHS)),
    "critic_arch": CategoricalDistribution(("transformer", "mlp")),
    "n_elite": CategoricalDistribution((1, 4, 8)),
}


def check_search_space(space: Mapping[str, BaseDistribution]) -> None:
    """
    Check a search space with UA2C's own validators (:func:`~sb3_ua2c.config.check_arguments`,
    :class:`~sb3_ua2c.config.ExecutionRule`): every name, both ends of every interval and every choice.

    :param space: name -> Optuna distribution, like :data:`SEARCH_SPACE`
    :raises ValueError: naming the first bad name or value
    """
    from sb3_ua2c.config import ExecutionRule, check_arguments

    ends: dict[str, tuple] = {}
    for name, dist in space.items():
        if not isinstance(dist, BaseDistribution):
            raise ValueError(f"search space {name!r} must be an optuna distribution, got {dist!r}")
        ends[name] = dist.choices if isinstance(dist, CategoricalDistribution) else (dist.low, dist.high)
        for value in ends[name]:
            if name.startswith("critic_kwargs."):
                continue  # the plug-in checks its own kwargs when it is built
            if name == "one_minus_gamma":
                check_arguments(gamma=1.0 - value)
            elif name == "net_arch":
                if value not in NET_ARCHS:
                    raise ValueError(f"net_arch must be names among {sorted(NET_ARCHS)}, got {value!r}")
            elif name == "entropy_threshold":
                ExecutionRule(entropy_threshold=value)
            else:
                check_arguments(**{name: value})
    if "n_elite" in ends and "n_candidates" in ends:
        check_arguments(n_elite=max(ends["n_elite"]), n_candidates=min(ends["n_candidates"]))


def sample_ua2c_params(
    trial: Any, n_actions: int, n_envs: int, additional_args: dict[str, Any], space: Mapping | None = None
) -> dict[str, Any]:
    """
    rl-zoo3's sampler for UA2C (the ``HYPERPARAMS_SAMPLER`` signature): one draw of ``space``.

    ``n_actions``, ``n_envs`` and ``additional_args`` are unused (UA2C explores by sampling its policy).

    :param trial: the Optuna trial
    :param space: name -> Optuna distribution; ``None`` is :data:`SEARCH_SPACE`
    :return: keyword arguments for ``UA2C(...)`` (:func:`convert_ua2c_params` of the draw)
    """
    sampled = {}
    for name, dist in (SEARCH_SPACE if space is None else space).items():
        if isinstance(dist, CategoricalDistribution):
            sampled[name] = trial.suggest_categorical(name, dist.choices)
        elif isinstance(dist, IntDistribution):
            sampled[name] = trial.suggest_int(name, dist.low, dist.high, step=dist.step, log=dist.log)
        else:
            sampled[name] = trial.suggest_float(name, dist.low, dist.high, step=dist.step, log=dist.log)
    return convert_ua2c_params(sampled)


def convert_ua2c_params(sampled: dict[str, Any]) -> dict[str, Any]:
    """
    Turn sampled parameters into UA2C constructor arguments (rl-zoo3's ``HYPERPARAMS_CONVERTER``).

    :param sampled: ``trial.params`` of a UA2C trial
    :return: ``one_minus_gamma`` replaced by ``gamma``, a ``net_arch`` name by its sizes, the
        arguments of :class:`~sb3_ua2c.policies.UA2CPolicy` moved into ``policy_kwargs`` and
        ``critic_kwargs.<name>`` into its ``critic_kwargs`` (a sampled ``policy_kwargs`` replaces
        the YAML one, as for every rl-zoo3 algorithm)
    :raises ValueError: for a ``net_arch`` name not in :data:`NET_ARCHS`
    """
    from sb3_ua2c.config import policy_kwargs_names
    from sb3_ua2c.policies import UA2CPolicy
    from sb3_ua2c.ua2c import UA2C

    params = dict(sampled)
    if "one_minus_gamma" in params:
        params["gamma"] = 1.0 - params.pop("one_minus_gamma")
    if "net_arch" in params:
        if params["net_arch"] not in NET_ARCHS:
            raise ValueError(f"net_arch must be one of {sorted(NET_ARCHS)}, got {params['net_arch']!r}")
        params["net_arch"] = list(NET_ARCHS[params["net_arch"]])
    policy_kwargs = {key: params.pop(key) for key in policy_kwargs_names(UA2CPolicy, UA2C) if key in params}
    for key in [key for key in params if key.startswith("critic_kwargs.")]:
        policy_kwargs.setdefault("critic_kwargs", {})[key.partition(".")[2]] = params.pop(key)
    return {**params, "policy_kwargs": policy_kwargs} if policy_kwargs else params


class OfflineDatasetCallback(BaseCallback):
    """
    Put the episodes of an offline dataset into UA2C's replay buffer when training starts.

    The rl-zoo way to keep offline data available online (paper §3.2: the buffer mixes offline
    k-step windows into each minibatch with ``offline_ratio``), e.g. when continuing from an
    offline pre-trained checkpoint with ``-i pretrained.zip``::

        callback:
          - sb3_ua2c.zoo.OfflineDatasetCallback:
              dataset: data/merge

    Nothing is added when the buffer already holds offline data (a ``replay_buffer.pkl`` next to
    the checkpoint, which rl-zoo3 loads with ``-i``), so the data is never counted twice.

    :param dataset: directory of a dataset written by ``python -m envs collect``
        (:func:`sb3_ua2c.offline.write_dataset`)
    :param verbose: 1 prints how many steps were added
    """

    def __init__(self, dataset: str | os.PathLike, verbose: int = 0) -> None:
        super().__init__(verbose)
        if not isinstance(dataset, str | os.PathLike) or not str(dataset):
            raise ValueError(f"OfflineDatasetCallback: dataset must be a directory path, got {dataset!r}")
        self.dataset = str(dataset)
        #: environment steps added to the buffer (0 when it already held offline data)
        self.n_added = 0

    def _on_training_start(self) -> None:
        from sb3_ua2c.offline import load_dataset

        add_offline_episodes = getattr(self.model, "add_offline_episodes", None)
        if add_offline_episodes is None:
            raise ValueError(f"OfflineDatasetCallback needs a UA2C model, got {type(self.model).__name__}")
        if self.model.replay_buffer.n_samples()[1] > 0:
            if self.verbose:
                print(f"OfflineDatasetCallback: offline data already in the buffer, {self.dataset} skipped")
            return
        dataset = load_dataset(self.dataset)
        dataset.check_compatible(self.training_env)
        self.n_added = add_offline_episodes(dataset.episodes)
        if self.verbose:
            print(f"OfflineDatasetCallback: {self.n_added} offline steps from {self.dataset}")

    def _on_step(self) -> bool:
        return True


def process_exclusive(env_id: str) -> bool:
    """Whether ``env_id``'s class allows one live instance per process (``metadata``); builds nothing."""
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    entry_point = gym.spec(env_id).entry_point
    creator = load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point
    return bool(getattr(creator, "metadata", {}).get("process_exclusive", False))


@functools.cache
def _experiment_manager() -> type:
    """rl-zoo3's ``ExperimentManager`` with continued timesteps and the process-exclusive check."""
    from rl_zoo3.exp_manager import ExperimentManager
    from stable_baselines3.common.vec_env import DummyVecEnv

    class UA2CExperimentManager(ExperimentManager):
        def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> Any:
            # an evaluation env always lives next to a training env (rl-zoo3 keeps both open)
            if (n_envs > 1 or eval_env) and self.vec_env_class is DummyVecEnv:
                env_id = self.env_name.gym_id
                if process_exclusive(env_id):
                    raise ValueError(
                        f"--vec-env dummy would put several {env_id} envs in one process, but it allows one "
                        "per process (libsumo): pass --vec-env subproc (or n_envs 1 and --eval-freq -1)"
                    )
            return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)

        def learn(self, model: Any) -> None:
            if self.continue_training:  # rl-zoo3 calls model.learn(n), which restarts the count at 0
                model.learn = functools.partial(type(model).learn, model, reset_num_timesteps=False)
            try:
                super().learn(model)
            finally:
                model.__dict__.pop("learn", None)  # gone before the model is saved

    return UA2CExperimentManager


def register(search_space: Mapping[str, BaseDistribution] | None = None) -> None:
    """
    Register ``ua2c`` in rl-zoo3: the algorithm, its Optuna sampler and converter, and the
    experiment manager of ``rl_zoo3.train`` (continued timesteps, process-exclusive envs). Idempotent;
    :func:`main` calls it; call it yourself before rl-zoo3's Python API (``rl_zoo3.train.train()``).

    :param search_space: name -> Optuna distribution for ``--optimize``; ``None`` is :data:`SEARCH_SPACE`
    :raises ValueError: naming a bad entry of ``search_space`` (:func:`check_search_space`)
    """
    import rl_zoo3.hyperparams_opt as hyperparams_opt
    import rl_zoo3.train

    from sb3_ua2c.ua2c import UA2C

    sampler = sample_ua2c_params
    if search_space is not None:
        check_search_space(search_space)
        sampler = functools.partial(sample_ua2c_params, space=dict(search_space))
    rl_zoo3.ALGOS["ua2c"] = UA2C
    hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"] = sampler
    hyperparams_opt.HYPERPARAMS_CONVERTER["ua2c"] = convert_ua2c_params
    rl_zoo3.train.ExperimentManager = _experiment_manager()


_USAGE = """usage: ua2c-zoo {train,enjoy,optimize} [rl-zoo3 arguments ...]
  rl-zoo3's train and enjoy with ua2c registered (--algo defaults to ua2c); optimize is
  train --optimize-hyperparameters. `ua2c-zoo train --help` lists rl-zoo3's arguments.
  Envs with one simulator per process (MixedTraffic-v0) need --vec-env subproc to evaluate.
example: ua2c-zoo train --env Pendulum-v1 --conf-file zoo_configs/ua2c.yml"""


def main(argv: Sequence[str] | None = None) -> None:
    """
    Entry point of ``ua2c-zoo`` and ``python -m sb3_ua2c.zoo``.

    :param argv: ``[command, *rl_zoo3_arguments]``; defaults to ``sys.argv[1:]``
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:  # -h, --help, nothing or an unknown command
        print(_USAGE)
        raise SystemExit(0 if argv[:1] in (["-h"], ["--help"]) else 2)
    command, args = argv[0], argv[1:]
    if not any(arg.startswith("--algo") for arg in args):
        args = ["--algo", "ua2c", *args]
    if command == "optimize":
        command, args = "train", [*args, "--optimize-hyperparameters"]
    register()
    from rl_zoo3.enjoy import enjoy  # not rl_zoo3.cli: it imports the plotting scripts, which need seaborn
    from rl_zoo3.train import train

    saved_argv, sys.argv = sys.argv, [f"ua2c-zoo {command}", *args]
    try:
        {"train": train, "enjoy": enjoy}[command]()
    finally:
        sys.argv = saved_argv


if __name__ == "__main__":
    main()
