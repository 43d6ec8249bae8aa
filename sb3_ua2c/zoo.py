"""rl-zoo3 launcher for UA2C: ``python -m sb3_ua2c.zoo train|enjoy|optimize ...`` (console script ``ua2c-zoo``).

rl-zoo3 has no plugin mechanism, so this module

1. registers ``ua2c`` in rl-zoo3's algorithm table (``rl_zoo3.ALGOS``), its Optuna sampler in
   ``rl_zoo3.hyperparams_opt.HYPERPARAMS_SAMPLER`` and its converter (used by ``--trial-id``) in
   ``HYPERPARAMS_CONVERTER``, before rl-zoo3 parses its arguments (``--algo`` checks its choices
   against the table at parse time, and ``--gym-packages`` is imported too late for an algorithm);
2. hands every other argument to rl-zoo3's own ``train`` / ``enjoy`` unchanged.

Choices made here, where rl-zoo3 2.9.2 alone does not do what a UA2C user expects:

* ``--algo`` defaults to ``ua2c`` (rl-zoo3's own default is ``ppo``).
* ``optimize`` is ``train --optimize-hyperparameters``.
* ``train -i model.zip`` continues the run: the number of timesteps keeps growing
  (``learn(reset_num_timesteps=False)``) instead of restarting at 0, so ``-n`` means
  "this many more steps" and logs/schedules continue where the checkpoint stopped. Any checkpoint
  written by ``model.save`` works, including one produced by offline pre-training.
* rl-zoo3 ships no hyperparameters for ``ua2c``: ``train``/``optimize`` with ``--algo ua2c`` and no
  ``--conf-file`` stop with a message pointing at ``zoo_configs/ua2c.yml``.

* Continuing with hyperparameters that change the networks' shapes (``chunk_size``,
  ``history_len``) stops with an error naming the argument.
* Environments that allow one live instance per process (``metadata["process_exclusive"]``,
  e.g. ``MixedTraffic-v0``: libsumo runs one simulation per process) run in their own processes:
  without ``--vec-env`` the training and the evaluation envs are ``SubprocVecEnv``s. An explicit
  ``--vec-env dummy`` that would put several of them in this process (``n_envs > 1``, an
  evaluation env, ``--n-jobs > 1``) stops before training with an error saying so.
* :class:`OfflineDatasetCallback` (YAML ``callback:``) keeps an offline dataset in UA2C's replay
  buffer during online training.

Sweeps: without ``--storage`` the study lives in memory (one process). ``--storage
sqlite:///sweep.db`` keeps it on one machine; several workers on several machines share a
study through ``--storage postgresql://user:password@host:5432/db --study-name NAME`` (Optuna's
RDB storage, driver ``psycopg2``). The launcher creates Optuna's tables under a PostgreSQL
advisory lock, so workers may start at the same moment on an empty database, and every trial
records its worker (``"hostname:pid"``, user attribute ``worker``). ``--n-trials`` counts per
worker; ``--max-total-trials`` caps the whole study (rl-zoo3 checks it after each trial, so
workers finishing at the same moment can overshoot it by at most ``workers - 1``).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import math
import os
import socket
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_ua2c.checks import check_int
from sb3_ua2c.config import ExecutionRule, check_arguments, policy_kwargs_names
from sb3_ua2c.critics import critic_defaults
from sb3_ua2c.policies import UA2CPolicy

if TYPE_CHECKING:
    import optuna

COMMANDS = ("train", "enjoy", "optimize")

#: Velocity-field architectures the sampler chooses from (``UA2CSearchSpace.net_arch``).
NET_ARCHS: dict[str, tuple[int, ...]] = {
    "small": (64, 64),
    "medium": (256, 256),
    "large": (256, 256, 256),
}

# Key of the PostgreSQL advisory lock that serialises Optuna's schema creation between workers.
_SCHEMA_LOCK_KEY = 0x55413243  # "UA2C"

# rl-zoo3's --vec-env and the prefixes argparse accepts for it.
_VEC_ENV_NAMES = tuple("--vec-env"[:n] for n in range(5, len("--vec-env") + 1))

# rl-zoo3's flag and the prefix argparse accepts for it.
_OPTIMIZE_FLAGS = frozenset({"-optimize", "--optimize", "--optimize-hyperparameters"})

#: Keys of an rl-zoo3 hyperparameter entry that rl-zoo3 consumes itself; every other key of a
#: ``zoo_configs/*.yml`` entry is passed to the algorithm's constructor.
ZOO_KEYS = frozenset(
    {
        "n_timesteps",
        "n_envs",
        "normalize",
        "env_wrapper",
        "vec_env_wrapper",
        "frame_stack",
        "callback",
        "env_kwargs",
        "monitor_kwargs",
        "noise_type",
        "noise_std",
    }
)

_USAGE = """usage: ua2c-zoo {train,enjoy,optimize} [rl-zoo3 arguments ...]
       python -m sb3_ua2c.zoo {train,enjoy,optimize} [rl-zoo3 arguments ...]

  train     rl-zoo3 train; -i model.zip continues from a checkpoint (timesteps keep growing)
  enjoy     rl-zoo3 enjoy; runs the stateful predict (adaptive chunks, replanning in place)
  optimize  rl-zoo3 train --optimize-hyperparameters (Optuna); --storage postgresql://...
            lets workers on several machines share one study

