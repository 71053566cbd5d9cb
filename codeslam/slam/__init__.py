"""Dense monocular SLAM with learned depth codes (paper Sec. 4.2-4.3): photometric tracking against the last
keyframe, PTAM-like keyframe selection, a sliding window of keyframes whose codes and poses are optimised jointly,
and old keyframes marginalised into a linear prior.

Entry points: :class:`CodeSLAM` (the algorithm, one frame at a time) and :func:`codeslam.slam.pipeline.run_slam`
(the runner: dataset loop, resampling, timing, evaluation and outputs).
"""

from codeslam.slam.config import KeyframeConfig, SLAMConfig, TrackerConfig, WindowConfig, load_config
from codeslam.slam.keyframes import KeyframeDecision, decide_keyframe
from codeslam.slam.system import CodeSLAM, DepthModelFactory, FrameResult
from codeslam.slam.tracker import PhotometricTracker, TrackResult
from codeslam.slam.window import MapKeyframe, SlidingWindow, WindowReport, schur_complement

__all__ = [
    "CodeSLAM", "DepthModelFactory", "FrameResult", "KeyframeConfig", "KeyframeDecision", "MapKeyframe",
    "PhotometricTracker", "SLAMConfig", "SlidingWindow", "TrackResult", "TrackerConfig", "WindowConfig",
    "WindowReport", "decide_keyframe", "load_config", "schur_complement",
]
