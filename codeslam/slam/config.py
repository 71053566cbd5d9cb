"""Configuration of the SLAM system (paper Sec. 4.2-4.3): one dataclass per subsystem, overlaid from YAML, and
the resolved configuration written next to every result.

YAML layout (every section and key optional; unknown keys are errors)::

    device: cpu            # or cuda, cuda:1
    dtype: float32
    tracker:   {pyramid_levels: [3, 2, 1, 0], min_inlier_ratio: 0.6, ...}
    keyframes: {min_baseline_ratio: 0.08, ...}
    window:    {size: 4, ..., sfm: {sigma_photometric: 0.05, pyramid_levels: [2, 1, 0], ...}}
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import yaml

from codeslam.configfile import coerce, read_yaml_mapping
from codeslam.errors import ConfigError
from codeslam.sfm.config import SfMConfig

MOTION_MODELS = ("constant_velocity", "static")
DTYPES = ("float32", "float64")
JACOBIAN_DTYPES = ("float32", "bfloat16", "auto")
COARSEST_LEVEL = ("always", "unsettled")
TRAJECTORIES = ("interpolated", "reference")


@dataclass(frozen=True)
class TrackerConfig:
    """Photometric tracking of each frame against the last keyframe (paper Sec. 4.2): only the frame's pose (and
    the affine brightness of the pair) is free, the keyframe's depth is fixed. The photometric residual and its
    loss functions are those of ``window.sfm`` (sigma, Huber, border, slant and occlusion weights)."""

    pyramid_levels: tuple[int, ...] = (3, 2, 1, 0)
    """Levels visited coarse to fine (0 = finest): the coarse levels widen the basin of convergence (Sec. 4.2)."""
    max_iterations: tuple[int, ...] = (8, 8, 6, 5)
    """Levenberg-Marquardt iterations per visited level (same length as ``pyramid_levels``)."""
    feature_start_level: int = 1
    """With a start pose from ORB + PnP (its inlier matches joining the alignment), skip the levels of
    ``pyramid_levels`` coarser than this one: the matches already put the pose within about a pixel of the
    feature camera, a quarter pixel at level 0, inside the basin of the finer levels. Frames without such a start
    (the motion model's guess) visit every level. -1: every frame visits every level. Measured at 1 against -1
    (docs/results/slam_table.md, session of 2026-11-26, seventh): the tracker's median 23.9 -> 19.3 ms on TUM
    fr1/rpy (2 threads), ATE within single-run noise on the seven sequences of the table, network and stand-in."""
    relative_cost_tolerance: float = 1e-3
    """Stop a level when a step lowers the cost by less than this fraction: tracking needs a fraction of a pixel,
    not the mapping's 1e-5 (measured on the generator's rooms: 1e-3 and 1e-5 end within 0.1 mm)."""
    affine_brightness: bool = True
    """Estimate a gain and bias between keyframe and frame (exposure changes, paper Sec. 5.2)."""
    motion_model: str = "constant_velocity"
    """Initial guess and failure fallback: 'constant_velocity' (the last inter-frame motion's velocity carried over
    the time to the frame: one motion per frame at a steady frame rate, more after dropped frames) or 'static'."""
    motion_prior_acceleration: float = 4.0
    """A soft prior on the frame's pose at the motion model's prediction, as a constant-velocity model's process
    noise: the acceleration (map units, ~metres, per s²) that the prediction leaves unexplained. The translation's
    noise per frame is this times dt² (dt: the time since the last frame), so the same setting holds at 10 and at 30
    frames per second and over dropped frames: 4 m/s² (a walking head's bob) gives 4 cm at 10 frames/s, 4.4 mm at
    30. It holds the translation where a small rotation would explain the images as well (network depth, 1 thread,
    docs/results/slam_table.md, session of 2026-11-26, fourth): TUM fr1/rpy 0.0167 -> 0.0149 m and 1.34 -> 1.21 deg,
    the generator's four fast turns 1.29 / 13.07 / 0.51 / 0.43 -> 1.20 / 5.44 / 0.51 / 0.32 deg; the HoloLens walk
    0.142 -> 0.142 m, the generator walk 0.062 -> 0.064 m, its corridor 0.248 -> 0.248 m. 0 switches it off."""
    motion_prior_angular_acceleration_deg: float = 0.0
    """The same for the rotation (degrees per s²; noise per frame this times dt²); 0 leaves the rotation free."""
    max_rotation_from_prediction_deg: float = 25.0
    """Tracking fails when the aligned pose's rotation is more than this many degrees from the motion model's
    prediction and no matched keypoints vouch for it (0 switches the check off). Measured on every second
    HoloLens frame (docs/results/slam_table.md, session of 2026-11-28, eleventh): frame 168, facing a wall with no
    keypoint matches, turned 12.4 deg while its alignment, accepted by every other check (overlap 0.37, explained
    variance 0.60), turned it 54.5 deg, about 40 from the prediction; every later frame carried the 42 deg. The
    true rotation of that sequence (5 frames/s) leaves a constant angular velocity by at most 17.1 deg in one step
    (the real-rate HoloLens walk 5.8, TUM fr1/rpy 2.0, the generator's presets 1.0-4.1)."""
    min_overlap: float = 0.3
    """Tracking fails when fewer than this fraction of the keyframe's pixels land inside the frame."""
    min_inlier_ratio: float = 0.6
    """Tracking fails when fewer than this fraction of the overlapping pixels are photometric inliers."""
    inlier_sigmas: float = 2.0
    """A pixel is an inlier when its photometric residual is below this many ``sigma_photometric``."""
    min_explained_variance: float = 0.5
    """Tracking fails when the aligned frame explains less than this share of the keyframe's intensity variance
    (measured on the generator's rooms: >= 0.98 when aligned, <= 0.38 for other rooms with enough overlap)."""
    min_intensity_std: float = 0.004
    """Tracking fails when the keyframe's intensities (in [0, 1]) over the overlap vary less than this (std), and a
    frame whose own intensities do is lost before any alignment and starts no map: a view without texture (a black
    or saturated frame) constrains no pose, and the explained-variance test divides by that variance, so without
    this check such a frame would pass as tracked. About one 8-bit grey level (a black frame reads 0); a blank
    wall's shading above it still holds the pose. Measured (docs/results/slam_table.md, forty-eighth session): the
    generator walk of seed 91 faces a wall of 0.007-0.0095 for 15 frames; at 0.01 they were lost and a new segment
    was joined by the motion model (1.58 m, 42 deg), at 0.004 every frame is tracked, explained variance 0.96-0.98
    (0.50 m, 8.7 deg). No frame of the suite reads between the two (its faintest: 0.0105, fast turn 55), so its
    runs are the same bytes. Raising it to 0.04 failed fast turn 14's blank wall, whose recovery did worse than
    tracking (eleventh session of 2026-11-28)."""
    max_log_gain: float = 0.7
    """Tracking fails when the brightness gain leaves exp(+-0.7) = [0.5, 2]: no camera's exposure changes that
    much between frames; an unrelated image is often "explained" by a gain near 0."""
    rolling_shutter_readout: float = 0.0
    """With ``rolling_shutter_estimate`` false: the sensor's readout time as a fraction of the frame interval (0: a
    global shutter; negative: the rows read from the image's bottom up, a camera mounted upside down). Other than 0
    every frame is rectified to a global shutter at mid-readout before tracking
    (:mod:`codeslam.geometry.rolling_shutter`), with the angular velocity of the motion model (the last
    inter-frame rotation): its image, depth and mask, and its keypoints. A frame that becomes a keyframe is
    rectified again with the rotation from the last frame to its tracked pose (one frame more recent than the
    guess). A readout set by hand does harm where the camera has none (at 0.5: the generator's global-shutter walk
    0.061 -> 0.128 m, the HoloLens walk 0.139 -> 0.514 m); TUM RGB-D's Kinect: 0.5 (fr1/rpy, 1 thread, three
    start frames: orientation 1.7-6.4 -> 1.35-1.50 deg, ATE 0.026-0.040 -> 0.016-0.017 m; 0.3, 0.7 and 0.9 worse;
    docs/results/slam_table.md, session of 2026-11-26)."""
    rolling_shutter_estimate: bool = True
    """Choose the readout online (:mod:`codeslam.slam.readout`; ``rolling_shutter_readout`` is then not used): the
    first frames that turn against their keyframe are aligned again with their image rectified under each candidate
    readout, and the one that explains them best is taken (provisionally after 10 such frames, finally after 40; a
    global shutter when no candidate does clearly better, final as soon as the frames settle it). The datasets carry
    no readout, and a camera's own video rarely states one. Measured (1 thread, one run each,
    docs/results/slam_table.md, session of 2026-11-26, second): TUM fr1/rpy chooses 0.59 (0.75 from start frames
    5-15 and with the sensor's depth), the HoloLens and generator walks a global shutter (their trajectories
    unchanged to the last digit); TUM from frames 0 / 5 / 10 / 15: 1.71 / 6.37 / 3.35 / 2.82 deg -> 1.42 / 1.53 /
    1.15 / 2.94 deg (a hand-set 0.5: 1.38 / 1.35 / 1.50 / 1.68). The candidates are signed (rows read top down or
    bottom up; a camera upside down reads them bottom up): TUM fr1/rpy turned by 180 degrees 0.0382 m, 5.98 deg
    -> 0.0236 m, 2.18 deg (its readout -0.75; with the dataset's depth 0.0274 m, 1.53 deg -> 0.0113 m, 1.13 deg,
    upright 0.0122 m, 1.03 deg); upright runs unchanged to the byte (session of 2026-12-05, forty-sixth). The rows
    run along the frames' ``readout_axis`` (a portrait video's: the columns; TUM as one, four encodings: 0.040-0.044
    -> 0.023-0.028 m in three, 0.041 -> 0.045 m in one; as a landscape one 0.020-0.023 m). Costs seven alignments
    at the finest level for each of the first 10 informative frames, four after (one direction kept), none once
    chosen: on TUM 6.4 ms per frame averaged over the run at one thread (5.1 with positive candidates alone)."""
    rolling_shutter_restart: int = 200
    """With ``rolling_shutter_estimate``: when the choice is final within this many frames and some frame before it
    was rectified by another readout (0 while the evidence gathers, then the best so far), the run starts over from
    its first frame with every frame rectified by the chosen readout (:meth:`CodeSLAM.restart_with_readout`); 0:
    never. Those frames were tracked and made keyframes under a readout the camera does not have, and the map keeps
    them: TUM fr1/rpy's first 47 frames carried 2.25 deg RMSE of rotation error, the rest 1.08 deg. Measured
    (docs/results/slam_table.md, fifty-fifth session; 1 thread, Zen 5): TUM fr1/rpy 0.0159 m, 1.46 deg -> 0.0092 m,
    1.08 deg at 1.25 times the frames processed; runs that choose a global shutter, having rectified no frame,
    unchanged to the byte; with the dataset's depth (``--depth-model standin``) TUM 0.0129 -> 0.0214 m from frame 0,
    0.0088 / 0.0130 -> 0.0075 / 0.0086 m from frames 1 and 2 (fifty-eighth session). The parallel mode starts over
    too (fifty-eighth session; 2 threads, Zen 3, three runs each, none -> the restart): TUM from frame 0 0.014-0.018
    -> 0.015-0.019 m, 1.46-1.59 -> 1.16-1.44 deg; from frame 15, where the camera is turning, 0.027-0.029 ->
    0.0144-0.0146 m, 2.05-2.19 -> 1.22-1.35 deg (the sequential run's 1.22 deg), at 8.9-10.8 -> 6.6-8.4 frames/s
    (on Zen 5 from frame 0: 17.3 -> 14.5 frames/s whole process, 0.013 -> 0.018-0.021 m)."""

    def __post_init__(self) -> None:
        _check_levels("tracker", self.pyramid_levels, self.max_iterations)
        if self.feature_start_level != -1 and not 0 <= min(self.pyramid_levels) <= self.feature_start_level:
            raise ConfigError(f"tracker.feature_start_level must be -1 or a level no finer than the finest of "
                              f"pyramid_levels {self.pyramid_levels}, got {self.feature_start_level}")
        if self.rolling_shutter_restart < 0:
            raise ConfigError(f"tracker.rolling_shutter_restart must be >= 0 (0: never), got "
                              f"{self.rolling_shutter_restart}")
        if not -1.0 <= self.rolling_shutter_readout <= 1.0:
            raise ConfigError("tracker.rolling_shutter_readout must lie in [-1, 1] (a signed fraction of the frame "
                              "interval), "
                              f"got {self.rolling_shutter_readout}")
        if self.motion_model not in MOTION_MODELS:
            raise ConfigError(f"tracker.motion_model must be one of {MOTION_MODELS}, got {self.motion_model!r}")
        if not self.max_rotation_from_prediction_deg >= 0:
            raise ConfigError("tracker.max_rotation_from_prediction_deg must be >= 0 (0: off), got "
                              f"{self.max_rotation_from_prediction_deg}")
        for name in ("min_overlap", "min_inlier_ratio"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"tracker.{name} must lie in [0, 1], got {getattr(self, name)}")
        if not self.relative_cost_tolerance > 0:
            raise ConfigError(f"tracker.relative_cost_tolerance must be positive, got {self.relative_cost_tolerance}")
        if self.min_explained_variance > 1.0:
            raise ConfigError(f"tracker.min_explained_variance must be <= 1, got {self.min_explained_variance}")
        if not self.min_intensity_std >= 0:
            raise ConfigError(f"tracker.min_intensity_std must be >= 0, got {self.min_intensity_std}")
        if not self.max_log_gain > 0:
            raise ConfigError(f"tracker.max_log_gain must be positive, got {self.max_log_gain}")
        if not self.inlier_sigmas > 0:
            raise ConfigError(f"tracker.inlier_sigmas must be positive, got {self.inlier_sigmas}")
        for name in ("motion_prior_acceleration", "motion_prior_angular_acceleration_deg"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"tracker.{name} must be >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class FeatureConfig:
    """Sparse ORB features (:mod:`codeslam.slam.frontend`): the initial pose of every alignment, reprojection
    residuals beside the photometric ones, and relocalisation. Not in the paper, whose tracker starts from the
    motion model alone; measured on the HoloLens walk (oracle depth, frames three apart), that start fails 11 of 19
    alignments and the PnP start none."""

    enabled: bool = True
    """Use features (False: the paper's purely photometric tracker with a motion-model start)."""
    scale: int = 4
    """The feature camera is the network's camera with this many times the pixels per axis (512x384 for
    128x96): keypoints need more pixels than the network's input holds."""
    n_features: int = 1000
    """ORB keypoints per image."""
    fast_threshold: int = 12
    """FAST's intensity threshold (0-255): lower finds more keypoints on low-contrast indoor surfaces."""
    match_ratio: float = 0.85
    """Lowe's ratio test: best Hamming distance below this fraction of the second best."""
    max_hamming: int = 64
    """Largest descriptor distance (of 256 bits) accepted as a match."""
    guided_radius: float = 24.0
    """Guided matching: candidates within this many feature-camera pixels of the predicted position."""
    pnp_threshold: float = 3.0
    """RANSAC inlier threshold of the reprojection error (feature-camera pixels)."""
    min_inliers: int = 20
    """PnP needs at least this many inliers to give a pose."""
    ransac_iterations: int = 100
    """RANSAC hypotheses at most (OpenCV stops earlier once confident)."""
    sigma: float = 1.5
    """Reprojection noise (feature-camera pixels) of a keypoint found at ORB's finest level; scaled by the
    pyramid's scale factor per octave."""
    weight: float = 1.0
    """Weight of the reprojection residuals in the alignment (0: features give the initial pose only)."""
    max_point_depth: float = 10.0
    """A keyframe's keypoint gets no 3D point when its decoded depth lies beyond this many times the keyframe's
    median depth: the linear decoder p0 + J c can take a region's proximity to zero (depth without bound).
    Measured on the HoloLens walk with the dataset's depth: after a window solve 18% of a keyframe's pixels lay at
    15 km (median 2.4 m), its keypoints all among them, and PnP on those points put the next frame 540 m away."""
    min_agreement: float = 0.0
    """When the aligned pose keeps fewer than this fraction of PnP's inliers, the alignment has left the pose the
    matches agree on, and the PnP pose is taken instead (0: never). Off by default since measured: of the 20 frames
    where 0.5 took PnP's pose (TUM fr1/rpy, HoloLens walk, generator walk and hand-held, network depth), the
    aligned pose was nearer the true rotation in 14 (TUM's blurred frames 17, 22-24: 5-8 deg against PnP's 8-11;
    HoloLens: 0.2-2.7 against 1.8-5.3); ATE Sim(3) at 0 against 0.5 over start frames 0/5/10 (TUM), 0/4
    (HoloLens), 0/5 (generator walk): TUM 0.026/0.039/0.041 m against 0.043/0.044/0.043 (RPE 12-16 against
    20-22 mm; rotation 1.7/6.3/4.0 deg against 3.6/3.8/3.3), HoloLens 0.155/0.137 against 0.139/0.238, walk
    0.058/0.066 against 0.082/0.100; hand-held and fast turn unchanged (docs/results/slam_table.md)."""

    retry_agreement: float = 0.5
    """When the aligned pose keeps fewer than this fraction of PnP's inliers, PnP's pose may have been a wrong
    start (its RANSAC consensus a minority of repeated texture): the alignment is run again from the motion
    model's prediction through every pyramid level, and the pose with the lower cost (the same cost, both
    minimised) is kept (0: never). Measured on the generator corridor at 160x120 (the preset test), frame 12: PnP
    184 mm from the truth with 41 inliers, the prediction 25 mm; aligned from PnP's pose 122 mm off at cost 6673,
    kept 12 of the 41; the cost from the prediction is lower (5607 in a run that took it). Where the two starts
    were both aligned on every frame (TUM fr1/rpy, the generator corridor at 320x240, 1 thread), they reached
    the same cost within 2% on all 288 frames, so the retry changes nothing where PnP is right."""
    direct_first: str = "parallel"
    """Keypoints on demand: "never" (every frame's keypoints, as before), "parallel" (in the parallel mode only) or
    "always". A frame is then aligned photometrically from the motion model's prediction alone, without ORB
    keypoints, when the last frame's tracked pose lay within ``direct_first_deg`` of its own prediction (its
    rotation error plus its translation error over the keyframe's median depth, in radians, as degrees: the
    prediction's error in the image, scale-free), starting at ``tracker.feature_start_level`` as a PnP start does.
    The keypoints are extracted when that alignment fails or moves the pose more than twice ``direct_first_deg``
    from the prediction (then the frame is tracked as any other, from PnP), when the frame becomes a keyframe
    (its keypoints are the map's), and for every frame after one whose prediction missed. DSO's tracker never
    extracts keypoints; ORB + PnP widen the basin where the motion model is off, and their 512x384 keypoints add
    precision where the photometric term has little texture. Measured (docs/results/slam_table.md, thirty-sixth
    session): parallel mode (``--parallel --threads 2``, eight rounds alternating) TUM fr1/rpy 0.83-1.01x the wall
    time (median 0.89x; one bench_slam run 1.10x), its maps 0.012-0.019 m and 1.37-1.50 deg against 0.013-0.022 m
    and 1.31-1.81 deg, the hand-held preset 0.83x (0.087 -> 0.069 m), the HoloLens walk and the fast turn within
    their spread; sequential (``--threads 1``, the suite) the fast turn's orientation 0.45 -> 1.48 deg and TUM 0.0099 ->
    0.0114 m, so the sequential mode keeps every frame's keypoints by default."""
    direct_first_deg: float = 1.0
    """How close to its prediction the last frame must have been for keypoints to be put off (``direct_first``)."""

    def __post_init__(self) -> None:
        if self.scale < 1:
            raise ConfigError(f"features.scale must be >= 1, got {self.scale}")
        if not self.max_point_depth > 1:
            raise ConfigError(f"features.max_point_depth must be > 1, got {self.max_point_depth}")
        if self.n_features < 10 or self.min_inliers < 6:
            raise ConfigError("features.n_features must be >= 10 and features.min_inliers >= 6")
        if not 0 < self.match_ratio <= 1:
            raise ConfigError(f"features.match_ratio must lie in (0, 1], got {self.match_ratio}")
        for name in ("guided_radius", "pnp_threshold", "sigma"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"features.{name} must be positive, got {getattr(self, name)}")
        if self.direct_first not in ("never", "parallel", "always"):
            raise ConfigError(f"features.direct_first must be 'never', 'parallel' or 'always', got "
                              f"{self.direct_first!r}")
        if not self.direct_first_deg > 0:
            raise ConfigError(f"features.direct_first_deg must be > 0, got {self.direct_first_deg}")
        if not self.weight >= 0 or not 0 <= self.max_hamming <= 256 or not 0 <= self.fast_threshold <= 255:
            raise ConfigError("features.weight must be >= 0, max_hamming in [0, 256], fast_threshold in [0, 255]")
        for name in ("min_agreement", "retry_agreement"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"features.{name} must lie in [0, 1], got {getattr(self, name)}")
        if self.ransac_iterations < 1:
            raise ConfigError(f"features.ransac_iterations must be >= 1, got {self.ransac_iterations}")


@dataclass(frozen=True)
class RecoveryConfig:
    """What happens when tracking fails (ORB-SLAM relocalises, DSO re-initialises): relocalise against stored
    keyframes, and after a few lost frames start a new map segment joined to the old one by the motion model."""

    relocalise: bool = True
    """Match a lost frame against the window's and older keyframes (needs features)."""
    min_inliers: int = 30
    """PnP inliers needed to accept a relocalisation (more than tracking needs: there is no prediction)."""
    max_candidates: int = 8
    """Keyframes tried per lost frame, nearest to the predicted pose first."""
    appearance_candidates: int = 4
    """Keyframes tried besides those, the ones whose thumbnail the lost frame looks most like, wherever they are
    (PTAM's relocaliser, :mod:`codeslam.slam.thumbnails`): after a long loss the predicted pose says nothing.
    0: none."""
    lost_frames: int = 3
    """Consecutive lost frames after which the next frame starts a new map segment at its predicted pose."""
    merge_segments: bool = True
    """While a map segment other than the first is mapped, match each new keyframe's frame against the older
    segments' keyframes it looks like, and move the segment into the older map when two successive matches agree
    (:mod:`codeslam.slam.segments`)."""
    merge_agreement: float = 0.1
    """Two matches agree when they put the camera this fraction of the scene depth apart at most..."""
    merge_agreement_deg: float = 3.0
    """... and this many degrees."""
    promote_previous: bool = True
    """When a frame fails against its keyframe, first make the previous frame (tracked, not a keyframe) a keyframe
    and track the frame against it: a reference one frame old instead of one that has left the view."""

    def __post_init__(self) -> None:
        if self.min_inliers < 6 or self.max_candidates < 1 or self.lost_frames < 1 or self.appearance_candidates < 0:
            raise ConfigError("recovery.min_inliers must be >= 6, max_candidates and lost_frames >= 1, "
                              "appearance_candidates >= 0")
        if not (self.merge_agreement > 0 and self.merge_agreement_deg > 0):
            raise ConfigError("recovery.merge_agreement and merge_agreement_deg must be > 0")


@dataclass(frozen=True)
class KeyframeConfig:
    """When a tracked frame becomes a keyframe (paper Sec. 4.3, "once a certain baseline is achieved", PTAM-like).
    Any one criterion suffices; none applies to frames whose tracking failed."""

    min_baseline_ratio: float = 0.08
    """Translation from the last keyframe over that keyframe's median scene depth: enough parallax for stereo."""
    max_rotation_deg: float = 10.0
    """Rotation from the last keyframe (degrees): the view content changes even without translation."""
    min_overlap: float = 0.65
    """Fraction of the last keyframe's pixels still visible in the frame below which the map needs a new view."""
    urgent_overlap: float = 0.45
    """Below this overlap (or at twice the baseline or rotation, or with too few feature inliers) a keyframe is
    urgent: it is made even before ``min_frames_between``, and parallel mapping waits for it instead of tracking on
    against a keyframe that is leaving the view."""
    min_frames_between: int = 2
    """Frames that must pass after a keyframe before the next one (unless urgent): bounds the mapping load."""
    take_when_busy: bool = False
    """Parallel mapping: a keyframe wanted while the mapping thread is busy is taken as an urgent one is (the
    tracker waits for the decoding of the keyframe before it, or stops that keyframe's window solve after its
    current iteration, and hands the new one over), instead of being refused until the thread is idle. Off by
    default: measured (docs/results/slam_table.md, session of 2026-11-28, tenth; ``--parallel --threads 2``, one
    run at a time, ATE Sim(3) refused -> taken) it helps the real sequences and hurts the generator's walks, on
    which nearly every solve is then cut short: TUM fr1/rpy 0.0146-0.0159 m, 1.44-1.61 deg (5 runs) -> 0.0089-
    0.0130 m, 1.03-1.21 deg, 12.1-13.1 -> 10.1-11.6 frames/s; HoloLens walk 0.59-0.71 m (50-52 keyframes) ->
    0.49-0.54 m (88); hand-held preset 0.066-0.071 -> 0.037 m; but generator walk 0.174-0.182 -> 0.218 m, walk 42
    0.277-0.315 -> 0.297-0.380 m, corridor 0.32 m, 0.9 deg -> 0.71 m, 9.3 deg. Again at the fortieth session's head
    (three rounds alternating, same flags; refused -> taken): the HoloLens walk 0.33 / 0.77 (4 frames lost) / 0.31 m,
    9.8-26.5 deg -> 0.21 / 0.21 / 0.17 m, 4.6-5.8 deg (52 -> 88 keyframes), TUM 1.46-1.56 -> 1.28-1.34 deg
    (0.013-0.015 -> 0.013-0.016 m), the generator walk 0.16-0.20 -> 0.10 m, but the corridor 0.18 -> 0.25 m and the
    hand-held preset 0.07-0.08 -> 0.08-0.10 m, at 1.3-1.8 times the wall time (HoloLens 40-42 -> 54-62 s, TUM
    14-19 -> 18-27 s). Still off: the parallel mode's point is speed; set it for a parallel map that holds."""
    min_feature_inliers: int = 0
    """With features: a tracked frame whose pose rests on fewer ORB + PnP inliers against the keyframe than this
    becomes a keyframe (urgent, and exempt from the poor-photometric-fit hold), so that the next frames match its
    fresh keypoints (ORB-SLAM inserts a keyframe when the points it tracks thin out); 0 switches it off. Off by
    default: measured at 50 (1 thread, one run each): TUM fr1/rpy 0.036 -> 0.043 m, HoloLens walk 0.188 ->
    0.330 m, every second HoloLens frame 0.60 -> 0.75 m (0 lost either way, thanks to
    ``recovery.promote_previous``); only TUM with the dataset's depth gained (0.045 -> 0.033 m)."""

    def __post_init__(self) -> None:
        if not self.min_baseline_ratio > 0 or not self.max_rotation_deg > 0:
            raise ConfigError("keyframes.min_baseline_ratio and keyframes.max_rotation_deg must be positive")
        if not 0.0 <= self.min_overlap <= 1.0 or not 0.0 <= self.urgent_overlap <= 1.0:
            raise ConfigError("keyframes.min_overlap and keyframes.urgent_overlap must lie in [0, 1], got "
                              f"{self.min_overlap} and {self.urgent_overlap}")
        if self.min_frames_between < 1:
            raise ConfigError(f"keyframes.min_frames_between must be >= 1, got {self.min_frames_between}")
        if self.min_feature_inliers < 0:
            raise ConfigError(f"keyframes.min_feature_inliers must be >= 0, got {self.min_feature_inliers}")


def _default_window_sfm() -> SfMConfig:
    # Window solves start from tracked poses and the previous codes, so fewer, finer levels than the
    # from-scratch SfM default suffice. The geometric noise (SfM's default too since 2026-11-27) is wider than the
    # former 0.08: a window's keyframes are ~10 deg or tens of cm apart and start at the network's single-view
    # depths, which disagree at the true poses by 0.10-0.13 in log depth (robust spread; TUM fr1/rpy, HoloLens
    # walk, generator walk). At 0.08 the term shortened the pan between TUM keyframes by 9%; at 0.25, over two or
    # three start frames each (1 thread): HoloLens walk 0.18-0.26 -> 0.14-0.17 m, generator walk 0.12-0.13 ->
    # 0.08-0.10 m, hand-held 0.032 -> 0.021 m, HoloLens with the dataset's depth 0.70 -> 0.49 m; TUM fr1/rpy
    # 0.034-0.036 -> 0.040-0.044 m (docs/results/slam_table.md, third session of 2026-11-25).
    # A rejected step that promised less than 3e-4 of the cost ends its level: after a rejection the next, more
    # damped step was rejected again 60 of 63 times (TUM fr1/rpy window solves) and 60 of 61 (HoloLens walk), and
    # the steps accepted after a rejection gained 5e-4 of the cost or less. Measured when it became the default
    # (sixth session of 2026-11-25): TUM fr1/rpy, 2 threads, two runs each: iterations per solve 16.5 -> 12.5,
    # window median 1.62-1.70 -> 1.30-1.35 s, 2.84-2.94 -> 3.11-3.32 frames/s, 0.0256 -> 0.0255 m, 1.71 deg; the
    # six 1-thread runs of docs/results/slam_table.md: 12-31% fewer iterations, ATE within their spread (the
    # generator walk with the stand-in depth 0.038-0.059 -> 0.083 m, the HoloLens walk with it 0.41-0.49 ->
    # 0.39 m). At 1e-3 (10.1 iterations on TUM) the window test's gauge move left the codes short of the optimum.
    # The tracker's alignment takes these solver settings too (TUM: 4.98 -> 5.14 iterations per frame).
    # masked_rows 'common': loss (i) at the valid rows' mean, steps judged over the rows both states see
    # (SfMConfig.masked_rows; the tracker's blank-wall turns, session of 2026-11-29). Steps are then rejected less
    # often, so the rejection stop above fired less and solves ran on with steps that gained little (window
    # iterations per solve, 1 thread: TUM fr1/rpy 9.8 -> 14.0, HoloLens walk 13.0 -> 14.6, generator walk 10.7 ->
    # 14.0). An accepted step that gains less than the same 3e-4 of the cost ends the level too (10.3, 10.2, 9.5):
    # 2 threads, sequential, in one bench run each, TUM 7.10 -> 7.90 frames/s (window median 579 -> 478 ms), the
    # HoloLens walk 1.52 -> 1.92 frames/s (1005 -> 798 ms), ATE 0.0125 -> 0.0126 m and 0.139 -> 0.144 m; in the
    # 16-run suite no run more than 3% worse than at 1e-5 but the hand-held preset (0.0050 -> 0.0054 m), TUM and
    # every second HoloLens frame 4-5% better (docs/results/slam_table.md, session of 2026-11-29).
    # weights_per_level: the slant and occlusion weights and the geometric sigmas held through each level's run
    # (SfMConfig.weights_per_level). Recomputed at every trial step, they moved the cost the normal equations do not
    # model: a level's first step was accepted and its next three, each ten times more damped, rejected (TUM fr1/rpy
    # window solves: 1.96 of 4.13 finest-level iterations rejected -> 0.50). In 17 suite runs (1 thread, session
    # of 2026-12-03, thirty-fourth) iterations per solve fell or held on every run (TUM 10 -> 7) and the ATE's
    # geometric mean went 0.95x over the 16 at every frame (TUM fr1/rpy 0.0131 -> 0.0099 m, the four stand-in runs
    # 0.85-0.93x, walks and corridors 0.96-1.03x, the HoloLens walk 1.01x).
    # geometric_pose_min_std: a keyframe pair whose first view is blank (intensity std below 0.1; the tracker's
    # textured views read 0.1-0.2, the shared real sequences' tracked frames 0.146 or more) lets its geometric
    # residuals refine the codes, not move the poses (SfMConfig.geometric_pose_min_std). On the generator's blank
    # walls the term turned the keyframes' disagreeing single-view depths into motion along the optical axis: the
    # fast turn 14 with the dataset's depth stepped up to 27 mm a frame where the camera moved 1-5 mm (rotation
    # error 4.5 deg; without the term's pose rows 0.3 deg). Measured (docs/results/slam_table.md, session of
    # 2026-12-07, sixty-first).
    return SfMConfig(pyramid_levels=(2, 1, 0), max_iterations=(8, 6, 5), sigma_geometric=0.25,
                     rejection_stop_decrease=3e-4, relative_cost_tolerance=3e-4, masked_rows="common",
                     weights_per_level=True, geometric_pose_min_std=0.1)


@dataclass(frozen=True)
class WindowConfig:
    """The sliding window of keyframes optimised jointly (codes and poses, paper Sec. 4.1 and 4.3) and the
    marginalisation of old keyframes into a linear prior."""

    size: int = 4
    """Keyframes optimised jointly; the paper's system uses 4 ("in a 4-keyframes setup")."""
    min_pair_overlap: float = 0.3
    """Keyframe pairs get residuals when this fraction of one's view lands in the other (consecutive keyframes
    always do, so that the window stays connected)."""
    marginalise: bool = True
    """Turn the oldest keyframe's residuals into a linear prior (Schur complement) when it leaves the window;
    False drops them (a plain sliding window, for comparison)."""
    scale_prior_with_level: bool = True
    """Scale the prior by the pixel ratio on coarser levels, whose data terms sum over 4x fewer pixels per level."""
    sfm: SfMConfig = field(default_factory=_default_window_sfm)
    """Residuals, loss functions and solver of the window (and the photometric settings of the tracker)."""
    reprojection_weight: float = 1.0
    """Weight of the matched keypoints' reprojection residuals between the window's keyframes (0: none). They
    keep a keyframe whose photometric residuals vanish (moved out of the others' view, where masked residuals
    cost less than outliers) from running away: measured on the HoloLens walk, such a keyframe moved 284 m in one
    solve without them."""
    depth_scale_sigma: float = 0.3
    """Prior on each keyframe's mean log depth at its zero-code value (:mod:`codeslam.sfm.scale_prior`): how far
    (in log depth) the window may move a keyframe's scale from the network's prediction; 0 switches it off."""
    window_scale_sigma: float = 0.0
    """Prior on the window's keyframes' mean log depth taken together, at their zero-code values
    (:class:`~codeslam.sfm.scale_prior.WindowScalePrior`): how far the window as a whole may move from the
    network's scale, its keyframes' relative scales left to ``depth_scale_sigma``; applied in every solve, not
    marginalised; 0 switches it off. Off by default: at 0.05 (docs/results/slam_table.md, session of 2026-11-28)
    every second HoloLens frame went 0.90 / 0.47 / 0.96 -> 0.24 / 0.51 / 0.28 m over three start frames, but the
    stand-in runs (HoloLens 0.149 -> 0.235 m) and both corridors got worse, and no generator walk reached 1%."""
    code_directions: int = 64
    """Each keyframe's code is optimised in the span of this many leading directions of its decoder's Jacobian
    (:meth:`codeslam.sfm.decoder.LinearDecoder.principal`; 0, or the code size or more: the whole code). The
    tracker and window see a code of this size; the map's files hold the network's code. The window's normal
    equations cost the code size squared per pixel and pair, and the shipped network's 128 directions carry
    99.95% of J_0's energy in their leading 64. Measured (docs/results/slam_table.md, sixth session of
    2026-11-26): TUM fr1/rpy, 1 thread, 3.10 -> 4.83 frames/s, window median 1630 -> 871 ms, marginalisation
    208 -> 104 ms per keyframe; ATE Sim(3) at 64 against the whole code (1 thread, one run each, network): TUM
    0.0160 -> 0.0147 m, HoloLens walk 0.1376 -> 0.1448 m (5.04 -> 4.22 deg), generator walk 0.0607 -> 0.0652,
    hand-held 0.0054 -> 0.0058, corridor 0.2471 -> 0.2381, fast turns 0.0146 -> 0.0142 and 0.0145 -> 0.0147 m. At
    32 (99.4%) the HoloLens walk went to 0.603 m, 15.6 deg."""
    rollback: bool = True
    """Undo a window solve that fails :meth:`SlidingWindow.check`, and one after which the next frame cannot be
    tracked while it could be against the map before the solve."""
    max_rotation_change_deg: float = 10.0
    """A solve may change the relative rotation of consecutive keyframes by at most this much."""
    max_translation_change: float = 1.0
    """... and their relative translation by at most this fraction of the baseline (or of
    ``min_translation_scale`` times the median depth for short baselines)."""
    min_translation_scale: float = 0.1
    """Floor of the baseline the translation change is compared with, as a fraction of the median depth."""
    max_depth_change: float = 1.1
    """... and a keyframe's median depth by at most this much in log (a factor 3). The network's single-view
    scale errs by tens of percent from view to view and the window rightly reconciles it (at 0.4, a factor 1.5,
    solves on the generator's walk were rejected for that and its ATE was 2.4 times higher); what this catches is
    a depth running away. Not applied to the keyframe the solve was made for: its depth before that first solve
    is the network's single view, which can be 3x off the map's scale (the generator's walk 43, frame 83: the
    rejected solve left it so, and the frames tracked against it gained 4.1 deg of rotation error)."""
    max_runaway_share: float = 0.01
    """... and the share of a keyframe's pixels whose decoded proximity it sent to or beyond the ends of (0, 1)
    (depth clamped to infinity or zero) by at most this; 1 switches the test off. No network run of the suite
    ever left a pixel there; the stand-in's smooth code basis did, in the window solves of rotation-only
    keyframes (the generator's walk 43, frames 104-119: up to 2,453 times the zero code's depth at the 95th
    percentile, and the frames tracked against them gained 7.9 deg of rotation error)."""
    motion_prior_acceleration: float = 1.0
    """Constant-velocity prior on consecutive keyframes' positions (:mod:`codeslam.slam.velocity_prior`): the
    acceleration (m/s^2, map units) the camera may hold between two keyframe intervals; 0 switches it off.
    Measured (docs/results/slam_table.md, session of 2026-11-27, fifth; 1 thread, network depth, off -> 1): the
    generator's fast turn 14, whose keyframes on a blank wall the window moved 73-168 mm apart, 6.5 / 7.6 / 7.5
    -> 2.0 / 3.0 / 2.5 deg from start frames 0 / 1 / 2; every second HoloLens frame 1.15 / 0.43 / 1.03 -> 1.01 /
    0.32 / 0.96 m; a generator corridor 0.256 / 0.257 / 0.290 -> 0.219 / 0.156 / 0.268 m; fast turn 13 0.012 /
    0.010 / 0.012 -> 0.014 / 0.015 / 0.014 m; the rest within 0.004 m or better. At 4 it acted too little
    (fast turn 14: 5.2 deg; every second HoloLens frame: 1.20 m), 0.5 was no better than 1."""
    free_scale: bool = False
    """Each keyframe's code gets one more entry, a log scale s of its decoded depth, applied exactly (the depth
    times exp(s); :class:`~codeslam.sfm.decoder.ScaledDecoder`), under the code prior (N(0, 1) on s) and
    ``depth_scale_sigma`` on the whole depth: the code then fits a view's shape at whatever depth its span holds
    it, and the scale is left to the data and the priors. Off by default: measured (docs/results/slam_table.md,
    twenty-fifth session; the window's normal equations with it checked against autograd in float64), the whole
    suite's 18 network runs went 1.34x worse in geometric mean (walk 42 0.232 -> 0.135 m and hand-held 52 0.030 ->
    0.016 m better; the HoloLens walk 0.144 -> 0.262 m, the walk preset 0.064 -> 0.133 m, walk 54 0.145 -> 0.397
    m): the maps no longer grow with the span, they slide down at turns (walk 43: from 0.76 to 0.36 of the truth
    over frames 98-115, scale drift 0.42) with or without the velocity prior, with ``depth_scale_sigma`` 0.1 or
    ``window_scale_sigma`` 0.05, and with each new keyframe started at the map's scale. With ``size: 6`` walk 42
    reaches 0.063 m (0.45% of its path) but the suite is still 1.13x worse and the solves twice as long."""
    map_prior_weight: float = 0.35
    """A new keyframe's zero-code depth is moved this share of the way toward the map's depth in its view, low
    frequencies and shape only (:mod:`codeslam.slam.map_prior`: the window's newest keyframe of the same map segment
    splatted into the new view); 0 leaves the network's prior as it is (the paper). The network's errors are
    view-dependent and mostly smooth, and the window corrects each keyframe's shape while it holds it; this passes
    the correction on. Measured (docs/results/slam_table.md, twenty-eighth session; 1 thread, the suite's 18
    network runs from start frames 0 and 1, 0 -> 0.35): 0.913x the ATE in geometric mean (walk 42 0.232 -> 0.174 m,
    corridor 44 0.223 -> 0.129, walk 54 0.145 -> 0.108, the walk preset 0.064 -> 0.047, TUM 0.0133 -> 0.0117;
    walk 56 0.511 -> 0.547, corridor 53 0.228 -> 0.244). With the dataset's depth (``--depth-model standin``) the
    walk towards a blank wall went 0.049 -> 0.27 m: where the images carry no texture the map's depth is the
    window's guess, and this passes it on. 0.25 and 0.5 were measured worse (0.92, at an 8-pixel low-pass)."""
    map_prior_blur: float = 8.0
    """Width (finest-level pixels, Gaussian sigma) of the low-pass through which the map corrects a new keyframe's
    prior (``map_prior_weight``): the network's fine structure is its view's own, the map's splatted edges are not
    passed on. 4 and 16 were measured worse than 8 (at weight 0.5; docs/results/slam_table.md)."""
    map_prior_span: bool = False
    """The map's correction of a new keyframe's prior (``map_prior_weight``) fitted by the keyframe's code and taken
    as a shift of its zero code along the code's span (``D(I, c)``), instead of added pixel by pixel. For the
    stand-in depth (``--depth-model standin``), whose true depth lies in its code's span by construction: there the
    pixel-wise correction moves the prior off the span, away from a truth the code could reach, and the stand-in
    runs lose what they measure. Measured (docs/results/slam_table.md, twenty-ninth session; 1 thread, start frame
    0), stand-in: the walk towards a blank wall 0.281 -> 0.0495 m (0.049 without the map's prior), the walk preset
    0.0844 -> 0.0509, TUM 0.0127 -> 0.0118. With the network's depth it loses the map's gain (walk 42 0.174 ->
    0.235 m, corridor 44 0.128 -> 0.225, the walk preset 0.047 -> 0.061, as without the map's prior): what the map
    corrects there is what the network's span cannot express. Off by default."""
    interruptible: bool = True
    """Parallel mapping: a keyframe the tracker needs at once (the last one is leaving the view) stops the running
    window solve after its current iteration instead of waiting for all of it, as ORB-SLAM's local mapping stops
    its bundle adjustment for a new keyframe; the next solve goes on from there."""
    interrupt_finest_only: bool = True
    """With ``interruptible``: the tracker's stop reaches a solve in its finest level only; the coarser levels, a
    third of a solve's time, always run whole (the stop waits for them). Cut anywhere, 49-50 of the parallel
    HoloLens walk's 50-51 solves ended after a median of 1-3 iterations of the coarsest level, its keyframes 2.3°
    apart from each other in error (sequential 0.49°). Measured (docs/results/slam_table.md, thirty-seventh
    session; ``--parallel --threads 2``, ATE Sim(3) m, cut anywhere -> finest only, alternating): the HoloLens walk
    0.372-0.514 (median 0.421, 9 runs) -> 0.255-0.420 (median 0.355, 4 runs), rotation 10.9-22.3 -> 9.3-13.1°, the
    final map's keyframe steps 2.3 -> 1.3° off, but 4.5-6.4 -> 2.8-3.7 frames/s; the generator walk 0.197 / 0.201 /
    0.209 -> 0.361 / 0.164 / 0.158, corridor 0.190 / 0.205 / 0.187 -> 0.218 / 0.179 / 0.183, hand-held 0.033 /
    0.066 / 0.062 -> 0.069 / 0.069 / 0.058, TUM fr1/rpy 0.0149-0.0165 m and 1.35-1.48° (4 runs) -> 0.0126-0.0171 m
    and 1.37-1.68° (6 runs, 3 at or above 1.5°; 0.8-1.0x the frames/s there; eleven more in the thirty-eighth
    session: 0.0112-0.0189 m, 1.26-1.61°, median 1.38°, one above 1.5°). False: any level may be cut (before)."""
    coarse_iterations_after_stop: int = -1
    """With ``interrupt_finest_only``: once the tracker's stop has come, each coarser level runs at most this many more
    iterations and the solve goes on to the finest level, where it ends; -1 (the default): they run whole. The tracker
    waits for what runs after its stop: on the parallel HoloLens walk 10.8 of its 37.8 s went to coarse levels
    (docs/results/slam_table.md, fifty-second session). Measured there at 1 (``--parallel --threads 2``, runs
    alternating with the default, one at a time; ATE Sim(3) m, frames/s): the HoloLens walk 0.30-0.45 (median 0.31),
    4.5-5.6 frames/s (median 4.7), 5 runs -> 0.30-0.50 (median 0.35, two runs above 0.4, one 21 deg off in rotation),
    6.1-7.8 (median 6.4), 6 runs; TUM fr1/rpy 0.0137-0.0169, 1.40-1.54 deg, 12.2-15.4 frames/s -> 0.0135-0.0171,
    1.33-1.52 deg, 11.7-14.3 (5 runs each; its mapping keeps up); but the generator's corridor 44 0.257 / 0.256 -> 0.305
    / 0.333 and walk 42 0.223 / 0.219 -> 0.253 / 0.243 at 1.1-1.3x the frames/s (walk 10 0.335 / 0.170 -> 0.178 / 0.162,
    hand-held 0.100 / 0.083 -> 0.072 / 0.084, fast turn the same). Speed for a little of the map on some walks: left for
    a user to choose."""
    coarsest_level: str = "always"
    """When a window solve visits the coarsest level of ``sfm.pyramid_levels``: 'always' (the default), or 'unsettled':
    while the window is not yet full (a young map, whose keyframes start at the network's single views) and after a
    solve that stopped at an iteration cap on some level or was rolled back; otherwise the solve starts one level
    finer (DSO optimises its window at one level). Measured (docs/results/slam_table.md, fifty-third session; ATE
    Sim(3) m): never visiting the coarsest level (32x24) lost the generator walk (0.046 -> 0.55 m, 13 deg); 'unsettled'
    holds it (0.046, 0.044, 0.043 from frames 0, 1, 2), skips the level in about three of four solves and costs the
    window 3-15% less per keyframe (eight sequences, each run by both settings at the same time, ``--threads 1``:
    1.03-1.14x the frames/s); parallel (``--threads 2``) the HoloLens walk 5.95 -> 6.36 and TUM fr1/rpy 14.3 -> 15.4
    frames/s (medians of three and two runs). Not the default: over the 43 suite runs the ATE's geometric mean is
    1.02x, nine runs more than 5% further off (corridor 82 and the HoloLens walk with a tenth of its frames dropped
    1.10x, the stand-in HoloLens walk 1.11x), two better (walk 54, the covered HoloLens walk there and back 0.73x), and
    every second HoloLens frame 0.41 -> 0.94 m, 50 deg off (frames 72-80 turned 8-10 deg wrong). Speed for part of the
    map: a user's choice (README, "Speed")."""
    solve_process: bool = False
    """Parallel mapping on the CPU: the window solve and the marginalisation run in a child process
    (:mod:`codeslam.slam.solve_process`) instead of on the mapping thread, so that their Python work does not take
    turns with the tracker's for the GIL (the same values either way; the sequential mode and a GPU device always
    work in place). Off by default: no whole-run gain on the 2-core machine (docs/results/slam_table.md,
    thirty-fifth session; ``--parallel --threads 2``, three rounds alternating, wall s on the mapping thread -> in
    the child): TUM fr1/rpy 31.8 / 29.7 / 28.6 -> 33.8 / 33.0 / 31.8, the HoloLens walk 40.2 / 39.9 / 42.4 -> 38.3 /
    47.7 / 36.2 (the machine's hour moves either by a quarter). The tracking stage is faster in the child on TUM,
    but the child costs CPU of its own (its start, 3.9 s until ready; pickled copies of the window) that two cores
    do not have to spare."""

    def __post_init__(self) -> None:
        if self.size < 2:
            raise ConfigError(f"window.size must be >= 2 (the initialisation needs two keyframes), got {self.size}")
        if not 0.0 <= self.min_pair_overlap <= 1.0:
            raise ConfigError(f"window.min_pair_overlap must lie in [0, 1], got {self.min_pair_overlap}")
        if not self.depth_scale_sigma >= 0:
            raise ConfigError(f"window.depth_scale_sigma must be >= 0, got {self.depth_scale_sigma}")
        if not 0 <= self.max_runaway_share <= 1:
            raise ConfigError(f"window.max_runaway_share must be in [0, 1], got {self.max_runaway_share}")
        if not self.window_scale_sigma >= 0:
            raise ConfigError(f"window.window_scale_sigma must be >= 0, got {self.window_scale_sigma}")
        if not self.motion_prior_acceleration >= 0:
            raise ConfigError(f"window.motion_prior_acceleration must be >= 0, got {self.motion_prior_acceleration}")
        if not 0.0 <= self.map_prior_weight <= 1.0:
            raise ConfigError(f"window.map_prior_weight must lie in [0, 1], got {self.map_prior_weight}")
        if not self.map_prior_blur > 0:
            raise ConfigError(f"window.map_prior_blur must be > 0, got {self.map_prior_blur}")
        if self.coarsest_level not in COARSEST_LEVEL:
            raise ConfigError(f"window.coarsest_level must be one of {COARSEST_LEVEL}, got {self.coarsest_level!r}")
        if not (isinstance(self.code_directions, int) and self.code_directions >= 0):
            raise ConfigError(f"window.code_directions must be an integer >= 0, got {self.code_directions}")
        if self.free_scale and self.sfm.geometric_space != "log_depth":  # d r_geo / d s_B = -1 needs log depth
            raise ConfigError("window.free_scale needs window.sfm.geometric_space: log_depth")
        if self.free_scale and self.map_prior_weight > 0:  # measured apart only; together a test's window diverged
            raise ConfigError("window.free_scale needs window.map_prior_weight: 0 (the two together are not measured)")
        if self.free_scale and self.sfm.geometric_pose_min_std > 0:  # measured apart only; together a test's
            # window ended with a NaN derivative of the geometric term along its scale (scripts/window_scale_terms.py)
            raise ConfigError("window.free_scale needs window.sfm.geometric_pose_min_std: 0 (the two together are not "
                              "measured)")
        if not (isinstance(self.coarse_iterations_after_stop, int) and self.coarse_iterations_after_stop >= -1):
            raise ConfigError(f"window.coarse_iterations_after_stop must be an integer >= 0, or -1, got "
                              f"{self.coarse_iterations_after_stop}")
        if self.sfm.rolling_shutter:  # the window's marginalisation and the tracker have no readout rotations
            raise ConfigError("window.sfm.rolling_shutter is supported by `codeslam sfm` only, not in SLAM")


@dataclass(frozen=True)
class SLAMConfig:
    """The whole system."""

    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    """Frame-to-keyframe photometric tracking."""
    features: FeatureConfig = field(default_factory=FeatureConfig)
    """Sparse features: initial poses, reprojection residuals, relocalisation."""
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    """Relocalisation and re-initialisation after tracking failures."""
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    """Keyframe selection."""
    window: WindowConfig = field(default_factory=WindowConfig)
    """Sliding-window mapping and marginalisation."""
    device: str = "cpu"
    """Where the optimisation runs (cpu, cuda, cuda:N); tensors follow it, nothing is hard-coded."""
    dtype: str = "float32"
    """Floating-point type of images, decoders and solver (float64 for checks; the normal equations are solved
    in float64 either way)."""
    jacobian_dtype: str = "auto"
    """The type each keyframe's code Jacobian (the network's, Sec. 4.1) is computed in: float32, bfloat16, or
    auto (bfloat16 on a CPU with bfloat16 instructions, ``amx_bf16`` or ``avx512_bf16``, float32 elsewhere and
    with ``dtype: float64``: :func:`codeslam.network.jacobian.jacobian_dtype`). The
    zero-code depth and everything after the Jacobian keep ``dtype``. Measured on a 2-core CPU with AMX (docs/
    results/slam_table.md, thirty-first session; float32 -> bfloat16): a keyframe's decoding 158-212 -> 73-77 ms
    on 2 threads; ATE Sim(3) at 1 thread HoloLens walk 0.1383 -> 0.1381 m, TUM fr1/rpy 0.0127 -> 0.0131 m,
    generator walk 0.0479 -> 0.0487 m, corridor 0.1762 -> 0.1761 m (eight runs: geometric mean 1.009x, inside
    the spread of two draws), every frame tracked in all. On an AMD EPYC with ``avx512_bf16`` and no AMX
    (thirty-ninth session): decoding 155 -> 100 ms median inside a sequential TUM run on 2 threads, that run 1.11x
    the frames/s; nine runs at 1 thread within 0.97-1.01x float32's ATE (geometric mean 0.993x)."""
    trajectory: str = "interpolated"
    """How the final trajectory places a frame that is not a keyframe. 'reference': its reference keyframe's final
    pose times the pose tracked against it (``T_wk T_kf``, as ORB-SLAM and DSO write theirs), so the frames jump
    where they switch keyframe by whatever the window solves changed between the two keyframes. 'interpolated':
    the frames between a keyframe and the next one (tracked against it) take that change in proportion to how far
    along the tracked motion between the two they lie, by parallax (:func:`codeslam.slam.poses.path_fractions`;
    by time where no motion was tracked), so a camera held still stays still (by time, the HoloLens walk with a
    4 s stop moved 0.5 deg and 14 mm through it; forty-ninth session), and a run of lost frames between two
    frames with a pose in one map segment lies on the way from the one to the other, by time, instead of where
    the motion model carried the last velocity (a covered lens; fiftieth session). The live poses are the
    tracked and predicted ones either way. Measured when it spread by time (the same runs written both ways, network
    depth, 1 thread): RPE after the Sim(3) scale on TUM fr1/rpy 9.9 -> 9.1 mm, the HoloLens walk 26.0 -> 19.8, the
    generator walk 27.8 -> 14.1, hand-held 8.3 -> 2.5, corridor 41.3 -> 22.7, fast turn 4.0 -> 2.0; ATE Sim(3) 0.0163
    -> 0.0160, 0.1398 -> 0.1376, 0.0632 -> 0.0607, 0.0119 -> 0.0054, 0.2475 -> 0.2471, 0.0138 -> 0.0146 m
    (docs/results/slam_table.md)."""

    trajectory_smoothing: float = 0.05
    """Time scale (seconds) of the smoothing spline that the written trajectory's positions get once the run has
    ended, each map segment on its own (:mod:`codeslam.slam.smoothing`): motion that reverses faster than this is
    taken for tracking noise; a path linear in time is kept as it is. Rotations, keyframes and the live poses are
    left as they are. 0 switches it off. Measured on the ten runs of docs/results/slam_table.md (third session of
    2026-11-27), the same runs written both ways: RPE after the Sim(3) scale on TUM fr1/rpy 9.2 -> 2.7 mm, the
    HoloLens walk 19.8 -> 18.6, the generator walk 15.2 -> 14.0, hand-held 2.8 -> 1.9, corridor 23.4 -> 23.0,
    fast turns 2.6 -> 2.2 and 3.0 -> 3.1; no ATE grew (TUM 0.0148 -> 0.0123 m). Every time scale from 0.035 to
    0.07 s lowered the RPE of all but one of them (the fast turn with seed 14: 3.0 -> 3.0-3.1 mm); at 30 frames/s
    0.05 s is one and a half frame intervals, at 10 frames/s half of one."""

    def __post_init__(self) -> None:
        if not (isinstance(self.trajectory_smoothing, (int, float)) and self.trajectory_smoothing >= 0):
            raise ConfigError(f"trajectory_smoothing must be a time scale >= 0 (seconds), got "
                              f"{self.trajectory_smoothing!r}")
        if self.trajectory not in TRAJECTORIES:
            raise ConfigError(f"trajectory must be one of {TRAJECTORIES}, got {self.trajectory!r}")
        if self.dtype not in DTYPES:
            raise ConfigError(f"dtype must be one of {DTYPES}, got {self.dtype!r}")
        if self.jacobian_dtype not in JACOBIAN_DTYPES:
            raise ConfigError(f"jacobian_dtype must be one of {JACOBIAN_DTYPES}, got {self.jacobian_dtype!r}")
        if not isinstance(self.device, str) or not self.device:
            raise ConfigError(f"device must be a non-empty string such as 'cpu' or 'cuda', got {self.device!r}")

    @property
    def torch_dtype(self):
        import torch

        return {"float32": torch.float32, "float64": torch.float64}[self.dtype]

    @property
    def decoder_levels(self) -> int:
        """Pyramid levels every keyframe's depth model must provide."""
        return 1 + max(max(self.tracker.pyramid_levels), max(self.window.sfm.pyramid_levels))

    def to_dict(self) -> dict[str, Any]:
        """Plain (YAML-ready) mapping: tuples become lists."""
        return _plain(asdict(self))

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


def _check_levels(section: str, levels: tuple[int, ...], iterations: tuple[int, ...]) -> None:
    if not levels or len(levels) != len(iterations):
        raise ConfigError(f"{section}: pyramid_levels and max_iterations must be non-empty and of equal length")
    if any(lv < 0 for lv in levels) or any(it < 0 for it in iterations):
        raise ConfigError(f"{section}: pyramid levels and iteration counts must be >= 0")


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    return obj


def _overlay(base: Any, updates: Any, section: str) -> Any:
    """``base`` (one of the config dataclasses) with the keys of ``updates`` replaced, recursively."""
    if isinstance(base, SfMConfig):
        if not isinstance(updates, dict):
            raise ConfigError(f"config section '{section}' must be a mapping, got {type(updates).__name__}")
        return SfMConfig.from_dict({**base.to_dict(), **updates})
    if not isinstance(updates, dict):
        raise ConfigError(f"config section '{section}' must be a mapping, got {type(updates).__name__}")
    known = {f.name for f in fields(base)}
    unknown = sorted(str(k) for k in set(updates) - known)
    if unknown:
        where = f"{section} " if section else ""
        raise ConfigError(f"unknown {where}option(s): {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    changes = {}
    for k, v in updates.items():
        name = f"{section}.{k}" if section else k
        current = getattr(base, k)
        if hasattr(current, "__dataclass_fields__"):
            changes[k] = _overlay(current, v if v is not None else {}, name)
        else:
            changes[k] = coerce(name, v, current)
    try:
        return replace(base, **changes)
    except TypeError as e:
        raise ConfigError(f"config section '{section or 'top level'}': {e}") from None


def overlay_config(base: SLAMConfig, updates: dict[str, Any]) -> SLAMConfig:
    """``base`` with a (YAML-shaped) mapping of updates applied; validates every touched field."""
    return _overlay(base, updates, "")


def load_config(path: str | os.PathLike | None = None, base: SLAMConfig | None = None) -> SLAMConfig:
    """Read a YAML file (safe loader) and overlay it on ``base`` (the defaults when None)."""
    base = base or SLAMConfig()
    if path is None:
        return base
    return overlay_config(base, read_yaml_mapping(path, "sections tracker, keyframes, window"))
