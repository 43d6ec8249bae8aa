"""The base of every harness budget, whose fields one table checks (:attr:`Budget.CHECKS`), and the checks."""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

from sb3_ua2c.checks import check_int
from sb3_ua2c.defaults import defaults

#: ``check(label, value)`` raises ``ValueError`` naming ``label`` when ``value`` is bad
Check = Callable[[str, Any], None]


def integer(low: int = 1, high: int | None = None) -> Check:
    """An int (not a bool) in ``[low, high]``."""
    def check(label: str, value: Any) -> None:
        check_int(label, value, low=low)
        if high is not None and value > high:
            raise ValueError(f"{label} must be <= {high} (seed ranges), got {value!r}")
    return check


def optional(inner: Check) -> Check:
    """``None`` or a value ``inner`` accepts."""
    return lambda label, value: None if value is None else inner(label, value)


def each(inner: Check) -> Check:
    """A sequence whose every item ``inner`` accepts."""
    def check(label: str, value: Any) -> None:
        for item in value:
            inner(label, item)
    return check


def flag(label: str, value: Any) -> None:
    """A JSON bool (the budget is written to JSON)."""
    if not isinstance(value, bool):
        raise ValueError(f"{label} must be a bool, got {value!r}")


def mapping(label: str, value: Any) -> None:
    if not isinstance(value, Mapping):
        raise ValueError(f"{label} must be a mapping, got {value!r}")


def finite(label: str, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{label} must be a finite number, got {value!r}")


def one_of(*options: Any) -> Check:
    def check(label: str, value: Any) -> None:
        if value not in options:
            raise ValueError(f"{label} must be one of {list(options)}, got {value!r}")
    return check


def reserved_keys(*keys: str, why: str) -> Check:
    """A mapping that sets none of ``keys`` (``why``: who sets them instead)."""
    def check(label: str, value: Any) -> None:
        mapping(label, value)
        clash = sorted(set(keys) & set(value))
        if clash:
            raise ValueError(f"{label} must not set {clash}: {why}")
    return check


@dataclasses.dataclass(frozen=True)
class Budget:
    """Base of the harness budgets (see the module docstring)."""

    CHECKS: ClassVar[Mapping[str, Check]] = {}

    def __post_init__(self) -> None:
        name = type(self).__name__
        for field, check in self.CHECKS.items():
            check(f"{name}.{field}", getattr(self, field))
        for f in dataclasses.fields(self):  # plain containers: tuples and dicts, never the caller's objects
            value = getattr(self, f.name)
            if isinstance(value, Mapping):
                object.__setattr__(self, f.name, {k: dict(v) if isinstance(v, Mapping) else v for k, v in value.items()})
            elif isinstance(value, list):
                object.__setattr__(self, f.name, tuple(value))
        self.validate()

    def validate(self) -> None:
        """Rules across fields (a subclass's); may normalise fields with ``object.__setattr__``."""

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Budget:
        """Build from JSON: a nested budget from its dict, ``"inf"`` as infinity; an unknown key raises."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(values) - names
        if unknown:
            raise ValueError(f"unknown {cls.__name__} key(s) {sorted(unknown)}; valid: {sorted(names)}")
        hints = typing.get_type_hints(cls)
        out = dict(values)
        for key, value in values.items():
            kind = hints[key]
            if isinstance(kind, type) and issubclass(kind, Budget) and isinstance(value, Mapping):
                out[key] = kind.from_dict(value)
            elif isinstance(value, list):
                out[key] = tuple(math.inf if v == "inf" else v for v in value)
        return cls(**out)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the fields: the inverse of :meth:`from_dict`."""
        def plain(value: Any) -> Any:
            if isinstance(value, Budget):
                return value.to_dict()
            if isinstance(value, tuple):
                return list(value)
            if isinstance(value, Mapping):
                return {k: plain(v) for k, v in value.items()}
            return value
        return {f.name: plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    def replace(self, **changes: Any) -> Budget:
        """A copy with ``changes`` applied, checked like :meth:`from_dict`."""
        return type(self).from_dict({**self.to_dict(), **changes})


def library_default(name: str) -> Any:
    """UA2C's default of hyperparameter ``name`` (:func:`sb3_ua2c.defaults.defaults`)."""
    return defaults()[name]

