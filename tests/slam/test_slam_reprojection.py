"""The reprojection term: analytic Jacobians against autograd in float64, its normal equations against the dense
J^T W J, and a pose recovered from matched points by the solver with this term alone."""

from __future__ import annotations

import torch

from codeslam.geometry.camera import canonical_camera, project
from codeslam.geometry.lie import se3_act, se3_exp, se3_inverse
from codeslam.sfm.variables import POSE, BlockId, SfMState, VariableLayout
from codeslam.slam.reprojection import ReprojectionTerm

D = torch.float64


def _problem(seed: int = 0, n: int = 40, noise: float = 0.0):
    g = torch.Generator().manual_seed(seed)
    cam = canonical_camera(256, 192)
    T_wA = se3_exp(0.3 * torch.randn(6, generator=g, dtype=D))
    T_wB = se3_exp(torch.tensor([0.1, -0.05, 0.08, 0.05, -0.08, 0.03], dtype=D)) @ T_wA
    uv = torch.rand(n, 2, generator=g, dtype=D) * torch.tensor([255.0, 191.0], dtype=D)
    z = 1.0 + 3.0 * torch.rand(n, generator=g, dtype=D)
    xyz_a = torch.stack([(uv[:, 0] - cam.cx) / cam.fx * z, (uv[:, 1] - cam.cy) / cam.fy * z, z], 1)
    T_BA = se3_inverse(T_wB) @ T_wA
    uv_b = project(se3_act(T_BA, xyz_a), cam.params(D)) + noise * torch.randn(n, 2, generator=g, dtype=D)
    term = ReprojectionTerm(0, 1, xyz_a, uv_b, torch.full((n,), 1.5, dtype=D), cam)
    state = SfMState(torch.stack([T_wA, T_wB]), torch.zeros(2, 1, dtype=D), torch.zeros(0, 2, dtype=D))
    return term, state


def test_jacobians_match_autograd_float64():
    term, state = _problem()
    # Move the poses off the optimum so the residuals are not zero.
    state.poses[1] = se3_exp(torch.tensor([0.02, 0.01, -0.03, 0.01, 0.02, -0.01], dtype=D)) @ state.poses[1]
    r, J_A, J_B, _ = term.jacobians(state)
    for k, J in ((0, J_A), (1, J_B)):
        def f(xi, k=k):
            poses = state.poses.clone()
            poses[k] = se3_exp(xi) @ state.poses[k]
            return term.residuals(SfMState(poses, state.codes, state.affine))[0]

        J_auto = torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=D))  # (N, 2, 6)
        assert torch.allclose(J, J_auto, atol=1e-9, rtol=1e-7), (k, (J - J_auto).abs().max())
    assert r.abs().max() > 0.5  # the check ran away from the optimum


def test_normal_equations_equal_dense_irls_and_cost_decreases():
    term, state = _problem(seed=1, noise=0.5)
    state.poses[1] = se3_exp(torch.tensor([0.05, 0.0, 0.0, 0.0, 0.03, 0.0], dtype=D)) @ state.poses[1]
    layout = VariableLayout([(BlockId(POSE, 0), 6), (BlockId(POSE, 1), 6)])
    H = torch.zeros(12, 12, dtype=D)
    g = torch.zeros(12, dtype=D)
    term.add_to(H, g, layout, state)
    r, J_A, J_B, w = term.jacobians(state)
    J = torch.cat([J_A, J_B], -1).reshape(-1, 12)  # (2N, 12)
    W = w.repeat_interleave(2)
    assert torch.allclose(H, J.T @ (W[:, None] * J), atol=1e-8)
    assert torch.allclose(g, J.T @ (W * r.reshape(-1)), atol=1e-8)
    # A Gauss-Newton step on B alone lowers the cost.
    sl = layout.slice(BlockId(POSE, 1))
    step = -torch.linalg.solve(H[sl, sl], g[sl])
    moved = state.clone()
    moved.poses[1] = se3_exp(step) @ state.poses[1]
    assert float(term.cost(moved)) < 0.5 * float(term.cost(state))


def test_points_behind_the_camera_cost_a_constant_and_give_no_gradient():
    term, state = _problem(seed=2, n=10)
    term.xyz_a[:3, 2] *= -1.0  # three points behind A, hence behind B too
    r, J_A, J_B, w = term.jacobians(state)
    assert bool((w[:3] == 0).all()) and bool((w[3:] > 0).all())
    assert torch.isfinite(term.cost(state))


