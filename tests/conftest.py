"""Shared test fixtures."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
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


@pytest.fixture(scope="session")
def script():
    """``script(name)``: the module ``scripts/NAME.py`` (the scripts are not a package), registered in
    ``sys.modules`` while it runs, as its dataclasses look their module up."""

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        finally:
            del sys.modules[name]
        return module

    return load


def pytest_configure(config):
    # The tests use tiny tensors, for which one intra-op thread is fastest; on a shared 2-core machine
    # torch's default of 2 threads made the SfM tests up to 10x slower (measured 7-10 s vs 70-85 s).
    import torch

    torch.set_num_threads(1)
