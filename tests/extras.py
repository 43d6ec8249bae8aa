"""Optional extras in tests: CI installs every extra, so a missing one fails there; on a developer
machine without it the test is skipped with the install command."""

import importlib
import os
from types import ModuleType

import pytest

#: the command that installs each optional module (d3rlpy pins an old gym, so it goes in without its deps)
INSTALL = {
    "d3rlpy": "pip install -e '.[peers]' && pip install --no-deps d3rlpy==2.8.1 gym==0.26.2",
    "rliable": "pip install -e '.[peers]'",
    "ray": "pip install -e '.[peers]'",
    "ogbench": "pip install -e '.[ogbench]'",
    "sphinx": "pip install -e '.[docs]'",
}


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in {"1", "true", "yes"}


def unavailable(reason: str) -> None:
    """Fail under CI (which installs every extra and system package the tests use), skip elsewhere."""
    if in_ci():
        pytest.fail(f"CI must run this test: {reason}")
    pytest.skip(reason, allow_module_level=True)


def require(module: str) -> ModuleType:
    """Import ``module`` or fail (under CI) / skip (elsewhere) naming the extra that provides it."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        unavailable(f"{module} is missing: {INSTALL.get(module, f'pip install {module}')} ({error})")