def test_decoded_points_jacobians_match_autograd_float64():
    from codeslam.geometry.proximity import depth_to_prox
    from codeslam.slam.reprojection import DecodedReprojectionTerm

    term, state = _problem(seed=3, n=25)
    g = torch.Generator().manual_seed(5)
    C = 6
    z = term.xyz_a[:, 2]
    ray = term.xyz_a / z[:, None]
    jac = 0.02 * torch.randn(C, len(term), generator=g, dtype=D)
    dec = DecodedReprojectionTerm(0, 1, term.xyz_a, term.uv_b, term.sigma, term.camera, ray_a=ray,
                                  prox0=depth_to_prox(z, 1.5), jac=jac, avg_depth=1.5)
    state = SfMState(state.poses.clone(), 0.3 * torch.randn(2, C, generator=g, dtype=D), state.affine)
    state.poses[1] = se3_exp(torch.tensor([0.02, 0.01, -0.03, 0.01, 0.02, -0.01], dtype=D)) @ state.poses[1]
    r, w, blocks = dec.blocks(state)
    J = dict((b.kind + str(b.index), Jb) for b, Jb in blocks)

    def res(poses, codes):
        return dec.residuals(SfMState(poses, codes, state.affine))[0]

    for k in (0, 1):
        def f(xi, k=k):
            poses = state.poses.clone()
            poses[k] = se3_exp(xi) @ state.poses[k]
            return res(poses, state.codes)

        J_auto = torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=D))
        assert torch.allclose(J[f"pose{k}"], J_auto, atol=1e-9, rtol=1e-7)

    def fc(c):
        codes = state.codes.clone()
        codes[0] = c
        return res(state.poses, codes)

    J_auto = torch.autograd.functional.jacobian(fc, state.codes[0].clone())  # (N, 2, C)
    assert torch.allclose(J["code0"], J_auto, atol=1e-9, rtol=1e-7), (J["code0"] - J_auto).abs().max()
    assert float(J_auto.abs().max()) > 1e-3  # the code moves the points


def _decoded_pairs(seed: int = 7, C: int = 5):
    """Decoded pair terms among three frames with different match counts (one point behind the cameras), and a
    state away from their optimum."""
    from codeslam.geometry.proximity import depth_to_prox
    from codeslam.slam.reprojection import DecodedReprojectionTerm

    g = torch.Generator().manual_seed(seed)
    cam = canonical_camera(256, 192)
    poses = torch.stack([se3_exp(0.1 * torch.randn(6, generator=g, dtype=D)) for _ in range(3)])
    terms = []
    for (a, b), n in zip(((0, 1), (1, 0), (2, 1), (0, 2)), (9, 4, 13, 6)):
        uv = torch.rand(n, 2, generator=g, dtype=D) * torch.tensor([255.0, 191.0], dtype=D)
        z = 1.0 + 3.0 * torch.rand(n, generator=g, dtype=D)
        ray = torch.stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, torch.ones_like(z)], 1)
        X = ray * z[:, None]
        x = se3_act(se3_inverse(poses[b]) @ poses[a], X)
        uv_b = project(x, cam.params(D)) + torch.randn(n, 2, generator=g, dtype=D)
        jac = 0.02 * torch.randn(C, n, generator=g, dtype=D)
        terms.append(DecodedReprojectionTerm(a, b, X, uv_b, 1.0 + torch.rand(n, generator=g, dtype=D), cam,
                                             ray_a=ray, prox0=depth_to_prox(z, 1.2 + a), jac=jac,
                                             avg_depth=1.2 + a))
    terms[2].ray_a[0] *= -1.0  # a point behind A, hence behind B
    codes = 0.3 * torch.randn(3, C, generator=g, dtype=D)
    moved = poses.clone()
    moved[1] = se3_exp(torch.tensor([0.03, -0.02, 0.01, 0.02, -0.01, 0.015], dtype=D)) @ poses[1]
    return terms, SfMState(moved, codes, torch.zeros(0, 2, dtype=D))


def test_stacked_pairs_are_the_sum_of_their_pair_terms():
    """The window's one-pass keypoint term gives each pair's cost, gradient and J^T W J, with fixed blocks left
    out, exactly as the pair terms summed."""
    from codeslam.sfm.variables import CODE
    from codeslam.slam.reprojection import StackedReprojectionTerm

    terms, state = _decoded_pairs()
    C = state.codes.shape[1]
    stacked = StackedReprojectionTerm(terms + [terms[0].__class__(1, 2, terms[0].xyz_a[:0], terms[0].uv_b[:0],
                                                                  terms[0].sigma[:0], terms[0].camera,
                                                                  ray_a=terms[0].ray_a[:0],
                                                                  prox0=terms[0].prox0[:0],
                                                                  jac=terms[0].jac[:, :0], avg_depth=1.0)])
    assert len(stacked) == sum(len(t) for t in terms) and stacked.num_pairs == 4  # the empty pair is dropped
    assert torch.allclose(stacked.cost(state), sum(t.cost(state) for t in terms), rtol=1e-12)
    full = [(BlockId(POSE, i), 6) for i in range(3)] + [(BlockId(CODE, i), C) for i in range(3)]
    for layout in (VariableLayout(full), VariableLayout([b for b in full if b[0] not in
                                                         (BlockId(POSE, 0), BlockId(CODE, 2))])):
        H1, g1 = torch.zeros(layout.dim, layout.dim, dtype=D), torch.zeros(layout.dim, dtype=D)
        H2, g2 = H1.clone(), g1.clone()
        for t in terms:
            t.add_to(H1, g1, layout, state)
        stacked.add_to(H2, g2, layout, state)
        assert float(H1.abs().max()) > 1.0
        assert torch.allclose(H2, H1, rtol=1e-10, atol=1e-9), (H2 - H1).abs().max()
        assert torch.allclose(g2, g1, rtol=1e-10, atol=1e-9), (g2 - g1).abs().max()
    # The point behind the cameras costs the constant and gets no weight, in both.
    _, _, w = stacked.jacobians(state)
    assert int((w == 0).sum()) == 1 == sum(int((t.jacobians(state)[3] == 0).sum()) for t in terms)


