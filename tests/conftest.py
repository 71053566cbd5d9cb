"""Shared test fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
TUM_RPY = SHARED / "data" / "tum_fr1_rpy"
HOLOLENS = SHARED / "data" / "hololens_dvmvs"


@pytest.fixture(scope="session")
def tum_rpy() -> Path:
    if not TUM_RPY.is_dir():
        pytest.skip("../shared/data/tum_fr1_rpy is not present")
    return TUM_RPY


@pytest.fixture(scope="session")
def hololens() -> Path:
    if not HOLOLENS.is_dir():
        pytest.skip("../shared/data/hololens_dvmvs is not present")
    return HOLOLENS


def pytest_configure(config):
    # The tests use tiny tensors, for which one intra-op thread is fastest; on a shared 2-core machine
    # torch's default of 2 threads made the SfM tests up to 10x slower (measured 7-10 s vs 70-85 s).
    import torch

    torch.set_num_threads(1)
