"""The rolling-shutter readout chosen online from the photometric fit (``tracker.rolling_shutter_estimate``).

A rolling shutter reads the rows one after the other while the camera turns, so each image is distorted by its own
angular velocity; two images aligned as global shutters disagree by the *difference* of their velocities (on TUM
fr1/rpy the tracked rotation error follows that difference, correlation +0.62; ``scripts/
rotation_error_vs_velocity.py``). The readout is a property of the camera that the datasets do not carry, so it
is chosen from the images themselves: each informative frame (one that turns against its keyframe by more than
``min_turn_deg`` per frame) that tracked is aligned photometrically again under each hypothesis ``c`` about the
readout, 0 and each candidate (signed: the rows read top down or bottom up): its image rectified so that it keeps
the distortion its keyframe keeps under that hypothesis (first order: the keyframe, rectified by ``s_k`` times its
own turn ``w_k`` when it was made, keeps ``(c - s_k) w_k``; the frame, turning by ``w_f``, is rectified by
``c (w_f - w_k) + s_k w_k``). The mean log ratio of each candidate's RMS residual to that of readout 0 picks the
readout (the parabola's vertex through the best candidate and its neighbours) when the best beats readout 0 by
more than ``margin``, else a global shutter: provisionally from ``min_frames`` such frames on, so that the frames
after it are rectified, and finally after ``frames``, or as soon as a global shutter is settled: from
``min_frames`` on, when every candidate's mean log ratio stays above ``-margin`` by ``confidence`` standard errors
of the mean (the frames' spread). A global shutter is a
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
import statistics
from dataclasses import dataclass, field

import torch

CANDIDATES = (-0.75, -0.5, -0.25, 0.25, 0.5, 0.75)
"""Readouts tried, as signed fractions of the frame interval (a Kinect's rows take about half of it): positive
when the rows are read from the image's top down, negative from its bottom up (a camera mounted upside down, or a
video turned by 180 degrees by its rotation tag: the sensor still reads its own rows top down). Evenly spaced, 0
among them. Measured with positive ones alone (``docs/results/slam_table.md``, session of 2026-12-05,
forty-sixth): TUM fr1/rpy turned upside down found no positive readout better than none and settled as a global
shutter, 0.0382 m and 5.98 deg off against 0.0117 m and 1.34 deg upright."""


@dataclass
class ReadoutChoice:
    """Accumulates the evidence of informative frames: a provisional readout from ``min_frames`` of them on
    (updated with every further one), final after ``frames``, or once a global shutter is settled (``confidence``
    standard errors, module docstring). A camera reads its rows one way: from ``min_frames`` on, once the best
    candidate of one direction fits better than the other direction's best by ``confidence`` standard errors of
    their per-frame difference, that direction is kept (``side``) and only its candidates are weighed after that,
    which saves three of the seven alignments of each later frame (about 5 ms each on TUM fr1/rpy at one thread).
    The direction waits for that evidence: kept on the best candidate's mean alone at the tenth frame, TUM fr1/rpy
    started at frame 15 kept the bottom-up side on a mean log ratio of 0.019 against the top-down side's 0.021
    (frames 18, 20 and 21, where the turn slows down and picks up again, fit worse rectified either way), then
    settled as a global shutter on its three candidates at frame 30: 3.67 deg of rotation error, against 1.22 deg
    with the readout set to 0.75 (docs/results/slam_table.md, fifty-eighth session).

    value: None before ``min_frames`` informative frames, then the readout chosen so far (0.0: a global shutter);
    decided_at: the index of the frame that made it final; side: 0 while both directions are weighed, then +1
    (rows read top down) or -1 (bottom up); ratios: each frame's log ratio per candidate (NaN: not weighed), the
    one record of the evidence (the counts, sums and means are read from it)."""

    frames: int = 40
    min_frames: int = 10
    min_turn_deg: float = 0.5
    margin: float = 0.03
    confidence: float = 3.0
    ratios: list[tuple[float, ...]] = field(default_factory=list)
    seen: int = 0
    side: int = 0
    value: float | None = None
    decided_at: int | None = None

    def _sums(self, i: int) -> tuple[int, float, float]:
        """Candidate ``i``'s count of frames weighed, and the sum of its log ratios and of their squares, added
        frame by frame in order (an explicit loop: Python 3.12's ``sum`` compensates, and the choice must not
        depend on the interpreter)."""
        n, s, sq = 0, 0.0, 0.0
        for f in self.ratios:
            y = f[i]
            if not math.isnan(y):
                n, s, sq = n + 1, s + y, sq + y * y
        return n, s, sq

    @property
    def count(self) -> list[int]:
        """The number of frames each candidate was weighed on."""
        return [self._sums(i)[0] for i in range(len(CANDIDATES))]

    @property
    def final(self) -> bool:
        return self.seen >= self.frames or self.global_shutter_settled()

    @property
    def candidates(self) -> tuple[float, ...]:
        """The readouts still weighed: every candidate, then those of the direction kept (``side``)."""
        return tuple(c for c in CANDIDATES if self.side * c >= 0)

    def means(self) -> dict[float, float]:
        """Mean log residual ratio of each candidate weighed so far, over the frames it was weighed on."""
        sums = [self._sums(i) for i in range(len(CANDIDATES))]
        return {c: s / n for c, (n, s, _) in zip(CANDIDATES, sums) if n}

    def global_shutter_settled(self) -> bool:
        """Whether every candidate still weighed has its mean log ratio above ``-margin`` by ``confidence``
        standard errors of the mean (sample spread of the frames' ratios), from ``min_frames`` informative frames
        on."""
        if self.seen < max(self.min_frames, 2):
            return False
        for c in self.candidates:
            i = CANDIDATES.index(c)
            n, s, sq = self._sums(i)
            mean = s / n
            var = max(sq - n * mean * mean, 0.0) / (n - 1)
            if mean - self.confidence * math.sqrt(var / n) < -self.margin:
                return False
        return True

    def informative(self, turn: torch.Tensor) -> bool:
        """Whether a frame whose rotation vector relative to its keyframe is ``turn`` (3,) (radians per frame: the
        frame's own turn from the last frame minus the keyframe's) can still tell readouts apart."""
        return not self.final and math.degrees(float(turn.norm())) >= self.min_turn_deg

    def add(self, base: float, residuals: dict[float, float], index: int | None = None) -> None:
        """One informative frame (``index``): the RMS residual of its alignment under readout 0 (``base``) and
        under each candidate of :attr:`candidates` (``residuals``, by readout; others are not read)."""
        r = [residuals.get(c, math.nan) for c in self.candidates]
        if self.final or not (base > 0 and all(x > 0 and math.isfinite(x) for x in r)):
            return  # an alignment without overlap says nothing
        frame = [math.nan] * len(CANDIDATES)
        for c, x in zip(self.candidates, r):
            frame[CANDIDATES.index(c)] = math.log(x / base)
        self.ratios.append(tuple(frame))
        self.seen += 1
        if self.seen >= min(self.min_frames, self.frames):
            if self.side == 0:
                self.side = self.direction()
            self.value = choose({c: m for c, m in self.means().items() if c in self.candidates}, self.margin)
        if self.final:  # settled as a global shutter implies value 0.0: every mean lies above -margin
            self.decided_at = index

    def direction(self) -> int:
        """+1 (rows read top down) or -1 (bottom up) when the best candidate of that direction fits better than the
        other direction's best by ``confidence`` standard errors of the mean of their per-frame difference (sample
        spread, over the frames that weighed both); 0 while the frames cannot tell them apart."""
        means = self.means()
        top = min((c for c in means if c > 0), key=means.__getitem__, default=None)
        bottom = min((c for c in means if c < 0), key=means.__getitem__, default=None)
        if top is None or bottom is None:
            return 0
        i, j = CANDIDATES.index(top), CANDIDATES.index(bottom)
        d = [f[i] - f[j] for f in self.ratios if not (math.isnan(f[i]) or math.isnan(f[j]))]
        if len(d) < 2:
            return 0
        mean = statistics.fmean(d)
        if mean == 0.0 or abs(mean) <= self.confidence * statistics.stdev(d) / math.sqrt(len(d)):
            return 0
        return 1 if mean < 0 else -1

    def summary(self) -> dict:
        """What was decided and on what evidence (mean log residual ratio per candidate over the frames it was
        weighed on), for the run's result."""
        return {"readout": self.value, "frames": self.seen, "decided_at_frame": self.decided_at,
                "mean_log_residual_ratio": {str(c): m for c, m in self.means().items()}}


def choose(means: dict[float, float], margin: float) -> float:
    """The readout from the mean log residual ratio of each candidate weighed (``means``, by readout: evenly
    spaced candidates, one side of 0 or both) to the unrectified alignment (0 at readout 0): a global shutter (0.0)
    unless the best candidate beats it by more than ``margin``; else the vertex of the parabola through the best
    candidate and its neighbours in readout (readout 0 is the neighbour of the candidates nearest it), kept within
    half a step of it; the candidate itself at either end."""
    s, v = zip(*sorted({0.0: 0.0, **means}.items()))  # by readout
    best = min(range(len(v)), key=v.__getitem__)
    if s[best] == 0.0 or v[best] >= -margin:
        return 0.0
    if best in (0, len(v) - 1):
        return s[best]
    h = s[best + 1] - s[best]
    curvature = v[best - 1] - 2.0 * v[best] + v[best + 1]
    shift = 0.5 * h * (v[best - 1] - v[best + 1]) / curvature if curvature > 0 else 0.0
    return s[best] + max(-0.5 * h, min(0.5 * h, shift))
