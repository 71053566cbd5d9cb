"""The structured assembly of H = J^T W J, g = J^T W r against the dense Jacobian and against autograd, the
variable layout and the linear prior."""

from __future__ import annotations

import pytest
import torch
from sfm_scene import look_pose, make_frames

from codeslam.geometry.lie import se3_exp
from codeslam.sfm.autodiff import autodiff_normal_equations, retract_differentiable
from codeslam.sfm.config import SfMConfig
from codeslam.sfm.keyframes import build_levels
from codeslam.sfm.normal_equations import _local_blocks, add_local_blocks, assemble, batched_mv, dense_jacobian
from codeslam.sfm.residuals import evaluate_pairs, pair_jacobians
from codeslam.sfm.variables import AFFINE, CODE, POSE, RS, BlockId, LinearPrior, SfMState, VariableLayout

D = torch.float64
PAIRS = torch.tensor([[0, 1], [1, 0], [0, 2], [2, 1], [2, 0]])  # frame 0 is A twice: its weights are pooled


@pytest.fixture(scope="module")
def problem():
    gt = [look_pose(), look_pose((0.2, -0.05, 0.03), (0.02, -0.04, 0.01)),
          look_pose((-0.1, 0.1, 0.1), (0.0, 0.03, 0.02))]
    kfs, codes, poses = make_frames(gt, width=32, height=24, code_size=6, levels=1, seed=4)
    g = torch.Generator().manual_seed(7)
    poses = se3_exp(0.02 * torch.randn(3, 6, generator=g, dtype=D)) @ poses
    state = SfMState(poses, codes + 0.3 * torch.randn(codes.shape, generator=g, dtype=D),
                     0.05 * torch.randn(5, 2, generator=g, dtype=D))
    return build_levels(kfs, [0])[0], state


LAYOUTS = {
    "sfm_gauge": [BlockId(POSE, 0)],
    "codes_fixed": [BlockId(POSE, 0), BlockId(CODE, 0), BlockId(CODE, 1), BlockId(CODE, 2)],
    "tracking": [BlockId(POSE, 0), BlockId(POSE, 1)] + [BlockId(CODE, i) for i in range(3)]
    + [BlockId(AFFINE, p) for p in range(1, 5)],  # only pose 2 and one affine free
    "only_code_B": [BlockId(POSE, i) for i in range(3)] + [BlockId(CODE, 0), BlockId(CODE, 2)],
}


@pytest.mark.parametrize("name", sorted(LAYOUTS))
@pytest.mark.parametrize("types", [dict(), dict(photometric=False)])
def test_structured_assembly_equals_dense_jacobian_products(problem, name, types):
    level, state = problem
    cfg = SfMConfig(**types)
    layout = VariableLayout.for_sfm(3, 6, 5, True, fixed=LAYOUTS[name])
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    terms = pair_jacobians(level, PAIRS, ev)
    H, g = assemble(terms, PAIRS, state.poses, level, layout)
    J = dense_jacobian(terms, PAIRS, state.poses, level, layout)
    w, r = terms.w.reshape(-1), terms.r.reshape(-1)
    H_ref = J.T @ (w[:, None] * J)
    g_ref = J.T @ (w * r)
    scale = H_ref.abs().max()
    assert (H - H_ref).abs().max() < 1e-11 * scale
    assert (g - g_ref).abs().max() < 1e-11 * g_ref.abs().max()
    torch.testing.assert_close(H, H.T, rtol=0, atol=1e-11 * float(scale))


def test_rolling_shutter_assembly_equals_dense_jacobian_products_and_autograd(problem):
    level, state = problem
    g = torch.Generator().manual_seed(3)
    state = SfMState(state.poses, state.codes, state.affine, 0.03 * torch.randn(3, 3, generator=g, dtype=D))
    cfg = SfMConfig(gradient_mode="interpolant", rolling_shutter=True)
    layout = VariableLayout.for_sfm(3, 6, 5, True, fixed=[BlockId(POSE, 0), BlockId(RS, 1)], rolling_shutter=True)
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg, rs=state.rs)
    terms = pair_jacobians(level, PAIRS, ev)
    H, g = assemble(terms, PAIRS, state.poses, level, layout)
    J = dense_jacobian(terms, PAIRS, state.poses, level, layout)
    w, r = terms.w.reshape(-1), terms.r.reshape(-1)
    H_ref, g_ref = J.T @ (w[:, None] * J), J.T @ (w * r)
    assert (H - H_ref).abs().max() < 1e-11 * H_ref.abs().max()
    assert (g - g_ref).abs().max() < 1e-11 * g_ref.abs().max()
    H_ad, g_ad = autodiff_normal_equations(level, PAIRS, state, layout, cfg)
    assert (H - H_ad).abs().max() < 1e-10 * H_ad.abs().max()
    assert (g - g_ad).abs().max() < 1e-10 * g_ad.abs().max()