def test_stacked_pairs_jacobians_match_autograd_float64():
    from codeslam.slam.reprojection import StackedReprojectionTerm

    terms, state = _decoded_pairs(seed=8)
    stacked = StackedReprojectionTerm(terms)
    _, J, _ = stacked.jacobians(state)  # (N, 2, 12 + C) over [pose A, pose B, code A] of each match's pair
    a, b = stacked.a[stacked.pid], stacked.b[stacked.pid]

    def res(poses, codes):
        return stacked._residuals(SfMState(poses, codes, state.affine))[0]

    for k in range(3):
        def f(xi, k=k):
            poses = state.poses.clone()
            poses[k] = se3_exp(xi) @ state.poses[k]
            return res(poses, state.codes)

        def fc(c, k=k):
            codes = state.codes.clone()
            codes[k] = c
            return res(state.poses, codes)

        J_pose = torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=D))  # (N, 2, 6)
        J_code = torch.autograd.functional.jacobian(fc, state.codes[k].clone())  # (N, 2, C)
        expect = torch.where((a == k)[:, None, None], J[..., :6], 0) + torch.where((b == k)[:, None, None],
                                                                                   J[..., 6:12], 0)
        assert torch.allclose(expect, J_pose, atol=1e-9, rtol=1e-7), (k, (expect - J_pose).abs().max())
        expect_c = torch.where((a == k)[:, None, None], J[..., 12:], 0)
        assert torch.allclose(expect_c, J_code, atol=1e-9, rtol=1e-7), (k, (expect_c - J_code).abs().max())
        assert float(J_code.abs().max()) > 1e-3 or not bool((a == k).any())


def test_stacked_pairs_with_a_scale_entry_match_autograd_float64():
    """With the codes' last entry a log scale of A's depth (``window.free_scale``), the keypoints' gradient over
    poses, codes and scales equals autograd's of their cost; the depth is scaled exactly."""
    from codeslam.sfm.autodiff import retract_differentiable
    from codeslam.sfm.variables import CODE
    from codeslam.slam.reprojection import StackedReprojectionTerm

    terms, state = _decoded_pairs(seed=9, C=5)
    for t in terms:  # a placeholder row for the scale entry in each term's sampled Jacobian
        t.jac = torch.cat([t.jac, torch.zeros_like(t.jac[:1])])
    scales = torch.tensor([[0.2], [-0.1], [0.35]], dtype=D)
    state = SfMState(state.poses, torch.cat([state.codes, scales], 1), state.affine)
    stacked = StackedReprojectionTerm(terms, scaled=True)
    layout = VariableLayout([(BlockId(POSE, i), 6) for i in range(3)] + [(BlockId(CODE, i), 6) for i in range(3)])
    H, g = torch.zeros(layout.dim, layout.dim, dtype=D), torch.zeros(layout.dim, dtype=D)
    stacked.add_to(H, g, layout, state)
    delta = torch.zeros(layout.dim, dtype=D, requires_grad=True)
    stacked.cost(retract_differentiable(state, layout, delta)).backward()
    assert torch.allclose(g, delta.grad, rtol=1e-9, atol=1e-9), (g - delta.grad).abs().max()
    assert float(g[layout.slice(BlockId(CODE, 0)).stop - 1].abs()) > 1e-3  # the scale is seen
    # exp(s) scales the points A's keypoints decode to
    X = [stacked._residuals(SfMState(state.poses, torch.cat([state.codes[:, :-1], s * scales], 1),
                                     state.affine))[1] for s in (0.0, 1.0)]
    T_BA = se3_inverse(state.poses[stacked.b[stacked.pid]]) @ state.poses[stacked.a[stacked.pid]]
    X = [((x - T_BA[:, :3, 3])[:, None] @ T_BA[:, :3, :3]).squeeze(1) for x in X]  # back in A's frame
    torch.testing.assert_close(X[1], X[0] * torch.exp(scales[stacked.a[stacked.pid]]), rtol=1e-12, atol=1e-12)