--algo defaults to ua2c. `ua2c-zoo train --help` lists rl-zoo3's own arguments.
Envs with one simulator per process (MixedTraffic-v0) train and evaluate in SubprocVecEnv
workers unless --vec-env is given.
example: ua2c-zoo train --env Pendulum-v1 --conf-file zoo_configs/ua2c.yml
"""


@dataclass(frozen=True)
class UA2CSearchSpace:
    """
    Ranges of the UA2C Optuna sampler (``--optimize``). Every field is named after the UA2C constructor
    argument it samples, or the :class:`~sb3_ua2c.policies.UA2CPolicy` argument (``net_arch``,
    ``critic_arch``, ``critic_embed_dim``, ``n_elite``, which go into ``policy_kwargs``), and every value is checked by
    UA2C's own validator (:func:`~sb3_ua2c.config.check_arguments`, :class:`~sb3_ua2c.config.ExecutionRule`). ``gamma`` is sampled as
    ``one_minus_gamma`` on a log scale (as rl-zoo3 does for SAC/TD3/TQC); the other intervals are
    :data:`LOG_INTERVALS` (log scale), :data:`INT_INTERVALS` (integers) and :data:`INTERVALS`, given as
    ``(low, high)``; every other field is a tuple of choices. ``net_arch`` holds names of
    :data:`NET_ARCHS`; ``n_elite`` must not exceed ``min(n_candidates)``.
    """

    gamma: tuple[float, float] = (0.95, 0.9999)
    learning_rate: tuple[float, float] = (1e-5, 2e-3)
    batch_size: tuple[int, ...] = (64, 128, 256)
    tau: tuple[float, float] = (1e-3, 0.08)
    chunk_size: tuple[int, ...] = (3, 5, 8, 10)
    history_len: tuple[int, ...] = (1, 2, 4)
    flow_steps: tuple[int, int] = (2, 10)
    target_flow_steps: tuple[int, int] = (1, 6)
    n_candidates: tuple[int, ...] = (8, 16, 32)
    n_target_candidates: tuple[int, ...] = (1, 2, 4)
    entropy_threshold: tuple[float, float] = (-3.0, 1.5)
    q_weight: tuple[float, float] = (0.01, 3.0)
    smooth_weight: tuple[float, ...] = (0.0, 10.0, 100.0, 300.0)
    net_arch: tuple[str, ...] = ("small", "medium", "large")
    critic_arch: tuple[str, ...] = ("transformer", "mlp")
    critic_embed_dim: tuple[int, ...] = (32, 64)
    discrete_entropy: tuple[bool, ...] = (True, False)
    commit_discrete: tuple[bool, ...] = (False, True)
    online_targets: tuple[str, ...] = ("prefix", "window")
    n_elite: tuple[int, ...] = (1, 4, 8)

    def __post_init__(self) -> None:
        for field in fields(self):
            name, value = field.name, getattr(self, field.name)
            if name in LOG_INTERVALS or name in INT_INTERVALS or name in INTERVALS:
                _check_interval(name, value)
            elif not (isinstance(value, tuple) and value):
                raise ValueError(f"{name} must be a non-empty tuple of choices, got {value!r}")
            elif name == "net_arch":
                if not set(value) <= set(NET_ARCHS):
                    raise ValueError(f"net_arch must be names among {sorted(NET_ARCHS)}, got {value!r}")
            else:
                for choice in value:
                    _check_value(name, choice)
        check_arguments(n_elite=max(self.n_elite), n_candidates=min(self.n_candidates))

    @classmethod
    def from_dict(cls, config: dict[str, Any]) -> UA2CSearchSpace:
        """
        Build from a mapping (e.g. parsed YAML); lists become tuples.

        :param config: field name -> interval or choices
        :raises ValueError: on an unknown key or a bad value, naming it
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(config) - known)
        if unknown:
            raise ValueError(f"Unknown UA2C search-space key(s) {unknown}; known: {sorted(known)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in config.items()})


#: Intervals of :class:`UA2CSearchSpace` sampled on a log scale (``gamma`` through ``1 - gamma``).
LOG_INTERVALS = ("gamma", "learning_rate", "tau", "q_weight")
#: Integer intervals of :class:`UA2CSearchSpace`.
INT_INTERVALS = ("flow_steps", "target_flow_steps")
#: Uniform intervals of :class:`UA2CSearchSpace`.
INTERVALS = ("entropy_threshold",)


def _check_interval(name: str, interval: Any) -> None:
    """A ``(low, high)`` interval with ``low < high``, both ends valid values of ``name``; a log scale
    needs ``low > 0`` (``gamma``: ``high < 1``); an integer interval holds integers."""
    if not (isinstance(interval, tuple) and len(interval) == 2):
        raise ValueError(f"{name} must be a (low, high) tuple, got {interval!r}")
    low, high = interval
    if name in INT_INTERVALS and not all(isinstance(v, int) and not isinstance(v, bool) for v in interval):
        raise ValueError(f"{name} must hold integers, got {interval!r}")
    lower, upper = (0.0, 1.0) if name == "gamma" else (0.0 if name in LOG_INTERVALS else -math.inf, math.inf)
    if not lower < low < high < upper:
        raise ValueError(f"{name} must satisfy {lower} < low < high < {upper}, got {interval!r}")
    _check_value(name, low)
    _check_value(name, high)


def _check_value(name: str, value: Any) -> None:
    """UA2C's own check of one value of the constructor argument ``name`` (``ValueError`` naming it)."""
    if name == "entropy_threshold":
        ExecutionRule(entropy_threshold=value)
    elif name == "critic_embed_dim":  # the Transformer critic's critic_kwargs["embed_dim"]
        check_int(name, value)
    else:
        check_arguments(**{name: value})


def _suggest(trial: optuna.Trial, name: str, choices: tuple) -> Any:
    """One draw of field ``name`` of :class:`UA2CSearchSpace` (``gamma`` as ``one_minus_gamma``)."""
    if name == "gamma":
        return trial.suggest_float("one_minus_gamma", 1.0 - choices[1], 1.0 - choices[0], log=True)
    if name in LOG_INTERVALS:
        return trial.suggest_float(name, *choices, log=True)
    if name in INT_INTERVALS:
        return trial.suggest_int(name, *choices)
    if name in INTERVALS:
        return trial.suggest_float(name, *choices)
    return trial.suggest_categorical(name, choices)


def sample_ua2c_params(
    trial: optuna.Trial,
    n_actions: int,
    n_envs: int,
    additional_args: dict[str, Any],
    space: UA2CSearchSpace | None = None,
) -> dict[str, Any]:
    """
    rl-zoo3 sampler for UA2C: draws one point of ``space`` and returns UA2C constructor arguments.

    The signature is rl-zoo3's sampler signature (``HYPERPARAMS_SAMPLER``). The trial's raw
    parameters (``trial.params``) go through :func:`convert_ua2c_params`, so ``--trial-id`` reloads
    the same constructor arguments.

    :param trial: the Optuna trial
    :param n_actions: action dimension (unused: UA2C explores by sampling its flow policy)
    :param n_envs: number of environments (unused)
    :param additional_args: rl-zoo3's extra arguments (unused)
    :param space: ranges; ``None`` uses ``UA2CSearchSpace()``
    :return: keyword arguments for ``UA2C(...)``
    """
    space = UA2CSearchSpace() if space is None else space
    sampled = {
        "one_minus_gamma" if f.name == "gamma" else f.name: _suggest(trial, f.name, getattr(space, f.name))
        for f in fields(space)
    }
    trial.set_user_attr("gamma", 1.0 - sampled["one_minus_gamma"])
    return convert_ua2c_params(sampled)


def convert_ua2c_params(sampled: dict[str, Any]) -> dict[str, Any]:
    """
    Turn sampled Optuna parameters into UA2C constructor arguments (rl-zoo3 ``HYPERPARAMS_CONVERTER``).

    :param sampled: ``trial.params`` of a UA2C trial
    :return: the same parameters with ``one_minus_gamma`` replaced by ``gamma`` and the arguments of
        :class:`~sb3_ua2c.policies.UA2CPolicy` that UA2C does not take itself (``net_arch``, a
        :data:`NET_ARCHS` name, ``critic_arch``, ``n_elite``) moved into ``policy_kwargs``, and ``critic_embed_dim``
        into its ``critic_kwargs`` as ``embed_dim`` (the Transformer critic's only; dropped for another ``critic_arch``).
        As for every rl-zoo3 algorithm, a sampled ``policy_kwargs`` replaces the YAML one.
    """
    params = dict(sampled)
    if "one_minus_gamma" in params:
        params["gamma"] = 1.0 - params.pop("one_minus_gamma")
    if "net_arch" in params:
        name = params["net_arch"]
        if name not in NET_ARCHS:
            raise ValueError(f"net_arch must be one of {sorted(NET_ARCHS)}, got {name!r}")
        params["net_arch"] = list(NET_ARCHS[name])
    from sb3_ua2c.ua2c import UA2C

    policy_kwargs = {name: params.pop(name) for name in policy_kwargs_names(UA2CPolicy, UA2C) if name in params}
    if "critic_embed_dim" in params:
        embed_dim = params.pop("critic_embed_dim")
        arch = policy_kwargs.get("critic_arch", inspect.signature(UA2CPolicy).parameters["critic_arch"].default)
        if "embed_dim" in critic_defaults(arch):
            policy_kwargs["critic_kwargs"] = {"embed_dim": embed_dim}
    if policy_kwargs:
        params["policy_kwargs"] = policy_kwargs
    return params


def register(search_space: UA2CSearchSpace | None = None) -> None:
    """
    Register ``ua2c`` in rl-zoo3: algorithm table, Optuna sampler and sampled-parameter converter.

    Idempotent; called by :func:`main`. Call it yourself before using rl-zoo3's Python API
    (``rl_zoo3.train.train()``, ``ExperimentManager``) with ``algo="ua2c"``.

    :param search_space: ranges for ``--optimize``; ``None`` uses ``UA2CSearchSpace()``
    """
    import rl_zoo3.hyperparams_opt as hyperparams_opt
    from rl_zoo3 import ALGOS

    from sb3_ua2c import UA2C

    ALGOS["ua2c"] = UA2C
    if search_space is None:
        hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"] = sample_ua2c_params
    else:
        hyperparams_opt.HYPERPARAMS_SAMPLER["ua2c"] = functools.partial(
            sample_ua2c_params, space=search_space
        )
    hyperparams_opt.HYPERPARAMS_CONVERTER["ua2c"] = convert_ua2c_params


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
                print(
                    f"OfflineDatasetCallback: the replay buffer already holds offline data, {self.dataset} not added"
                )
            return
        dataset = load_dataset(self.dataset)
        dataset.check_compatible(self.training_env)
        self.n_added = add_offline_episodes(dataset.episodes)
        if self.verbose:
            print(f"OfflineDatasetCallback: {self.n_added} offline steps from {self.dataset}")

    def _on_step(self) -> bool:
        return True


#: ``metadata`` key of an environment class that allows one live instance per process.
PROCESS_EXCLUSIVE = "process_exclusive"


def needs_own_process(env_id: str) -> bool:
    """
    Whether the environment of ``env_id`` allows one live instance per process.

    Read from the class registered as the id's entry point (``metadata["process_exclusive"]``);
    nothing is constructed.

    :param env_id: a registered Gymnasium id
    """
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    entry_point = gym.spec(env_id).entry_point
    creator = load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point
    return bool(getattr(creator, "metadata", {}).get(PROCESS_EXCLUSIVE, False))


def envs_in_one_process(n_envs: int, n_eval_envs: int, evaluates: bool, n_jobs: int = 1) -> int:
    """
    Largest number of environments rl-zoo3 keeps open at once in its own process with ``DummyVecEnv``.

    :param n_envs: training envs
    :param n_eval_envs: evaluation envs (``--n-eval-envs``)
    :param evaluates: whether an evaluation env exists (``--eval-freq > 0``, or a sweep)
    :param n_jobs: trials run in parallel threads of the process (``--n-jobs``, sweeps only)
    """
    return n_jobs * (n_envs + (n_eval_envs if evaluates else 0))


def _vec_env_choice_error(env_id: str, n_open: int) -> str:
    return (
        f"{env_id} allows one live environment per process (libsumo runs one SUMO simulation per "
        f"process), but --vec-env dummy would keep {n_open} of them open in this process (training, "
        "evaluation and parallel trials together). Leave --vec-env out (the launcher then runs every "
        f"{env_id} env in its own process) or pass --vec-env subproc; --vec-env dummy works with "
        "n_envs 1, --eval-freq -1 and one job."
    )


class VecEnvChoiceError(ValueError):
    """An explicit ``--vec-env dummy`` would put several process-exclusive environments in one process."""


def _experiment_manager_class(vec_env_given: bool = False) -> type:
    """
    rl-zoo3's ``ExperimentManager`` with four additions.

    * Continued runs (``-i model.zip``) keep counting timesteps: rl-zoo3 2.9.2 calls
      ``model.learn(n_timesteps)``, which resets ``num_timesteps`` to 0 after loading a checkpoint;
      here the call gets ``reset_num_timesteps=False`` when continuing.
    * Continuing from a checkpoint whose network shapes differ from the hyperparameters
      (``chunk_size``, ``history_len``) stops with a clear error (see
      :func:`check_checkpoint_compatible`) instead of a tensor-size mismatch deep inside loading.
    * Every Optuna trial records the worker that ran it (user attribute ``worker`` =
      ``"hostname:pid"``), so a study shared by several machines shows who ran what.
    * Process-exclusive environments (:func:`needs_own_process`) get ``SubprocVecEnv`` for the
      training and the evaluation envs unless ``--vec-env`` was given (``vec_env_given``); an
      explicit ``dummy`` that would open several of them in this process raises
      :class:`VecEnvChoiceError` before the first env is created.
    """
    from rl_zoo3.exp_manager import ExperimentManager
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    class UA2CExperimentManager(ExperimentManager):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.own_process = needs_own_process(self.env_name.gym_id)
            if self.own_process and not vec_env_given:
                self.vec_env_class = SubprocVecEnv

        def create_callbacks(self) -> None:
            # The first step after the hyperparameters (n_envs) are read, before any env is built.
            if self.own_process and self.vec_env_class is DummyVecEnv:
                n_open = envs_in_one_process(
                    self.n_envs,
                    self.n_eval_envs,
                    evaluates=self.optimize_hyperparameters or self.eval_freq > 0,
                    n_jobs=self.n_jobs if self.optimize_hyperparameters else 1,
                )
                if n_open > 1:
                    raise VecEnvChoiceError(_vec_env_choice_error(self.env_name.gym_id, n_open))
            super().create_callbacks()

        def learn(self, model: Any) -> None:
            if not self.continue_training:
                super().learn(model)
                return
            # Shadow the bound method for this one call only; removed before the model is saved.
            model.learn = functools.partial(type(model).learn, model, reset_num_timesteps=False)
            try:
                super().learn(model)
            finally:
                del model.learn

        def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: Any) -> Any:
            check_checkpoint_compatible(self.trained_agent, hyperparams)
            return super()._load_pretrained_agent(hyperparams, env)

        def objective(self, trial: optuna.Trial) -> float:
            trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
            return super().objective(trial)

    return UA2CExperimentManager