def test_analytic_normal_equations_equal_autograd_ones(problem):
    level, state = problem
    cfg = SfMConfig(gradient_mode="interpolant")
    layout = VariableLayout.for_sfm(3, 6, 5, True, fixed=[BlockId(POSE, 0)])
    ev = evaluate_pairs(level, PAIRS, state.poses, state.codes, state.affine, cfg)
    terms = pair_jacobians(level, PAIRS, ev)
    N = terms.r.shape[-1]
    assert any(0 < len(k) < N for k in terms.JB_idx)  # J_B is sampled only where the geometric rows have weight
    H, g = assemble(terms, PAIRS, state.poses, level, layout)
    H_ad, g_ad = autodiff_normal_equations(level, PAIRS, state, layout, cfg)
    assert (H - H_ad).abs().max() < 1e-10 * H_ad.abs().max()
    assert (g - g_ad).abs().max() < 1e-10 * g_ad.abs().max()


def test_layout_offsets_and_membership():
    layout = VariableLayout.for_sfm(2, 4, 1, True, fixed=[BlockId(POSE, 0)])
    assert layout.dim == 6 + 4 + 4 + 2
    assert layout.slice(BlockId(POSE, 0)) is None and BlockId(POSE, 0) not in layout
    assert layout.slice(BlockId(POSE, 1)) == slice(0, 6)
    assert layout.slice(BlockId(CODE, 1)) == slice(10, 14)
    assert layout.indices([BlockId(AFFINE, 0), BlockId(POSE, 1)]).tolist() == [14, 15, 0, 1, 2, 3, 4, 5]
    no_affine = VariableLayout.for_sfm(2, 4, 1, False)
    assert no_affine.dim == 12 + 8


def test_retract_matches_its_differentiable_twin_and_local_difference_inverts_it(problem):
    _, state = problem
    layout = VariableLayout.for_sfm(3, 6, 5, True, fixed=[BlockId(POSE, 0)])
    g = torch.Generator().manual_seed(0)
    delta = 0.1 * torch.randn(layout.dim, generator=g, dtype=D)
    a = state.retract(layout, delta)
    b = retract_differentiable(state, layout, delta)
    for x, y in ((a.poses, b.poses), (a.codes, b.codes), (a.affine, b.affine)):
        torch.testing.assert_close(x, y)
    for blk, sl in layout.slices():
        torch.testing.assert_close(a.local_difference(blk, state.block(blk)), delta[sl])
    torch.testing.assert_close(a.poses[0], state.poses[0])  # fixed block untouched


def test_linear_prior_gradient_and_hessian_match_autograd(problem):
    _, state = problem
    layout = VariableLayout.for_sfm(3, 6, 5, True, fixed=[BlockId(POSE, 0)])
    blocks = [BlockId(POSE, 1), BlockId(CODE, 2)]
    g = torch.Generator().manual_seed(1)
    A = torch.randn(12, 12, generator=g, dtype=D)
    x0_state = state.retract(layout, 0.05 * torch.randn(layout.dim, generator=g, dtype=D))
    prior = LinearPrior(blocks, A @ A.T, torch.randn(12, generator=g, dtype=D),
                        [x0_state.block(b).clone() for b in blocks])
    H = torch.zeros(layout.dim, layout.dim, dtype=D)
    gv = torch.zeros(layout.dim, dtype=D)
    prior.add_to(H, gv, layout, state)
    idx = layout.indices(blocks)
    torch.testing.assert_close(H[idx[:, None], idx[None, :]], prior.H)
    outside = H.clone()
    outside[idx[:, None], idx[None, :]] = 0.0
    assert not bool(outside.any())  # nothing outside the prior's blocks (not a sum's equality: its last bit
    # depends on how the reduction is vectorised, which failed under MKL_CBWR=COMPATIBLE)

    # The gradient b + H d is exact for code blocks and first-order for poses (d(d)/d(increment) ~ I near x0).
    def cost(delta):
        st = retract_differentiable(state, layout, delta)
        d = torch.cat([st.local_difference(b, v0) for b, v0 in zip(prior.blocks, prior.x0)])
        return 0.5 * d @ prior.H @ d + prior.b @ d
    grad = torch.func.grad(cost)(torch.zeros(layout.dim, dtype=D))
    code_sl = layout.slice(BlockId(CODE, 2))
    torch.testing.assert_close(gv[code_sl], grad[code_sl])
    pose_sl = layout.slice(BlockId(POSE, 1))
    assert (gv[pose_sl] - grad[pose_sl]).norm() < 0.1 * grad[pose_sl].norm()


