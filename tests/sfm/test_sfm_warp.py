"""Warping (paper Eq. 5) and its Jacobians (Eqs. 7-9, SE(3) left form, adjoint chain) against autograd."""

from __future__ import annotations

import torch
from sfm_scene import look_pose, render

from codeslam.geometry.camera import canonical_camera, project, unproject
from codeslam.geometry.lie import se3_act, se3_exp, se3_inverse
from codeslam.sfm.warp import (
    cross_columns,
    point_jacobians,
    pose_columns,
    relative_pose,
    relative_pose_jacobians,
    warp,
    warp_jacobians,
)

D = torch.float64


def _random_setup(P=3, N=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    T_BA = se3_exp(0.3 * torch.randn(P, 6, generator=g, dtype=D))
    uv = torch.rand(P, N, 2, generator=g, dtype=D) * torch.tensor([40.0, 30.0], dtype=D)
    depth = 1.0 + 3.0 * torch.rand(P, N, generator=g, dtype=D)
    params = torch.tensor([35.0, 36.0, 19.5, 14.5], dtype=D)
    return T_BA, uv, depth, params


def test_warp_is_projection_of_transformed_unprojection():
    T_BA, uv, depth, params = _random_setup()
    v, x, ray = warp(uv, depth, T_BA, params, params)
    x_ref = se3_act(T_BA, unproject(uv, depth, params))
    torch.testing.assert_close(x, x_ref)
    torch.testing.assert_close(v, project(x_ref, params))
    torch.testing.assert_close(ray * depth[..., None], unproject(uv, depth, params))


def test_warp_maps_a_pixel_to_where_b_sees_the_same_surface_point():
    cam = canonical_camera(40, 30)
    params = cam.params(D)
    T_wA, T_wB = look_pose(), look_pose((0.2, -0.05, 0.1), (0.03, -0.05, 0.02))
    _, depth_A = render(T_wA, params, 30, 40, panel=False)
    _, depth_B = render(T_wB, params, 30, 40, panel=False)
    uv = torch.stack(torch.meshgrid(torch.arange(40, dtype=D), torch.arange(30, dtype=D), indexing="xy"), -1)
    uv = uv.reshape(1, -1, 2)
    v, x, _ = warp(uv, depth_A.reshape(1, -1), relative_pose(T_wA, T_wB)[None], params, params)
    inside = (v[0, :, 0] > 1) & (v[0, :, 0] < 38) & (v[0, :, 1] > 1) & (v[0, :, 1] < 28)
    # B's depth at the nearest pixel of v agrees with the warped point's depth (no occluders without the panel).
    vi = v[0, inside].round().long()
    zb = depth_B[vi[:, 1], vi[:, 0]]
    rel = ((x[0, inside, 2] - zb).abs() / zb).median()
    assert inside.sum() > 600 and rel < 0.02


def test_point_jacobians_match_autograd():
    T_BA, uv, depth, params = _random_setup()
    _, x, ray = warp(uv, depth, T_BA, params, params)
    dx_dxi, dx_dd = point_jacobians(x, ray, T_BA)
    for p in range(T_BA.shape[0]):
        def f(xi, p=p):
            return se3_act(se3_exp(xi) @ T_BA[p], ray[p] * depth[p, :, None])  # (N, 3), left perturbation
        J = torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=D))  # (N, 3, 6)
        torch.testing.assert_close(dx_dxi[p], J)

        def g(d, p=p):
            return se3_act(T_BA[p], ray[p] * d[:, None])
        Jd = torch.autograd.functional.jacobian(g, depth[p])  # (N, 3, N)
        torch.testing.assert_close(dx_dd[p], torch.diagonal(Jd, dim1=0, dim2=2).T)


def test_warp_jacobians_match_autograd():
    T_BA, uv, depth, params = _random_setup(P=2, N=5, seed=1)
    _, x, ray = warp(uv, depth, T_BA, params, params)
    dv_dxi, dv_dd, _ = warp_jacobians(x, ray, T_BA, params)
    for p in range(2):
        def f(xi, p=p):
            return warp(uv[p:p + 1], depth[p:p + 1], se3_exp(xi)[None] @ T_BA[p:p + 1], params, params)[0][0]
        torch.testing.assert_close(dv_dxi[p], torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=D)))

        def g(d, p=p):
            return warp(uv[p:p + 1], d[None], T_BA[p:p + 1], params, params)[0][0]
        Jd = torch.autograd.functional.jacobian(g, depth[p])  # (N, 2, N)
        torch.testing.assert_close(dv_dd[p], torch.diagonal(Jd, dim1=0, dim2=2).T)


def test_relative_pose_jacobians_are_the_adjoint_chain():
    g = torch.Generator().manual_seed(3)
    T_wA, T_wB = se3_exp(torch.randn(2, 6, generator=g, dtype=D))
    dA, dB = relative_pose_jacobians(T_wB)
    T_BA = relative_pose(T_wA, T_wB)
    # xi_BA(xi) = log(T_BA(perturbed) T_BA^-1); its derivative at 0 is the chain-rule matrix.
    from codeslam.geometry.lie import se3_log

    def rel_A(xi):
        return se3_log(relative_pose(se3_exp(xi) @ T_wA, T_wB) @ se3_inverse(T_BA))

    def rel_B(xi):
        return se3_log(relative_pose(T_wA, se3_exp(xi) @ T_wB) @ se3_inverse(T_BA))
    zero = torch.zeros(6, dtype=D)
    torch.testing.assert_close(dA, torch.autograd.functional.jacobian(rel_A, zero))
    torch.testing.assert_close(dB, torch.autograd.functional.jacobian(rel_B, zero))


def test_cross_columns_is_the_cross_product_over_the_channel_dimension():
    g = torch.Generator().manual_seed(6)
    a = torch.randn(2, 3, 7, generator=g, dtype=D)
    b = torch.randn(2, 3, 7, generator=g, dtype=D)
    omega = torch.randn(2, 3, 1, generator=g, dtype=D)  # one vector per batch element, broadcast over the points
    torch.testing.assert_close(cross_columns(a, b), torch.linalg.cross(a, b, dim=-2))
    torch.testing.assert_close(cross_columns(a, omega), torch.linalg.cross(a, omega.expand_as(a), dim=-2))
    out = torch.full((2, 6, 7), float("nan"), dtype=D)
    assert cross_columns(b, a, out=out[:, 3:]).data_ptr() == out[:, 3:].data_ptr()  # written in place
    torch.testing.assert_close(out[:, 3:], torch.linalg.cross(b, a, dim=-2))
    assert out[:, :3].isnan().all()  # and nowhere else


def test_pose_columns_equal_a_row_times_the_point_jacobian():
    T_BA, uv, depth, params = _random_setup(seed=4)
    _, x, ray = warp(uv, depth, T_BA, params, params)
    dx_dxi, _ = point_jacobians(x, ray, T_BA)
    a = torch.randn(x.shape, generator=torch.Generator().manual_seed(5), dtype=D)
    out = torch.empty(x.shape[0], 6, x.shape[1], dtype=D)  # (P, 6, N) columns
    pose_columns(a.transpose(1, 2), x.transpose(1, 2), out)
    torch.testing.assert_close(out.transpose(1, 2), (a.unsqueeze(-2) @ dx_dxi).squeeze(-2))