#: Constructor arguments that fix network shapes: a continued run (``-i``) must keep them.
SHAPE_ARGUMENTS = ("chunk_size", "history_len")


def check_checkpoint_compatible(checkpoint: str, hyperparams: dict[str, Any]) -> None:
    """
    Check that hyperparameters passed with ``-i checkpoint`` keep the checkpoint's network shapes.

    rl-zoo3 passes the YAML hyperparameters to ``load``, which overrides the saved attributes; a
    different ``chunk_size`` or ``history_len`` would rebuild networks of another shape.

    :param checkpoint: path of the ``.zip`` checkpoint
    :param hyperparams: the hyperparameters rl-zoo3 is about to pass to ``load``
    :raises ValueError: naming the first argument that differs
    """
    if not any(key in hyperparams for key in SHAPE_ARGUMENTS):
        return
    from stable_baselines3.common.save_util import load_from_zip_file

    data, _, _ = load_from_zip_file(checkpoint, load_data=True, device="cpu", print_system_info=False)
    for key in SHAPE_ARGUMENTS:
        if key in hyperparams and data is not None and key in data and hyperparams[key] != data[key]:
            raise ValueError(
                f"{key}={hyperparams[key]!r} in the hyperparameters, but the checkpoint {checkpoint} was "
                f"trained with {key}={data[key]!r}: the networks' shapes depend on it. Use the checkpoint's "
                f"value (e.g. -params {key}:{data[key]!r})."
            )


