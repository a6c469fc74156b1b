"""DVGO-style dense feature grid: an alternative backbone to the hash grid (METHOD.md section 3; not the paper's).

A ``R^3`` lattice of ``C``-channel feature vectors over ``[0,1]^3`` (vertex ``i`` at ``u = i / (R-1)``),
read by trilinear interpolation; the result equals ``F.grid_sample(..., align_corners=True)`` on the
same lattice. It is the one-level, densely indexed special case of the hash encoding, so it shares
its kernels (torch reference and the C++ gather/scatter), its channels-last table layout (a corner's
``C`` features are contiguous), gradients with respect to the points, and the output interface
``[N, out_dim]``. Features are initialised ``U(-1e-4, 1e-4)`` like the hash table (METHOD section 3).
"""

import math

from jaxtyping import Float
from torch import Tensor

from nvf.encoding import HashEncoding


class DenseGridEncoding(HashEncoding):
    """Dense trilinear grid ``[N,3] -> [N, features]``; ``resolution`` vertices per axis."""

    def __init__(self, resolution: int = 128, features: int = 32, backend: str = "auto") -> None:
        if resolution < 2:
            raise ValueError(f"dense grid resolution must be >= 2, got {resolution}")
        super().__init__(
            num_levels=1,
            features_per_level=features,
            log2_hashmap_size=math.ceil(3 * math.log2(resolution)),
            base_resolution=resolution - 1,
            max_resolution=resolution - 1,
            backend=backend,
        )
        self.resolution = resolution

    def grid(self) -> Float[Tensor, "C R R R"]:
        """The features as a ``[C, R, R, R]`` (z, y, x) volume, the layout of ``F.grid_sample``."""
        r = self.resolution
        return self.table.view(r, r, r, -1).permute(3, 0, 1, 2)
