"""The linear decoder interface and the network-free stand-in."""

from __future__ import annotations

import pytest
import torch

from codeslam.errors import CodeSLAMError
from codeslam.geometry.image import image_pyramid
from codeslam.geometry.proximity import prox_to_depth
from codeslam.sfm.decoder import DecoderLevel, LinearDecoder, cosine_basis, standin_decoder

D = torch.float64


def test_cosine_basis_is_orthonormal_and_starts_constant():
    B = cosine_basis(10, 12, 16, D)  # (C, H, W)
    gram = torch.einsum("chw,dhw->cd", B, B) / (12 * 16)
    torch.testing.assert_close(gram, torch.eye(10, dtype=D), atol=1e-12, rtol=0)
    torch.testing.assert_close(B[0], torch.ones(12, 16, dtype=D))


def test_standin_reaches_the_target_at_the_offset_code_on_every_level():
    g = torch.Generator().manual_seed(0)
    target = 0.3 + 0.4 * torch.rand(24, 32, generator=g, dtype=D)
    c = torch.randn(6, generator=g, dtype=D)
    dec = standin_decoder(target, 6, 3, 2.0, code_offset=c, image=torch.rand(24, 32, generator=g, dtype=D))
    torch.testing.assert_close(dec.prox(c, 0), target)
    pyr = image_pyramid(target[None, None], 3)
    for lvl in range(3):  # linear pyramid: level l of prox(c) is prox_l(c)
        torch.testing.assert_close(dec.prox(c, lvl), pyr[lvl][0, 0])
    torch.testing.assert_close(dec.depth(c, 0), prox_to_depth(target, 2.0))


def test_decoder_is_exactly_linear_in_the_code():
    g = torch.Generator().manual_seed(1)
    dec = standin_decoder(0.5 * torch.ones(12, 16, dtype=D), 5, 2, 2.0)
    c1, c2 = torch.randn(2, 5, generator=g, dtype=D)
    for lvl in range(2):
        lin = dec.prox(c1, lvl) + dec.prox(c2, lvl) - dec.prox(torch.zeros(5, dtype=D), lvl)
        torch.testing.assert_close(dec.prox(c1 + c2, lvl), lin)


def test_from_levels_accepts_network_shapes_and_rejects_mismatches():
    prox = [torch.rand(1, 1, 8 >> k, 12 >> k) for k in range(2)]
    jac = [torch.rand(1, 4, 8 >> k, 12 >> k) for k in range(2)]
    dec = LinearDecoder.from_levels(prox, jac, 2.0, uncertainty=[p.clone() for p in prox])
    assert dec.code_size == 4 and dec.num_levels == 2 and dec.levels[1].uncertainty.shape == (4, 6)
    with pytest.raises(CodeSLAMError):
        LinearDecoder.from_levels(prox, jac[:1], 2.0)
    with pytest.raises(CodeSLAMError):
        LinearDecoder((DecoderLevel(torch.rand(8, 12), torch.rand(4, 8, 12)),
                       DecoderLevel(torch.rand(3, 6), torch.rand(4, 3, 6))), 2.0)
    with pytest.raises(CodeSLAMError):
        LinearDecoder((DecoderLevel(torch.rand(8, 12), torch.rand(4, 8, 12)),), -1.0)


def test_principal_keeps_the_codes_leading_directions_on_every_level():
    g = torch.Generator().manual_seed(2)
    dec = standin_decoder(0.3 + 0.4 * torch.rand(24, 32, generator=g, dtype=D), 12, 3, 2.0,
                          image=torch.rand(24, 32, generator=g, dtype=D))
    red, U = dec.principal(5)
    assert red.code_size == 5 and U.shape == (12, 5)
    torch.testing.assert_close(U.T @ U, torch.eye(5, dtype=D))
    z = torch.randn(5, generator=g, dtype=D)
    for lvl in range(3):  # the same proximity as the network's code U z, on every level
        torch.testing.assert_close(red.prox(z, lvl), dec.prox(U @ z, lvl))
        assert red.levels[lvl].uncertainty is dec.levels[lvl].uncertainty
    # the kept directions are those the finest proximity follows most: what is left of J_0 outside their span is
    # no more than outside any other 5-dimensional subspace (here a random one)
    J = dec.levels[0].jac.reshape(12, -1)
    left = (J - U @ (U.T @ J)).square().sum()
    Q, _ = torch.linalg.qr(torch.randn(12, 5, generator=g, dtype=D))
    assert left <= (J - Q @ (Q.T @ J)).square().sum()
    assert float(left) < float(J.square().sum())
    assert dec.principal(12) == (dec, None) and dec.principal(40) == (dec, None)
    with pytest.raises(CodeSLAMError):
        dec.principal(0)
