"""Array conventions of the metrics (PROTOCOL.md 4): images are ``[V, H, W, 3]`` floats, numpy or torch,
clipped to ``[0, 1]`` before any comparison; ``Array`` is either kind."""

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

Array = np.ndarray | Tensor


def as_tensor(x: Array) -> Tensor:
    return x if isinstance(x, Tensor) else torch.from_numpy(np.asarray(x))


def as_numpy(x: Array) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)


def clipped(images: Float[Array, "V H W 3"]) -> Float[Tensor, "V 3 H W"]:
    """Images as float64 ``[V, 3, H, W]`` clipped to [0, 1], on their own device."""
    return as_tensor(images).to(torch.float64).clamp(0.0, 1.0).permute(0, 3, 1, 2)
