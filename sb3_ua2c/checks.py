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


def check_number(name: str, value: Any, low: float, high: float, *, open_low: bool, open_high: bool) -> None:
    """
    Raise ``ValueError`` naming ``name`` unless ``value`` is a real number (not a ``bool``, not NaN) in
    the interval from ``low`` to ``high``.

    :param name: the parameter's name as the user wrote it (e.g. ``"critic_target_kwargs['expectile']"``)
    :param value: the value to check
    :param low: lower bound
    :param high: upper bound (``math.inf``: none)
    :param open_low: ``low`` itself is refused
    :param open_high: ``high`` itself is refused
    """
    ok = not isinstance(value, bool) and isinstance(value, int | float | np.number) and value == value
    if ok:
        ok = (low < value if open_low else low <= value) and (value < high if open_high else value <= high)
    if not ok:
        interval = f"{'(' if open_low else '['}{low}, {high}{')' if open_high else ']'}"
        raise ValueError(f"{name} must be a number in {interval}, got {value!r}")
