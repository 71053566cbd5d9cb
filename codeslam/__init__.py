"""codeslam: CodeSLAM (Bloesch et al., CVPR 2018) in PyTorch.

Package layout (one folder per part of the paper):

- ``codeslam.geometry``: Lie groups, pinhole camera, proximity, image pyramids (pure torch functions,
  each paired with its Jacobian).
- ``codeslam.data``: the typed ``Frame`` record and one reader per dataset format.
- ``codeslam.eval``: trajectories (TUM / EuRoC files) and metrics (ATE, RPE, drift).
- ``codeslam.synth``: the synthetic indoor RGB-D generator (embedded default data).
- ``codeslam.network``: the intensity-conditioned variational depth auto-encoder (Sec. 2).
- ``codeslam.sfm``: dense warping and N-frame structure from motion (Sec. 3, 4.1).
- ``codeslam.cli``: the ``codeslam`` command, a thin shell over the above.
"""

__version__ = "0.1.0"
