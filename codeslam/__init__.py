"""codeslam: CodeSLAM (Bloesch et al., CVPR 2018) in PyTorch.

Package layout (one folder per part of the paper):

- ``codeslam.geometry``: Lie groups, pinhole camera, proximity, image pyramids (pure torch functions,
  each paired with its Jacobian).
- ``codeslam.data``: the typed ``Frame`` record, one reader per dataset format, and trajectories with their
  files (TUM, EuRoC CSV) and timestamp association.
- ``codeslam.synth``: the synthetic indoor RGB-D generator (embedded default data).
- ``codeslam.network``: the intensity-conditioned variational depth auto-encoder (Sec. 2).
- ``codeslam.sfm``: dense warping and N-frame structure from motion (Sec. 3, 4.1).
- ``codeslam.slam``: tracking, keyframes, the sliding window with marginalisation (Sec. 4.2, 4.3).
- ``codeslam.eval``, ``codeslam.recon``: trajectory metrics (ATE, RPE, drift) and reconstruction outputs.
- ``codeslam.cli``: the ``codeslam`` command, a thin shell over the above.

Layers point one way: geometry <- data <- network <- sfm <- slam <- eval / recon <- cli
(``tests/test_layers.py`` checks it). Timing is the runner's: the core names its stages on a
:class:`codeslam.clock.Clock` that the runner passes in, and never reads a clock itself (``tests/test_clock.py``).
"""

__version__ = "0.1.0"
