"""The chunk critics of UA2C, by name: ``policy_kwargs["critic_arch"]`` picks a class of :data:`CRITICS`
and ``policy_kwargs["critic_kwargs"]`` holds that class's own arguments, whose defaults are in its
signature. The policy asks a critic for the call of :class:`ChunkCritic` only.

A new critic is one module with one class (docs/algorithm.md, "Adding a critic or an actor") and one
line in :data:`CRITICS`.
"""

from __future__ import annotations

import inspect
from typing import Any, Protocol

import torch as th
from torch import nn

from sb3_ua2c.critics.mlp import MLPChunkCritics
from sb3_ua2c.critics.transformer import ChunkCritics


class ChunkCritic(Protocol):
    """
    The interface of a critic class of :data:`CRITICS`: an ``nn.Module`` built as
    ``cls(obs_history_dim, chunk_size, action_dim, n_critics, activation_fn, **critic_kwargs)`` that values
    ``C`` chunks per history with its ``n_critics`` members in one call. It checks its own arguments
    (a ``ValueError`` naming ``critic_kwargs[...]``).
    """

    def __call__(self, obs_history: th.Tensor, chunks: th.Tensor) -> th.Tensor:
        """
        :param obs_history: flattened observation histories, ``(B, ℓ*obs_dim)``
        :param chunks: ``C`` chunks per history, ``(B, C, k, action_dim)``
        :return: Q-values, ``(n_critics, B, C)``
        """


#: the critics by ``critic_arch``: the paper's per-token Transformer, or Q-chunking's MLP
CRITICS: dict[str, type[nn.Module]] = {
    "transformer": ChunkCritics,
    "mlp": MLPChunkCritics,
}

#: the arguments every critic class takes before its own (the policy passes them)
_COMMON = ("self", "obs_history_dim", "chunk_size", "action_dim", "n_critics", "activation_fn")


def critic_class(critic_arch: str) -> type[nn.Module]:
    """
    :param critic_arch: a key of :data:`CRITICS`
    :return: its class
    """
    if not isinstance(critic_arch, str) or critic_arch not in CRITICS:
        raise ValueError(f"critic_arch must be one of {list(CRITICS)}, got {critic_arch!r}")
    return CRITICS[critic_arch]


def critic_defaults(critic_arch: str) -> dict[str, Any]:
    """
    The own arguments of a critic class and their defaults (its ``critic_kwargs`` when none are given).

    :param critic_arch: a key of :data:`CRITICS`
    :return: ``{name: default}``, in the signature's order
    """
    params = inspect.signature(critic_class(critic_arch).__init__).parameters
    return {name: p.default for name, p in params.items() if name not in _COMMON}


def make_critic(
    critic_arch: str,
    obs_history_dim: int,
    chunk_size: int,
    action_dim: int,
    n_critics: int,
    activation_fn: type[nn.Module],
    critic_kwargs: dict[str, Any] | None,
) -> nn.Module:
    """
    Build the critics of ``critic_arch`` with ``critic_kwargs``: ``(B, ℓ*obs_dim), (B, C, k, A) -> (n_critics, B, C)``.

    :param critic_arch: a key of :data:`CRITICS`
    :param obs_history_dim: ``ℓ * obs_dim``
    :param chunk_size: ``k``
    :param action_dim: action size
    :param n_critics: members of the ensemble
    :param activation_fn: activation class
    :param critic_kwargs: the class's own arguments (``None``: its defaults); an unknown key raises a
        ``ValueError`` naming it
    :return: the critics
    """
    own = critic_defaults(critic_arch)
    for key in critic_kwargs or {}:
        if key not in own:
            raise ValueError(f"unknown critic_kwargs key {key!r} for critic_arch={critic_arch!r}; allowed: {list(own)}")
    cls = critic_class(critic_arch)
    return cls(obs_history_dim, chunk_size, action_dim, n_critics, activation_fn, **(critic_kwargs or {}))


__all__ = ["CRITICS", "ChunkCritic", "ChunkCritics", "MLPChunkCritics", "critic_class", "critic_defaults", "make_critic"]
