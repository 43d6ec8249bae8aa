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
import math
import os
import socket
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_ua2c.buffers import ONLINE_TARGETS

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
    Ranges of the UA2C Optuna sampler (``--optimize``). Intervals are ``(low, high)``; tuples of
    choices are categorical. Every name is a UA2C constructor argument except ``gamma``, which is
    sampled as ``one_minus_gamma`` on a log scale (as rl-zoo3 does for SAC/TD3/TQC).

    :param gamma: discount interval, inside (0, 1)
    :param learning_rate: log-uniform interval
    :param batch_size: choices
    :param tau: Polyak coefficient, log-uniform interval
    :param chunk_size: choices of k (Eq. 2-4); 1 gives the one-step baseline
    :param history_len: choices of the history length l of h_t
    :param flow_steps: integer interval of Euler steps N of the flow sampler when acting
    :param target_flow_steps: integer interval of Euler steps for the target candidates
    :param n_candidates: choices of S, chunks sampled per replanning (Eq. 7, 8)
    :param n_target_candidates: choices of Q, chunks sampled per target (Eq. 4)
    :param entropy_threshold: uniform interval of delta (Eq. 7), in nats; may be negative
        (differential entropy)
    :param q_weight: log-uniform interval of lambda (Eq. 2)
    :param smooth_weight: choices of mu, the in-chunk smoothness term added to Eq. 2 (0 = the paper)
    :param discrete_entropy: choices of ``discrete_entropy`` (``H_u`` with or without the
        categorical dims)
    :param commit_discrete: choices of ``commit_discrete`` (``L_t`` through the first categorical
        switch of the selected chunk, or Eq. 7 alone)
    :param online_targets: choices among ``"prefix"`` (Eq. 8) and ``"window"`` (Eq. 4 on executed
        actions)
    :param n_elite: choices of m, candidates averaged per replanning, stored in ``policy_kwargs``
        (each at most ``min(n_candidates)``)
    :param net_arch: choices among ``NET_ARCHS`` (velocity-field MLP), stored in ``policy_kwargs``
    :param critic_embed_dim: choices of the critics' token width, stored in ``policy_kwargs``
        (must be divisible by the policy's ``critic_n_heads``, 4 by default)
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
    discrete_entropy: tuple[bool, ...] = (True, False)
    commit_discrete: tuple[bool, ...] = (False, True)
    online_targets: tuple[str, ...] = ("prefix", "window")
    n_elite: tuple[int, ...] = (1, 4, 8)
    net_arch: tuple[str, ...] = ("small", "medium", "large")
    critic_embed_dim: tuple[int, ...] = (32, 64)

    def __post_init__(self) -> None:
        # name -> (interval, exclusive lower bound of low, exclusive upper bound of high)
        intervals = {
            "gamma": (self.gamma, 0.0, 1.0),
            "learning_rate": (self.learning_rate, 0.0, math.inf),
            "tau": (self.tau, 0.0, 1.0),
            "flow_steps": (self.flow_steps, 0, math.inf),
            "target_flow_steps": (self.target_flow_steps, 0, math.inf),
            "entropy_threshold": (self.entropy_threshold, -math.inf, math.inf),
            "q_weight": (self.q_weight, 0.0, math.inf),
        }
        for name, (interval, lower, upper) in intervals.items():
            if not (isinstance(interval, tuple) and len(interval) == 2):
                raise ValueError(f"{name} must be a (low, high) tuple, got {interval!r}")
            low, high = interval
            if not (lower < low < high < upper):
                raise ValueError(f"{name} must satisfy {lower} < low < high < {upper}, got {interval!r}")
        for name in ("flow_steps", "target_flow_steps"):
            if not all(isinstance(v, int) and not isinstance(v, bool) for v in getattr(self, name)):
                raise ValueError(f"{name} must hold integers, got {getattr(self, name)!r}")
        if not (
            isinstance(self.smooth_weight, tuple)
            and self.smooth_weight
            and all(
                isinstance(c, int | float) and not isinstance(c, bool) and 0.0 <= c < math.inf
                for c in self.smooth_weight
            )
        ):
            raise ValueError(
                f"smooth_weight must be a non-empty tuple of finite numbers >= 0, got {self.smooth_weight!r}"
            )
        if not (isinstance(self.net_arch, tuple) and self.net_arch and set(self.net_arch) <= set(NET_ARCHS)):
            raise ValueError(
                f"net_arch must be a non-empty tuple of names among {sorted(NET_ARCHS)}, got {self.net_arch!r}"
            )
        for name in (
            "batch_size",
            "chunk_size",
            "history_len",
            "n_candidates",
            "n_target_candidates",
            "critic_embed_dim",
            "n_elite",
        ):
            choices = getattr(self, name)
            if not (
                isinstance(choices, tuple)
                and choices
                and all(isinstance(c, int) and not isinstance(c, bool) and c >= 1 for c in choices)
            ):
                raise ValueError(f"{name} must be a non-empty tuple of integers >= 1, got {choices!r}")
        if max(self.n_elite) > min(self.n_candidates):
            raise ValueError(
                f"n_elite must not exceed min(n_candidates)={min(self.n_candidates)}, got {self.n_elite!r}"
            )
        for name in ("discrete_entropy", "commit_discrete"):
            choices = getattr(self, name)
            if not (isinstance(choices, tuple) and choices and all(isinstance(c, bool) for c in choices)):
                raise ValueError(f"{name} must be a non-empty tuple of bools, got {choices!r}")
        if not (
            isinstance(self.online_targets, tuple)
            and self.online_targets
            and set(self.online_targets) <= set(ONLINE_TARGETS)
        ):
            raise ValueError(
                f"online_targets must be a non-empty tuple of values among {list(ONLINE_TARGETS)}, "
                f"got {self.online_targets!r}"
            )

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
        "one_minus_gamma": trial.suggest_float(
            "one_minus_gamma", 1.0 - space.gamma[1], 1.0 - space.gamma[0], log=True
        ),
        "learning_rate": trial.suggest_float("learning_rate", *space.learning_rate, log=True),
        "batch_size": trial.suggest_categorical("batch_size", space.batch_size),
        "tau": trial.suggest_float("tau", *space.tau, log=True),
        "chunk_size": trial.suggest_categorical("chunk_size", space.chunk_size),
        "history_len": trial.suggest_categorical("history_len", space.history_len),
        "flow_steps": trial.suggest_int("flow_steps", *space.flow_steps),
        "target_flow_steps": trial.suggest_int("target_flow_steps", *space.target_flow_steps),
        "n_candidates": trial.suggest_categorical("n_candidates", space.n_candidates),
        "n_target_candidates": trial.suggest_categorical("n_target_candidates", space.n_target_candidates),
        "entropy_threshold": trial.suggest_float("entropy_threshold", *space.entropy_threshold),
        "q_weight": trial.suggest_float("q_weight", *space.q_weight, log=True),
        "smooth_weight": trial.suggest_categorical("smooth_weight", space.smooth_weight),
        "net_arch": trial.suggest_categorical("net_arch", space.net_arch),
        "critic_embed_dim": trial.suggest_categorical("critic_embed_dim", space.critic_embed_dim),
        "discrete_entropy": trial.suggest_categorical("discrete_entropy", space.discrete_entropy),
        "commit_discrete": trial.suggest_categorical("commit_discrete", space.commit_discrete),
        "online_targets": trial.suggest_categorical("online_targets", space.online_targets),
        "n_elite": trial.suggest_categorical("n_elite", space.n_elite),
    }
    trial.set_user_attr("gamma", 1.0 - sampled["one_minus_gamma"])
    return convert_ua2c_params(sampled)


