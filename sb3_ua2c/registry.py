"""Plug-ins chosen by name: a registry is a ``{name: class}`` table, and a class's own arguments, with
their defaults in its signature (their one home), are given as a ``<kind>_kwargs`` dict. The critic
targets (:mod:`sb3_ua2c.targets`), the actor extractions (:mod:`sb3_ua2c.extraction`) and the
exploration rules (:mod:`sb3_ua2c.exploration`) are built here; the critics (:mod:`sb3_ua2c.critics`)
follow the same pattern with the arguments the policy passes first.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any


def registered(registry: Mapping[str, type], name: Any, param: str) -> type:
    """
    :param registry: ``{name: class}``
    :param name: a key of ``registry``
    :param param: the argument that names it (e.g. ``"critic_target"``), for the error
    :return: its class; an unknown name raises a ``ValueError`` naming ``param``
    """
    if not isinstance(name, str) or name not in registry:
        raise ValueError(f"{param} must be one of {list(registry)}, got {name!r}")
    return registry[name]


def own_defaults(cls: type) -> dict[str, Any]:
    """
    The own arguments of a plug-in class and their defaults (its ``<kind>_kwargs`` when none are given).

    :param cls: a class whose constructor takes keyword arguments with defaults only
    :return: ``{name: default}``, in the signature's order
    """
    params = inspect.signature(cls.__init__).parameters  # type: ignore[misc]
    named = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)  # not object's *args
    return {name: p.default for name, p in params.items() if name != "self" and p.kind in named}


def build(registry: Mapping[str, type], name: Any, kwargs: Mapping[str, Any] | None, param: str) -> Any:
    """
    Build the plug-in ``name`` of ``registry`` with its own arguments ``kwargs``.

    :param registry: ``{name: class}``
    :param name: a key of ``registry`` (else a ``ValueError`` naming ``param``)
    :param kwargs: the class's own arguments (``None``: its defaults); an unknown key raises a
        ``ValueError`` naming ``<param>_kwargs``, and the class checks the values
    :param param: the argument that names the plug-in (``"critic_target"``, ``"actor_extraction"``, ...)
    :return: the instance
    """
    cls = registered(registry, name, param)
    if kwargs is not None and not isinstance(kwargs, Mapping):
        raise ValueError(f"{param}_kwargs must be a dict or None, got {kwargs!r}")
    own = own_defaults(cls)
    for key in kwargs or {}:
        if key not in own:
            raise ValueError(f"unknown {param}_kwargs key {key!r} for {param}={name!r}; allowed: {list(own)}")
    return cls(**(kwargs or {}))


def resolved_kwargs(
    registry: Mapping[str, type], name: str, kwargs: Mapping[str, Any] | None
) -> dict[str, Any]:
    """``kwargs`` with the class's signature defaults filled in (what a model stores and saves)."""
    return {**own_defaults(registry[name]), **(kwargs or {})}


__all__ = ["build", "own_defaults", "registered", "resolved_kwargs"]
