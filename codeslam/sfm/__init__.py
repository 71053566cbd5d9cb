"""Dense warping and N-frame structure from motion (paper Sec. 3 and 4.1): joint Gauss-Newton over the codes and
poses of keyframes with linear depth decoders.

Entry point: :func:`sfm` (keyframes, pairs, config) -> :class:`SfMResult`. Building blocks for tracking and a
sliding-window back-end: :class:`PairProblem` + :func:`levenberg_marquardt` (level by level:
:func:`coarse_to_fine`) with a :class:`VariableLayout` of free blocks and optional :class:`LinearPrior` terms.
"""

from codeslam.sfm.config import SfMConfig
from codeslam.sfm.decoder import DecoderLevel, LinearDecoder, cosine_basis, standin_decoder
from codeslam.sfm.keyframes import Keyframe, LevelData, build_levels
from codeslam.sfm.pairs import all_pairs, master_pairs, overlapping_pairs, view_overlap
from codeslam.sfm.solver import (
    LMReport,
    PairProblem,
    SfMResult,
    coarse_to_fine,
    levenberg_marquardt,
    sfm,
    solve_damped,
)
from codeslam.sfm.variables import BlockId, LinearPrior, SfMState, VariableLayout

__all__ = [
    "BlockId", "DecoderLevel", "Keyframe", "LevelData", "LinearDecoder", "LinearPrior", "LMReport", "PairProblem",
    "SfMConfig", "SfMResult", "SfMState", "VariableLayout", "all_pairs", "build_levels", "coarse_to_fine",
    "cosine_basis", "levenberg_marquardt", "master_pairs", "overlapping_pairs", "sfm", "solve_damped",
    "standin_decoder", "view_overlap",
]