def convert_ua2c_params(sampled: dict[str, Any]) -> dict[str, Any]:
    """
    Turn sampled Optuna parameters into UA2C constructor arguments (rl-zoo3 ``HYPERPARAMS_CONVERTER``).

    :param sampled: ``trial.params`` of a UA2C trial
    :return: the same parameters with ``one_minus_gamma`` replaced by ``gamma`` and the policy's
        ``net_arch`` (a ``NET_ARCHS`` name), ``critic_embed_dim`` and ``n_elite`` moved into
        ``policy_kwargs``.
        As for every rl-zoo3 algorithm, a sampled ``policy_kwargs`` replaces the YAML one.
    """
    params = dict(sampled)
    if "one_minus_gamma" in params:
        params["gamma"] = 1.0 - params.pop("one_minus_gamma")
    policy_kwargs = {}
    if "net_arch" in params:
        name = params.pop("net_arch")
        if name not in NET_ARCHS:
            raise ValueError(f"net_arch must be one of {sorted(NET_ARCHS)}, got {name!r}")
        policy_kwargs["net_arch"] = list(NET_ARCHS[name])
    for name in ("critic_embed_dim", "n_elite"):
        if name in params:
            policy_kwargs[name] = params.pop(name)
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

    :param dataset: directory of a dataset written by ``python -m sb3_ua2c collect``
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
