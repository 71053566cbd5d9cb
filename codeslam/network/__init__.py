"""The intensity-conditioned variational depth auto-encoder (paper Sec. 2): D = D(I, c).

- :mod:`~codeslam.network.model`: the network (:class:`CodeNetwork`) in one file.
- :mod:`~codeslam.network.jacobian`: the code Jacobian dD/dc (:func:`code_jacobian`).
- :mod:`~codeslam.network.loss`: the Laplace likelihood + KL training loss.
- :mod:`~codeslam.network.weights`: safetensors weights with their config (:func:`load_model`).
- :mod:`~codeslam.network.config`, :mod:`~codeslam.network.data`, :mod:`~codeslam.network.train`: training.
"""

from codeslam.network.config import NetworkConfig, TrainConfig
from codeslam.network.jacobian import code_jacobian
from codeslam.network.model import CodeNetwork, NetworkOutput, to_network_image
from codeslam.network.weights import DEFAULT_WEIGHTS, load_model, save_weights

__all__ = [
    "DEFAULT_WEIGHTS",
    "CodeNetwork",
    "NetworkConfig",
    "NetworkOutput",
    "TrainConfig",
    "code_jacobian",
    "load_model",
    "save_weights",
    "to_network_image",
]