def test_the_window_sized_local_blocks_add_up_the_same_on_every_call():
    """A window's 12 pairs with 64-dimensional codes, added on two threads: the same bits every time, and the sums
    of a float64 reference. (index_put_ with accumulate=True gave a different H on almost every call here: the
    same sequence ended at different trajectories from run to run with --threads 2.)"""
    F, C, K = 4, 64, 14
    pairs = [(a, b) for a in range(F) for b in range(F) if a != b]
    layout = VariableLayout.for_sfm(F, C, len(pairs), True, [BlockId(POSE, 0)])
    blocks = [_local_blocks(a, b, p, False) + [(BlockId(CODE, a), K, K + C), (BlockId(CODE, b), K + C, K + 2 * C)]
              for p, (a, b) in enumerate(pairs)]
    g = torch.Generator().manual_seed(5)
    H_local = torch.randn(len(pairs), K + 2 * C, K + 2 * C, generator=g)
    g_local = torch.randn(len(pairs), K + 2 * C, generator=g)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        results = []
        for _ in range(20):
            H, gv = torch.zeros(layout.dim, layout.dim), torch.zeros(layout.dim)
            add_local_blocks(H, gv, layout, blocks, H_local, g_local)
            results.append((H.numpy().tobytes(), gv.numpy().tobytes()))
    finally:
        torch.set_num_threads(threads)
    assert len(set(results)) == 1
    H_ref, g_ref = torch.zeros(layout.dim, layout.dim, dtype=D), torch.zeros(layout.dim, dtype=D)
    for p, pair_blocks in enumerate(blocks):
        for bi, i0, i1 in pair_blocks:
            si = layout.slice(bi)
            if si is None:
                continue
            g_ref[si] += g_local[p, i0:i1].double()
            for bj, j0, j1 in pair_blocks:
                sj = layout.slice(bj)
                if sj is not None:
                    H_ref[si, sj] += H_local[p, i0:i1, j0:j1].double()
    torch.testing.assert_close(H.double(), H_ref, atol=1e-4, rtol=1e-5)
    torch.testing.assert_close(gv.double(), g_ref, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("shape", [(4, 64, 300), (3, 8, 1), (1, 1, 5)])
def test_batched_mv_is_the_batched_matrix_vector_product(shape):
    gen = torch.Generator().manual_seed(0)
    A = torch.randn(*shape, generator=gen, dtype=torch.float64)
    v = torch.randn(shape[0], shape[2], generator=gen, dtype=torch.float64)
    torch.testing.assert_close(batched_mv(A, v), (A @ v[..., None]).squeeze(-1), rtol=1e-12, atol=1e-12)
    At = A.transpose(1, 2).contiguous().transpose(1, 2)  # a transposed view, as the callers pass
    torch.testing.assert_close(batched_mv(At, v), (A @ v[..., None]).squeeze(-1), rtol=1e-12, atol=1e-12)


def test_linear_prior_delta_is_each_blocks_local_difference_in_block_order():
    """The batched delta (one batch per kind, then a gather) equals the blocks' own differences, blocks in any
    order, and repeats itself (its per-kind stacks are cached on first use)."""
    g = torch.Generator().manual_seed(5)
    poses = se3_exp(0.3 * torch.randn(3, 6, generator=g, dtype=D))
    state = SfMState(poses, torch.randn(3, 4, generator=g, dtype=D), torch.randn(2, 2, generator=g, dtype=D))
    blocks = [BlockId(CODE, 2), BlockId(POSE, 1), BlockId(AFFINE, 0), BlockId(POSE, 0), BlockId(CODE, 0)]
    x0 = [torch.randn(4, generator=g, dtype=D), se3_exp(0.2 * torch.randn(6, generator=g, dtype=D)),
          torch.randn(2, generator=g, dtype=D), se3_exp(0.2 * torch.randn(6, generator=g, dtype=D)),
          torch.randn(4, generator=g, dtype=D)]
    prior = LinearPrior(blocks, torch.eye(20, dtype=D), torch.zeros(20, dtype=D), x0)
    expected = torch.cat([state.local_difference(b, v) for b, v in zip(blocks, x0)])
    torch.testing.assert_close(prior.delta(state), expected, rtol=1e-12, atol=1e-12)
    moved = SfMState(se3_exp(0.1 * torch.randn(3, 6, generator=g, dtype=D)) @ poses, state.codes + 1, state.affine)
    expected = torch.cat([moved.local_difference(b, v) for b, v in zip(blocks, x0)])
    torch.testing.assert_close(prior.delta(moved), expected, rtol=1e-12, atol=1e-12)
