"""The rolling-shutter readout chosen online from the photometric fit (``tracker.rolling_shutter_estimate``).

A rolling shutter reads the rows one after the other while the camera turns, so each image is distorted by its own
angular velocity; two images aligned as global shutters disagree by the *difference* of their velocities (on TUM
fr1/rpy the tracked rotation error follows that difference, correlation +0.62; ``scripts/
rotation_error_vs_velocity.py``). The readout is a property of the camera that the datasets do not carry, so it
is chosen from the images themselves: each informative frame (one that turns against its keyframe by more than
``min_turn_deg`` per frame) that tracked is aligned photometrically again under each hypothesis ``c`` about the
readout, 0 and each candidate: its image rectified so that it keeps the distortion its keyframe keeps under that
hypothesis (first order: the keyframe, rectified by ``s_k`` times its own turn ``w_k`` when it was made, keeps
``(c - s_k) w_k``; the frame, turning by ``w_f``, is rectified by ``c (w_f - w_k) + s_k w_k``). The mean log ratio
of each candidate's RMS residual to that of readout 0 picks the readout (the parabola's vertex through the best
candidate and its neighbours) when the best beats readout 0 by more than ``margin``, else a global shutter:
provisionally from ``min_frames`` such frames on, so that the frames after it are rectified, and finally after
``frames``, or as soon as a global shutter is settled: from ``min_frames`` on, when every candidate's mean log ratio
stays above ``-margin`` by ``confidence`` standard errors of the mean (the frames' spread). A global shutter is a
yes or no that such evidence settles; a rolling shutter's readout is a value that every further frame refines, so
that choice always takes ``frames``. Measured (1 thread, first 70 frames; ``docs/results/slam_table.md``, session of
2026-12-02, thirtieth): the HoloLens walk and the generator's walk and corridor settle at their 10th informative
frame (the lowest of the candidates' bounds at 3 standard errors -0.021 to +0.081 there, +0.075 to +0.120 at the
40th), and the choice was a global shutter from the 10th frame on anyway; TUM fr1/rpy (means -0.10 to -0.26) never
does.
This is model selection by the profiled photometric likelihood (the pose re-optimised for each readout), not the
paper's maths: our own addition, measured in ``docs/results/slam_table.md`` (session of 2026-11-26, second).
Measured before writing it, in whole runs with and without a readout of 0.5: the mean RMS residual of the
non-keyframes fell by 13% on TUM fr1/rpy (19% with the sensor's depth) and rose by 37% on the HoloLens walk and
29% on the generator's global-shutter walk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

CANDIDATES = (0.25, 0.5, 0.75)
"""Readouts tried, as fractions of the frame interval (a Kinect's rows take about half of it)."""


@dataclass
class ReadoutChoice:
    """Accumulates the evidence of informative frames: a provisional readout from ``min_frames`` of them on
    (updated with every further one), final after ``frames``, or once a global shutter is settled (``confidence``
    standard errors, module docstring).

    value: None before ``min_frames`` informative frames, then the readout chosen so far (0.0: a global shutter);
    decided_at: the index of the frame that made it final."""

    frames: int = 40
    min_frames: int = 10
    min_turn_deg: float = 0.5
    margin: float = 0.03
    confidence: float = 3.0
    log_ratio: list[float] = field(default_factory=lambda: [0.0] * len(CANDIDATES))
    log_ratio_sq: list[float] = field(default_factory=lambda: [0.0] * len(CANDIDATES))
    seen: int = 0
    value: float | None = None
    decided_at: int | None = None

    @property
    def final(self) -> bool:
        return self.seen >= self.frames or self.global_shutter_settled()

    def global_shutter_settled(self) -> bool:
        """Whether every candidate's mean log ratio lies above ``-margin`` by ``confidence`` standard errors of the
        mean (sample spread of the frames' ratios), from ``min_frames`` informative frames on."""
        n = self.seen
        if n < max(self.min_frames, 2):
            return False
        for s, ss in zip(self.log_ratio, self.log_ratio_sq):
            mean = s / n
            var = max(ss - n * mean * mean, 0.0) / (n - 1)
            if mean - self.confidence * math.sqrt(var / n) < -self.margin:
                return False
        return True

    def informative(self, turn: torch.Tensor) -> bool:
        """Whether a frame whose rotation vector relative to its keyframe is ``turn`` (3,) (radians per frame: the
        frame's own turn from the last frame minus the keyframe's) can still tell readouts apart."""
        return not self.final and math.degrees(float(turn.norm())) >= self.min_turn_deg

    def add(self, base: float, residuals: list[float], index: int | None = None) -> None:
        """One informative frame (``index``): the RMS residual of its alignment under readout 0 and under each
        candidate."""
        if self.final or not (base > 0 and all(r > 0 and math.isfinite(r) for r in residuals)):
            return  # an alignment without overlap says nothing
        for i, r in enumerate(residuals):
            x = math.log(r / base)
            self.log_ratio[i] += x
            self.log_ratio_sq[i] += x * x
        self.seen += 1
        if self.seen >= min(self.min_frames, self.frames):
            self.value = choose([v / self.seen for v in self.log_ratio], self.margin)
        if self.final:  # settled as a global shutter implies value 0.0: every mean lies above -margin
            self.decided_at = index

    def summary(self) -> dict:
        """What was decided and on what evidence (mean log residual ratio per candidate), for the run's result."""
        n = max(self.seen, 1)
        return {"readout": self.value, "frames": self.seen, "decided_at_frame": self.decided_at,
                "mean_log_residual_ratio": {str(c): v / n for c, v in zip(CANDIDATES, self.log_ratio)}}


def choose(means: list[float], margin: float) -> float:
    """The readout from the mean log residual ratio of each candidate (:data:`CANDIDATES`, evenly spaced) to the
    unrectified alignment (0 at readout 0): a global shutter (0.0) unless the best candidate beats it by more
    than ``margin``; else the vertex of the parabola through the best candidate and its neighbours (readout 0
    counts as the neighbour of the first), kept within half a step of it."""
    s = (0.0, *CANDIDATES)
    v = (0.0, *means)
    best = min(range(len(v)), key=v.__getitem__)
    if best == 0 or v[best] >= -margin:
        return 0.0
    if best == len(v) - 1:
        return s[best]
    h = s[1] - s[0]
    curvature = v[best - 1] - 2.0 * v[best] + v[best + 1]
    shift = 0.5 * h * (v[best - 1] - v[best + 1]) / curvature if curvature > 0 else 0.0
    return s[best] + max(-0.5 * h, min(0.5 * h, shift))