@contextlib.contextmanager
def _patched_train_module(vec_env_given: bool) -> Iterator[None]:
    import rl_zoo3.train as zoo_train

    original = zoo_train.ExperimentManager
    zoo_train.ExperimentManager = _experiment_manager_class(vec_env_given)
    try:
        yield
    finally:
        zoo_train.ExperimentManager = original


def _option_value(args: Sequence[str], names: Sequence[str]) -> str | None:
    """Value of the last occurrence of an option among ``names`` (``--x v`` or ``--x=v``), else None."""
    value = None
    for i, arg in enumerate(args):
        for name in names:
            if arg == name and i + 1 < len(args):
                value = args[i + 1]
            elif arg.startswith(name + "="):
                value = arg[len(name) + 1 :]
    return value


def prepare_storage(storage: str | None, attempts: int = 5) -> None:
    """
    Create Optuna's tables in an RDB storage once, safely when several workers start together.

    Workers started at the same time on an empty database would all run Optuna's schema creation
    and all but one crash (duplicate ``CREATE TYPE``/``CREATE TABLE``; optuna issue #1092). On
    PostgreSQL the creation runs under a session advisory lock, so exactly one worker creates
    the schema and the others find it; other databases retry. In-memory studies (``None``) and
    journal files (``*.log``) need nothing.

    :param storage: the ``--storage`` value
    :param attempts: tries for databases without advisory locks
    """
    if storage is None or storage.endswith(".log") or "://" not in storage:
        return
    import optuna
    import sqlalchemy

    try:
        engine = sqlalchemy.create_engine(storage)
    except ImportError as error:
        raise SystemExit(
            f"error: --storage {storage.split('://')[0]}://... needs its database driver ({error}); "
            "for PostgreSQL: pip install 'sb3-ua2c[zoo]' (psycopg2-binary)"
        ) from None
    try:
        if engine.dialect.name == "postgresql":
            with engine.connect() as connection:
                connection.execute(
                    sqlalchemy.text("SELECT pg_advisory_lock(:key)"), {"key": _SCHEMA_LOCK_KEY}
                )
                try:
                    optuna.storages.RDBStorage(storage)
                finally:
                    connection.execute(
                        sqlalchemy.text("SELECT pg_advisory_unlock(:key)"), {"key": _SCHEMA_LOCK_KEY}
                    )
            return
        for attempt in range(attempts):
            try:
                optuna.storages.RDBStorage(storage)
                return
            except sqlalchemy.exc.SQLAlchemyError:
                if attempt == attempts - 1:
                    raise
                time.sleep(0.5 * (attempt + 1))
    finally:
        engine.dispose()


