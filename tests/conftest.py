import os

import pytest
import torch

# Tests are small; one thread keeps them fast and deterministic on 2-core machines.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(autouse=True)
def _seed_torch():
    torch.manual_seed(0)
