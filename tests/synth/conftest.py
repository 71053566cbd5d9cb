"""Fixtures of the synthetic-data tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Render with one torch thread, as the synth CLI and its workers do (the renderer's cache-sized
    tensor chunks only lose from intra-op threads); the previous setting is restored afterwards."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