def build_zoo_argv(command: str, args: Sequence[str]) -> list[str]:
    """
    Translate launcher arguments into rl-zoo3 arguments (without the program name).

    :param command: one of ``train``, ``enjoy``, ``optimize``
    :param args: the arguments after the command, handed to rl-zoo3 unchanged except that
        ``--algo ua2c`` is added when no ``--algo`` is given and ``optimize`` adds
        ``--optimize-hyperparameters``
    :return: the argument list for rl-zoo3's ``train()`` or ``enjoy()``
    :raises ValueError: on an unknown command, or ``train``/``optimize`` of ``ua2c`` without
        ``--conf-file`` (rl-zoo3 has no built-in UA2C hyperparameters)
    """
    if command not in COMMANDS:
        raise ValueError(f"Unknown command {command!r}: expected one of {', '.join(COMMANDS)}")
    zoo_args = list(args)
    asks_help = any(arg in ("-h", "--help") for arg in zoo_args)
    algo = _option_value(zoo_args, ("--algo",))
    if algo is None:
        algo = "ua2c"
        zoo_args = ["--algo", algo, *zoo_args]
    if command == "optimize" and not _OPTIMIZE_FLAGS & set(zoo_args):
        zoo_args.append("--optimize-hyperparameters")
    if (
        command != "enjoy"
        and algo == "ua2c"
        and not asks_help
        and _option_value(zoo_args, ("-conf", "--conf-file")) is None
    ):
        raise ValueError(
            "rl-zoo3 has no built-in hyperparameters for ua2c: pass --conf-file "
            "(e.g. --conf-file zoo_configs/ua2c.yml from a source checkout)"
        )
    return zoo_args


