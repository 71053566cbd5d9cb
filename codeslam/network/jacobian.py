"""The code Jacobian dD/dc of the decoder (paper Sec. 4.1: computed once per keyframe).

With the linear decoder ``D(I, c) = D(I, 0) + J(I) c`` holds exactly, so column k of J is
``D(I, e_k) - D(I, 0)``, which the decoder's linear part maps from ``e_k`` directly (measured at 96x128, code 128,
2 threads: reverse-mode ``jacrev`` ~160 s, a batched decoding of the zero and unit codes 0.44 s, this 0.21 s).

A nonlinear decoder's Jacobian depends on the code; there it is computed exactly at the given code with
forward-mode automatic differentiation (``torch.func.jacfwd``, which pushes all C tangent directions through the
decoder in one vectorised pass), not with finite differences.
"""

from __future__ import annotations

import torch
from torch.func import jacfwd, vmap

from codeslam.network.model import CodeNetwork


def _linear_jacobian(
    model: CodeNetwork, feats: list[torch.Tensor], chunk_size: int | None, dtype: torch.dtype | None = None
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Linear decoder: -> (mu at the zero code, J) per level, (B, 1, h, w) and (B, C, h, w). One decoding of the
    zero code, and the columns ``D(I, e_k) - D(I, 0)`` pushed through the decoder's linear part
    (:meth:`~codeslam.network.model.DepthDecoder.code_directions`, computed in ``dtype``), ``chunk_size``
    columns at a time."""
    B, C = feats[0].shape[0], model.code_size
    prox0 = model.decode(feats, feats[0].new_zeros(B, C))
    basis = torch.eye(C, dtype=feats[0].dtype, device=feats[0].device)
    chunk = C if chunk_size is None else max(1, chunk_size)
    parts = [model.decoder.code_directions(feats, basis[k : k + chunk], dtype) for k in range(0, C, chunk)]
    jac = [torch.cat([p[lvl] for p in parts], dim=1) for lvl in range(len(prox0))]
    return prox0, jac


def _forward_mode_jacobian(
    model: CodeNetwork, feats: list[torch.Tensor], code: torch.Tensor
) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Any decoder, exact at ``code`` (B, C): -> (mu at the code, J) per level, (B, 1, h, w), (B, C, h, w)."""

    def decode_one(f: list[torch.Tensor], c: torch.Tensor) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        mu = model.decode([x[None] for x in f], c[None])  # levels x (1, 1, h, w)
        mu = [m[0, 0] for m in mu]  # levels x (h, w)
        return mu, mu

    # jacfwd returns (d mu / d c, mu) with has_aux: levels x (h, w, C) and levels x (h, w)
    jac_fn = jacfwd(decode_one, argnums=1, has_aux=True)
    jac, mu = vmap(jac_fn)(feats, code)  # levels x (B, h, w, C), levels x (B, h, w)
    return [m[:, None] for m in mu], [j.permute(0, 3, 1, 2) for j in jac]


def code_jacobian(
    model: CodeNetwork,
    image: torch.Tensor | None = None,
    *,
    feats: list[torch.Tensor] | None = None,
    code: torch.Tensor | None = None,
    all_levels: bool = False,
    chunk_size: int | None = None,
    dtype: torch.dtype | None = None,
) -> tuple[torch.Tensor, torch.Tensor] | tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Decoded proximity and its Jacobian with respect to the code.

    Args:
        model: the network (its decoder's type picks the method, see the module docstring).
        image: (B, in_channels, H, W) in [0, 1]; or pass ``feats`` from :meth:`CodeNetwork.image_features`.
        code: (B, C) the code to linearise at; default zero. For the linear decoder J does not depend on it.
        all_levels: return every pyramid level instead of the finest only.
        chunk_size: linear decoder only: decode at most this many codes per image at once (bounds memory).
        dtype: linear decoder only: the type J is computed in (:func:`jacobian_dtype`; it is returned in the
            features' type); None: the network's. The decoded proximity is always the network's type.

    Returns:
        prox (B, 1, H, W): the decoded proximity at ``code`` (D(I, 0) by default), and
        J (B, C, H, W): d prox / d code; with ``all_levels`` two lists of those, finest level first.
    """
    if feats is None:
        if image is None:
            raise ValueError("code_jacobian needs an image or its features")
        feats = model.image_features(image)
    B = feats[0].shape[0]
    if code is None:
        code = feats[0].new_zeros(B, model.code_size)
    with torch.no_grad():
        if model.config.linear_decoder:
            prox0, jac = _linear_jacobian(model, feats, chunk_size, dtype)
            # bmm, not einsum("bchw,bc->bhw"), which took a batched matrix-vector path 19x slower at B = 8
            # (the same values; see LevelData.prox)
            prox = [p + torch.bmm(code.unsqueeze(1), J.flatten(2)).view_as(p) for p, J in zip(prox0, jac, strict=True)]
        else:
            prox, jac = _forward_mode_jacobian(model, feats, code)
    if all_levels:
        return prox, jac
    return prox[0], jac[0]


def jacobian_dtype(setting: str, device: torch.device | str = "cpu",
                   system_dtype: torch.dtype = torch.float32) -> torch.dtype:
    """The type a keyframe's code Jacobian is computed in: ``setting`` names a torch type ('float32',
    'bfloat16') or is 'auto'; ``device`` and ``system_dtype`` are where and in what the SLAM system solves.

    'auto' is float32 when the system runs in float64 (a check of the maths, not of speed), else bfloat16 on a
    CPU that multiplies bfloat16 in hardware (``amx_bf16``: Intel Xeon since Sapphire Rapids; ``avx512_bf16``: Intel
    Cooper Lake, AMD since Zen 4), and float32 everywhere else (a GPU, a CPU without either). Measured with
    ``benchmarks/bench_decode.py`` (128x96, code 128, the shipped weights): with AMX 250 -> 82 ms on one thread, 142
    -> 54 ms on two; on an AMD EPYC with ``avx512_bf16`` and no AMX 277 -> 156 ms on one thread, 164 -> 92 ms on
    two (0.56x; bfloat16 autocast, which kept some float32 operands, had gained only 12% there); on the same CPU with
    oneDNN held below its bfloat16 instructions (``ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI`` / ``AVX2``) bfloat16
    took 1.8x / 9x float32's time, hence float32 on such CPUs. J then holds about three significant digits (largest
    error 0.8% of the largest entry, the shipped weights); the decoded depth stays float32.
    """
    if setting == "auto":
        capabilities = getattr(torch.cpu, "get_capabilities", None)  # absent in older torch: float32
        caps = capabilities() if torch.device(device).type == "cpu" and capabilities is not None else {}
        bf16_in_hardware = bool(caps.get("amx_bf16", False) or caps.get("avx512_bf16", False))
        return torch.bfloat16 if bf16_in_hardware and system_dtype == torch.float32 else torch.float32
    dtype = getattr(torch, setting, None)
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise ValueError(f"the code Jacobian's type must be 'auto' or a floating-point type, got {setting!r}")
    return dtype
