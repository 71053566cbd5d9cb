"""Pinhole projection functions: Jacobians against autograd, round trips, pixel grid convention."""

import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch.autograd.functional import jacobian

from codeslam.geometry.camera import (
    PinholeCamera,
    pixel_grid,
    project,
    project_jac,
    unproject,
    unproject_jac_depth,
)

F64 = torch.float64
PARAMS = torch.tensor([525.0, 520.0, 319.5, 239.5], dtype=F64)


def _points(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    xy = torch.randn(n, 2, generator=g, dtype=F64)
    z = torch.rand(n, 1, generator=g, dtype=F64) * 5 + 0.2
    return torch.cat([xy, z], dim=-1)


def _diag(J: torch.Tensor) -> torch.Tensor:
    """(N, m, N, n) full Jacobian of a row-wise function -> (N, m, n)."""
    return torch.diagonal(J, dim1=0, dim2=2).permute(2, 0, 1)


def test_project_jac_against_autograd():
    xyz = _points(40, 0)
    J = _diag(jacobian(lambda x: project(x, PARAMS), xyz))
    assert torch.allclose(project_jac(xyz, PARAMS), J, atol=1e-10)


def test_project_jac_channels_first_is_the_same_jacobian():
    params = torch.stack([PARAMS, PARAMS * 0.5])[:, None]  # (2, 1, 4): one camera per batch element
    xyz = _points(14, 5).reshape(2, 7, 3)
    rows = project_jac(xyz, params)  # (2, 7, 2, 3)
    columns = project_jac(xyz.transpose(1, 2).contiguous(), params, dim=-2)  # (2, 2, 3, 7)
    assert columns.shape == (2, 2, 3, 7)
    assert torch.equal(columns, rows.permute(0, 2, 3, 1))


def test_unproject_jac_depth_against_autograd():
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(40, 2, generator=g, dtype=F64) * torch.tensor([640.0, 480.0], dtype=F64)
    depth = torch.rand(40, generator=g, dtype=F64) * 5 + 0.1
    J = jacobian(lambda d: unproject(uv, d, PARAMS), depth)  # (40, 3, 40)
    J = torch.diagonal(J, dim1=0, dim2=2).T  # (40, 3)
    assert torch.allclose(unproject_jac_depth(uv, PARAMS), J, atol=1e-12)


def test_params_broadcast_per_batch_camera():
    params = torch.stack([PARAMS, PARAMS * 0.5])  # (2, 4)
    xyz = _points(14, 2).reshape(2, 7, 3)
    uv = project(xyz, params[:, None])  # (2, 7, 2)
    assert uv.shape == (2, 7, 2)
    assert torch.allclose(uv[1], project(xyz[1], params[1]))
    assert project_jac(xyz, params[:, None]).shape == (2, 7, 2, 3)


def test_params_match_the_camera_matrix():
    cam = PinholeCamera(fx=500.0, fy=480.0, cx=300.0, cy=200.0, width=640, height=480)
    xyz = _points(10, 3)
    uvw = xyz @ cam.K(F64).T
    assert torch.allclose(project(xyz, cam.params(F64)), uvw[:, :2] / uvw[:, 2:], atol=1e-10)


def test_pixel_grid_convention():
    grid = pixel_grid(3, 4, F64)
    assert grid.shape == (3, 4, 2)
    assert grid[0, 0].tolist() == [0.0, 0.0]
    assert grid[2, 1].tolist() == [1.0, 2.0]  # (u = column, v = row)
    # The principal point projects straight ahead.
    assert torch.allclose(unproject(PARAMS[2:], torch.tensor(2.0, dtype=F64), PARAMS),
                          torch.tensor([0.0, 0.0, 2.0], dtype=F64))


@settings(max_examples=50, deadline=None)
@given(
    fx=st.floats(10, 2000), fy=st.floats(10, 2000), cx=st.floats(-10, 700), cy=st.floats(-10, 500),
    u=st.floats(-100, 800), v=st.floats(-100, 600), depth=st.floats(1e-3, 1e3),
)
def test_unproject_project_round_trip_property(fx, fy, cx, cy, u, v, depth):
    params = torch.tensor([fx, fy, cx, cy], dtype=F64)
    uv = torch.tensor([u, v], dtype=F64)
    xyz = unproject(uv, torch.tensor(depth, dtype=F64), params)
    assert torch.isclose(xyz[2], torch.tensor(depth, dtype=F64))
    assert torch.allclose(project(xyz, params), uv, atol=1e-8, rtol=1e-10)
