"""Configuration of dense N-frame structure from motion (paper Sec. 4.1) and its Levenberg-Marquardt solver."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from codeslam.configfile import from_mapping
from codeslam.errors import ConfigError

GRADIENT_MODES = ("sobel", "interpolant")
GEOMETRIC_SPACES = ("log_depth", "proximity")
MASKED_ROWS = ("threshold", "common")


@dataclass(frozen=True)
class SfMConfig:
    """Residuals, loss functions (paper Sec. 4.1 (i)-(v)) and the damped Gauss-Newton solver.

    Residuals are normalised by their sigma before the Huber function, so the sigmas set the relative weighting of
    the photometric and geometric terms (loss (ii)) and the Huber thresholds are in units of sigma.
    """

    # --- residuals -------------------------------------------------------------------------------------------
    photometric: bool = True
    """Use the photometric residual I_A[u] - (alpha I_B[w] + beta) (paper Sec. 4.1, E_pho)."""
    geometric: bool = True
    """Use the geometric residual (proximity of the warped point vs B's decoded proximity at w, E_geo)."""
    affine_brightness: bool = True
    """Estimate a per-pair affine brightness (log-gain, bias): the paper's exposure correction (Sec. 5.2)."""
    sigma_photometric: float = 0.05
    """Photometric noise (grey levels in [0, 1]); relative weighting (ii) against ``sigma_geometric``."""
    geometric_space: str = "log_depth"
    """Space of the geometric residual f(z) - f(D_B[v]): 'log_depth' (scale-free: scaling every depth and
    translation together leaves it unchanged, as it leaves the photometric term) or 'proximity' (the decoder's
    output; beyond the average depth a it shrinks as depths grow, so it pulls the scale up)."""
    sigma_geometric: float = 0.25
    """Geometric noise in the units of ``geometric_space`` (relative weighting (ii)): 0.25 in log depth, the
    SLAM window's value. The network's single-view depths of real frames disagree at the true poses by 0.10-0.13
    (robust spread), so the former 0.08 (8% relative depth error; what 0.02 in proximity is at the average depth,
    for ``geometric_space: proximity``) let the term pull the depths of frames with little parallax after poses
    fitted to noise. Measured on TUM fr1/rpy (``docs/results/table1_sfm.md``, issue 11 item 5): with neighbours
    -6..+9 frames the far masters 60, 100, 140 end +1.5%, -18%, +9% against their zero code at 0.08 and -10%,
    -25%, -19% at 0.25; the close masters 6, 18, 30, 42 (+-2, +-4) -20..-41% and -24..-31%. It costs the
    generator rooms part of their gain (scene 0, one paired frame: -53% -> -23%)."""
    geometric_pose_min_std: float = 0.0
    """Where a pair's first view is blank, its geometric residuals refine the codes but do not move the poses: the
    standard deviation of A's intensities over the pixels its photometric residuals see in B (what that term has
    to go on, the tracker's ``texture``) below this scales the geometric rows' derivatives by the poses (and
    readout rotations) by ``(std / this)^2``. Only the steps' normal equations leave that pull out; the cost that
    accepts or rejects a step keeps the whole term. The geometric residual (Eq. 14) compares two decoded depths;
    where the images cannot correct them they stay the network's single-view guesses, whose disagreement (an error
    of scale or layout shared by all pixels) thousands of pixels otherwise count as a precise measurement of the
    camera moving along its axis. 0 switches it off (the default here; the SLAM window's is 0.1,
    :func:`~codeslam.slam.config._default_window_sfm`)."""
    geometric_pose_regions: int = 1
    """The spread of ``geometric_pose_min_std`` taken per region: A's image cut into this many cells a side (on
    every level), each cell's spread gating its own pixels' geometric pose rows. 1: the whole overlap of the pair
    at once. A view that is only partly blank (a wall beside a textured floor) has a spread above the threshold
    taken whole, and its blank part's pixels keep their pull on the poses. Not the SLAM window's default
    (docs/results/slam_table.md, sixty-second session; 1 thread, one run each): there at 4 cells a side and 0.05
    (a cell spreads less than its view), the runs with the dataset's depth went 0.86x in geometric mean (fast turn
    14 0.0156 -> 0.0094 m, 2.96 -> 0.60 deg) and the network's 18 suite runs 0.97x (TUM fr1/rpy 0.0145 -> 0.0120
    m), but every second frame of the HoloLens walk went further off in each of four draws (start frames 0 and 1,
    1 and 2 threads: 1.06-2.6x), and in the variants measured (0.1; 2 cells; a cell with few pixels seen taking
    the pair's factor). Taken over all of a cell's pixels it held there (1.09x, 0.95x) and turned fast turn 14
    with the dataset's depth 15 deg off."""
    geometric_stride: int = 1
    """Geometric residuals on every s-th pixel of every s-th row of the finest level only (level l: s >> l, at
    least 1), each weighted s^2 so the term keeps its weight. The decoded depths are smooth, so the term's
    information is of low frequency, while its code-B coupling costs C x C per pixel (the bulk of a window
    linearisation when the codes are free); the photometric residuals keep every pixel."""
    use_uncertainty: bool = False
    """Add the network's Laplace scales b of both views to the geometric noise: sigma^2 + 2 b_A^2 + 2 b_B^2 (b
    carried into log depth at first order when ``geometric_space`` is 'log_depth')."""
    huber_photometric: float = 1.345
    """Huber threshold in sigmas (loss (iii)); 1.345 keeps 95% efficiency for Gaussian noise."""
    huber_geometric: float = 1.345
    """Huber threshold in sigmas for the geometric residual (loss (iii))."""
    border: float = 1.0
    """Correspondences closer than this (pixels) to the border of B are masked (loss (i)): Sobel is unreliable there."""
    slant_cos_min: float = 0.25
    """Loss (iv): weight min(1, cos/slant_cos_min) with cos the angle between A's surface normal and viewing ray."""
    occlusion_margin: float = 0.1
    """Loss (v): a warped point more than this fraction behind B's decoded surface counts as likely occluded."""
    occlusion_weight: float = 0.1
    """Loss (v): weight of photometric residuals of likely-occluded pixels."""
    occlusion_geometric: bool = True
    """Apply loss (v) to the geometric residual too. The paper does not (a point that looks occluded may be one
    whose depth is wrong, which the geometric term must correct), but the geometric residuals of truly occluded
    pixels all have one sign and bias the optimum. Measured on the synthetic room with an occluding panel
    (tests/sfm): two-frame pose error 1.4 cm -> 0.5 cm on a 25 cm baseline; 4-frame joint SfM depth-scale error
    25% -> 8%, rotation error 0.6 -> 0.2 degrees. Set False for the paper's behaviour."""
    rolling_shutter: bool = False
    """Model a rolling shutter: each frame k gets a rotation omega_k over its readout (the camera that exposed row
    y is turned by s(y) omega_k, s(y) = (y - (H - 1) / 2) / H, to first order), optimised with the poses under a
    N(0, ``rolling_shutter_sigma``^2) prior. On TUM fr1/rpy the frames are misaligned at the ground-truth poses by
    up to 1.75 px at 128x96, changing linearly from the top rows to the bottom ones
    (``scripts/row_shift_at_gt.py``). Measured (docs/results/table1_sfm.md): on frames rendered by a rolling
    shutter the pose errors fall from 2.6-5.5 to under 0.1 degrees; on TUM fr1/rpy (30 masters) the median
    rotation error 0.74 -> 0.53 degrees but the depth does not improve; mixed on the HoloLens walk. Off by
    default; SfM only (the SLAM window refuses it)."""
    rolling_shutter_sigma: float = 0.05
    """Prior sigma (radians) of each component of a frame's readout rotation omega."""
    masked_rows: str = "threshold"
    """How loss (i) prices a masked row (out of view, too close to B's border, behind the camera) and how the solver
    accepts a step. 'threshold': at the Huber threshold ``rho(k) = k^2 / 2`` and a step accepted when the total cost
    falls. 'common': at the mean of the pair's valid rows, and a step accepted when the cost over the rows valid
    before and after it falls (:func:`~codeslam.sfm.residuals.common_cost_change`), so pixels that leave or enter
    the view judge neither side. The normal equations are the valid rows' either way. The SLAM window and tracker
    use 'common': at the threshold's price a step that turned pixels out of view was rejected whatever the images
    said, and on a blank wall the tracker stayed at the motion model's guess 1.1 deg off (generator fast turn, seed
    14, frame 92); with 'common' the suite's ATE fell on 13 of 16 runs, 11 with the window's 3e-4 accepted-step stop
    that came with it (``docs/results/slam_table.md``, session of 2026-11-29). ``codeslam sfm`` keeps 'threshold':
    on issue 11's far-range TUM master 60 (neighbours -6..+9, no parallax) 'common' accepts the steps that move the
    depth after noise and ends 11% worse than the zero code, against 9.8% better; the rejected steps were what held
    it (masters 100 and 140 end better with 'common')."""
    gradient_mode: str = "sobel"
    """Image gradient at w: 'sobel' (smooth, Kerl et al.) or 'interpolant' (exact slope of the bilinear lookup,
    what autograd through the lookup gives; used to check the Jacobians against autograd)."""
    weights_per_level: bool = False
    """Hold the residuals' fixed weights (loss (iv)'s slant weight of A's decoded surface, loss (v)'s occlusion
    weight) and their sigmas (the geometric term's, with the network's uncertainty) at the values of a pyramid
    level's first evaluation through that level's Levenberg-Marquardt run, as constants of an iteratively
    reweighted least-squares step, instead of recomputing them at every evaluation. Those factors move with the
    codes and poses but are not differentiated, so recomputed at every trial step they change the cost the normal
    equations do not model, and the solver rejects steps the model rightly promised: in the SLAM window's solves on
    TUM fr1/rpy the first step of a level was accepted and the next three, each ten times more damped and
    promising 4e-4 to 3e-3 of the cost, rejected. Levels start from fresh weights. Off for ``codeslam sfm``; the
    SLAM window holds them (``docs/results/slam_table.md``, session of 2026-12-03, thirty-fourth)."""

    # --- priors ----------------------------------------------------------------------------------------------
    code_prior_weight: float = 1.0
    """Weight of the VAE prior 0.5 w |c|^2 (N(0, I) on codes): keeps unobservable code directions at zero."""
    depth_scale_sigma: float = 0.0
    """Prior on each frame's mean log depth at its zero-code value (:mod:`codeslam.sfm.scale_prior`), in log
    depth; 0 switches it off. The SLAM window sets its own (``window.depth_scale_sigma``)."""
    affine_prior_sigma: tuple[float, float] = (0.2, 0.1)
    """Gaussian prior sigmas on (log-gain, bias): keeps the normal equations definite on pairs with no overlap."""

    # --- solver ----------------------------------------------------------------------------------------------
    pyramid_levels: tuple[int, ...] = (3, 2, 1, 0)
    """Pyramid levels visited coarse to fine (0 = full resolution), for a wider basin of convergence (Sec. 4.2).
    All four of the network's levels: on TUM fr1_rpy (128x96, known depth, identity start) starting at level 3
    instead of 2 took convergence from rotations of about 10 to about 27 degrees."""
    max_iterations: tuple[int, ...] = (15, 15, 10, 10)
    """Accepted-or-rejected LM iterations per visited level (same length as ``pyramid_levels``)."""
    initial_damping: float = 1e-4
    """Initial lambda of the Marquardt damping H + lambda diag(H)."""
    code_damping: float = 1.0
    """The code entries' share of that damping: ``H + lambda diag(H) M`` with ``M`` this on the code entries and 1
    on the poses and the rest (1: Marquardt's own). Above 1 each level's first steps move the poses before the
    codes. 1 in the SLAM window too. Measured there at 100 (``window: {sfm: {code_damping: 100}}``;
    docs/results/slam_table.md, session of 2026-12-01, twenty-fourth; one thread): every second HoloLens frame
    from start frames 0 / 1 / 2 1.13 / 0.47 / 0.94 -> 0.28 / 0.45 / 0.42 m, the suite's 19 network runs 10% lower
    ATE (geometric mean), but four generator sequences rendered afterwards 2% higher (one walk +22%), the
    HoloLens walk with the dataset's depth +26% and the hand-held preset +22%; 1,000 and 10,000 no better."""
    damping_increase: float = 10.0
    """Factor applied to lambda after a rejected step (cost increase, NaN/inf or non-PD system)."""
    damping_decrease: float = 0.3
    """Factor applied to lambda after an accepted step."""
    max_damping: float = 1e8
    """Stop a level when lambda grows beyond this: no descent direction can be found."""
    min_diagonal: float = 1e-6
    """Floor of diag(H) in the damping term, so variables with no data still get damped."""
    relative_cost_tolerance: float = 1e-5
    """Stop a level when an accepted step decreases the cost by less than this fraction."""
    step_tolerance: float = 1e-7
    """Stop a level when the step's norm falls below this."""
    rejection_stop_decrease: float = 0.0
    """Stop a level at a rejected step whose predicted decrease was below this fraction of the cost: a promise of
    that size lies within what the cost moves by between evaluations (bilinear lookups, validity masks and robust
    weights change with the state), and more damping shortens the step without changing much else. 0 switches it
    off (every rejection raises the damping and tries again)."""

    def __post_init__(self) -> None:
        if not (self.photometric or self.geometric):
            raise ConfigError("SfM config: at least one of photometric/geometric residuals must be enabled")
        for name in ("sigma_photometric", "sigma_geometric", "huber_photometric", "huber_geometric",
                     "slant_cos_min", "damping_increase", "max_damping", "rolling_shutter_sigma"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"SfM config: {name} must be positive, got {getattr(self, name)}")
        if not 0.0 <= self.rejection_stop_decrease < 1.0:
            raise ConfigError("SfM config: rejection_stop_decrease must lie in [0, 1), got "
                              f"{self.rejection_stop_decrease}")
        if not 0 < self.damping_decrease < 1 < self.damping_increase:
            raise ConfigError("SfM config: need 0 < damping_decrease < 1 < damping_increase")
        if not (isinstance(self.geometric_stride, int) and self.geometric_stride >= 1):
            raise ConfigError(f"SfM config: geometric_stride must be an integer >= 1, got {self.geometric_stride}")
        if not self.geometric_pose_min_std >= 0:  # "not >=" also refuses NaN
            raise ConfigError(f"SfM config: geometric_pose_min_std must be >= 0, got {self.geometric_pose_min_std}")
        if self.geometric_pose_regions < 1:
            raise ConfigError(f"SfM config: geometric_pose_regions must be >= 1, got {self.geometric_pose_regions}")
        if self.geometric_space not in GEOMETRIC_SPACES:
            raise ConfigError(f"SfM config: geometric_space must be one of {GEOMETRIC_SPACES}, "
                              f"got {self.geometric_space!r}")
        if self.masked_rows not in MASKED_ROWS:
            raise ConfigError(f"SfM config: masked_rows must be one of {MASKED_ROWS}, got {self.masked_rows!r}")
        if self.gradient_mode not in GRADIENT_MODES:
            raise ConfigError(f"SfM config: gradient_mode must be one of {GRADIENT_MODES}, got {self.gradient_mode!r}")
        if len(self.pyramid_levels) != len(self.max_iterations) or not self.pyramid_levels:
            raise ConfigError("SfM config: pyramid_levels and max_iterations must be non-empty and of equal length")
        if any(level < 0 for level in self.pyramid_levels):
            raise ConfigError(f"SfM config: pyramid levels must be >= 0, got {self.pyramid_levels}")
        if any(s <= 0 for s in self.affine_prior_sigma) or len(self.affine_prior_sigma) != 2:
            raise ConfigError("SfM config: affine_prior_sigma must be two positive numbers")
        if not self.depth_scale_sigma >= 0:
            raise ConfigError(f"SfM config: depth_scale_sigma must be >= 0, got {self.depth_scale_sigma}")
        if self.code_prior_weight < 0 or self.occlusion_weight < 0 or self.border < 0:
            raise ConfigError("SfM config: code_prior_weight, occlusion_weight and border must be >= 0")
        if any(n < 0 for n in self.max_iterations):
            raise ConfigError(f"SfM config: max_iterations must be >= 0, got {self.max_iterations}")
        if not (self.code_damping > 0 and math.isfinite(self.code_damping)):
            raise ConfigError(f"SfM config: code_damping must be a positive number, got {self.code_damping}")
        for name in ("initial_damping", "min_diagonal", "relative_cost_tolerance", "step_tolerance",
                     "occlusion_margin"):
            if not getattr(self, name) >= 0:  # "not >=" also refuses NaN
                raise ConfigError(f"SfM config: {name} must be >= 0, got {getattr(self, name)}")

    @property
    def residual_types(self) -> tuple[str, ...]:
        """The enabled residual types in the order they are stacked: ('photometric', 'geometric')."""
        return tuple(t for t, on in (("photometric", self.photometric), ("geometric", self.geometric)) if on)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> SfMConfig:
        """From a (YAML) mapping of a subset of the fields; unknown keys or mistyped values raise ConfigError."""
        return from_mapping(cls, d, "sfm")
