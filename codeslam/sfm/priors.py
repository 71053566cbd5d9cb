"""The fixed priors of the SfM cost as cost objects: the VAE's prior on the codes (paper Sec. 2.1), the prior on
each pair's affine brightness and, with a rolling-shutter model, on each frame's readout rotation.

Each has the interface of :class:`~codeslam.sfm.variables.LinearPrior` (``cost(state)``, ``add_to(H, g, layout,
state)``), so :class:`~codeslam.sfm.solver.PairProblem` and the window's marginalisation
(:meth:`~codeslam.slam.window.SlidingWindow.marginal_prior`) add them in one place, beside the linear and scale
priors. All three act on additive blocks, so their Gauss-Newton Hessians are exact: ``0.5 w |x|^2`` gives
``H += w I`` and ``g += w x`` on every free block it covers.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from codeslam.sfm.variables import AFFINE, CODE, RS, RS_DIM, SfMState, VariableLayout


class CodePrior:
    """``0.5 w |c_i|^2`` over the codes of ``frames`` (None: every frame): the VAE is trained with the codes
    distributed as N(0, I), the paper's prior on them (Sec. 2.1). The cost sums over the frames' codes whether
    they are free or not (a fixed code adds a constant); the normal equations get the free ones."""

    def __init__(self, weight: float, frames: Sequence[int] | None = None) -> None:
        self.weight = weight
        self.frames = None if frames is None else list(frames)

    def cost(self, state: SfMState) -> torch.Tensor:
        codes = state.codes if self.frames is None else state.codes[self.frames]
        return 0.5 * self.weight * codes.square().sum()  # VAE prior N(0, I) (Sec. 2.1)

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        for b, sl in layout.slices():
            if b.kind == CODE and (self.frames is None or b.index in self.frames):
                H[sl, sl] += self.weight * torch.eye(sl.stop - sl.start, dtype=H.dtype, device=H.device)
                g[sl] += self.weight * state.codes[b.index].to(g.dtype)


class AffinePrior:
    """``0.5 |a_p / sigma|^2`` over every pair's affine brightness (log-gain, bias), ``sigma`` = (log-gain's,
    bias's) standard deviation (``SfMConfig.affine_prior_sigma``): keeps the normal equations definite on pairs
    with no overlap."""

    def __init__(self, sigma: tuple[float, float]) -> None:
        self.sigma = tuple(sigma)

    def cost(self, state: SfMState) -> torch.Tensor:
        return 0.5 * (state.affine / state.affine.new_tensor(self.sigma)).square().sum()

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        inv_var = 1.0 / H.new_tensor(self.sigma) ** 2
        for b, sl in layout.slices():
            if b.kind == AFFINE:
                H[sl, sl] += torch.diag(inv_var)
                g[sl] += inv_var * state.affine[b.index].to(g.dtype)


class ReadoutPrior:
    """``0.5 |w_i / sigma|^2`` over every frame's rotation over its readout (radians; ``SfMConfig.rolling_shutter``
    and ``rolling_shutter_sigma``): N(0, sigma^2) on each component. No cost on a state without readout
    rotations."""

    def __init__(self, sigma: float) -> None:
        self.sigma = sigma

    def cost(self, state: SfMState) -> torch.Tensor | float:
        return 0.0 if state.rs is None else 0.5 * (state.rs / self.sigma).square().sum()

    def add_to(self, H: torch.Tensor, g: torch.Tensor, layout: VariableLayout, state: SfMState) -> None:
        inv_var = 1.0 / self.sigma**2
        for b, sl in layout.slices():
            if b.kind == RS:
                H[sl, sl] += inv_var * torch.eye(RS_DIM, dtype=H.dtype, device=H.device)
                g[sl] += inv_var * state.rs[b.index].to(g.dtype)
