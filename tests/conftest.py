import os

import gymnasium as gym
import pytest
import torch

# Tests are small; one thread keeps them fast and deterministic on 2-core machines.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(autouse=True)
def _seed_torch():
    torch.manual_seed(0)


@pytest.fixture
def make_env():
    """Factory of ``MixedTraffic-v0`` envs, all closed at teardown (libsumo: one live simulation per process)."""
    import envs  # noqa: F401  (registers MixedTraffic-v0)

    created = []

    def factory(**kwargs):
        env = gym.make("MixedTraffic-v0", **kwargs)
        created.append(env)
        return env

    yield factory
    for env in created:
        env.close()


#: Module-scoped fixtures that run a whole experiment (Figure 2, the head-to-head) in quick mode:
#: 10-15 s on 2 cores, so every test that uses one is ``slow`` (``make test`` leaves them to CI).
SLOW_FIXTURES = frozenset({"quick_run"})


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if SLOW_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)
