"""Argument checks shared by the configuration classes and entry points: a bad value raises a
``ValueError`` that names the parameter."""

from __future__ import annotations

from typing import Any

import numpy as np


def check_int(name: str, value: Any, low: int = 1) -> None:
    """
    Raise ``ValueError`` naming ``name`` unless ``value`` is an integer ``>= low``.

    ``bool`` is refused (``True`` is an ``int`` in Python); NumPy integers are accepted.

    :param name: the parameter's name as the user wrote it (e.g. ``"Fig2Budget.seeds"``)
    :param value: the value to check
    :param low: smallest allowed value
    """
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")


def check_bool(name: str, value: Any) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a ``bool`` (NumPy bools accepted)."""
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be a bool, got {value!r}")


def check_net_arch(name: str, value: Any) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``value`` is a non-empty list of positive integers."""
    if isinstance(value, str) or not hasattr(value, "__len__") or not value or any(
        isinstance(h, bool) or not isinstance(h, int | float | np.number) or int(h) != h or h < 1 for h in value
    ):
        raise ValueError(f"{name} must be a non-empty list of positive integers, got {value!r}")