def main(argv: Sequence[str] | None = None) -> None:
    """
    Entry point of ``python -m sb3_ua2c.zoo`` and of the ``ua2c-zoo`` console script.

    :param argv: ``[command, *rl_zoo3_arguments]``; defaults to ``sys.argv[1:]``
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_USAGE)
        if not argv:
            raise SystemExit(2)
        return
    command, rest = argv[0], argv[1:]
    try:
        zoo_argv = build_zoo_argv(command, rest)
    except ValueError as error:
        print(_USAGE, file=sys.stderr)
        raise SystemExit(f"error: {error}") from None

    register()
    if _OPTIMIZE_FLAGS & set(zoo_argv):
        prepare_storage(_option_value(zoo_argv, ("--storage",)))
    program = f"ua2c-zoo {command}"
    saved_argv = sys.argv
    sys.argv = [program, *zoo_argv]
    try:
        if command == "enjoy":
            from rl_zoo3.enjoy import enjoy

            enjoy()
        else:
            from rl_zoo3.train import train

            # argparse accepts any unambiguous prefix of --vec-env (rl-zoo3 has no other --vec... option)
            vec_env_given = _option_value(zoo_argv, _VEC_ENV_NAMES) is not None
            with _patched_train_module(vec_env_given):
                train()
    except VecEnvChoiceError as error:
        raise SystemExit(f"error: {error}") from None
    finally:
        sys.argv = saved_argv


if __name__ == "__main__":
    main()
