"""Multi-resolution hash encoding (Instant-NGP) of normalised positions (METHOD.md section 3).

Level ``l`` has resolution ``N_l = floor(base * b^l)`` with ``b = (max / base)^(1 / (L - 1))``; its grid
has ``(N_l + 1)^3`` vertices. A level with at most ``2^log2_hashmap_size`` vertices is indexed densely
(``x + y (N_l+1) + z (N_l+1)^2``), the others by the spatial hash ``(x ^ y*pi_1 ^ z*pi_2) mod T`` with
``pi = (1, 2654435761, 805459861)``. Features are interpolated trilinearly; the table is initialised
``U(-1e-4, 1e-4)``.

Two interchangeable backends compute the same function:

- ``torch``: index arithmetic in int32 (the hash primes wrap to int32; only the low bits survive the
  power-of-two modulus), one ``index_select`` gather and one ``index_add_`` scatter. It supports
  gradients with respect to the input points (needed by -OPT, METHOD section 14) and any device.
- ``cpp``: a fused gather + trilinear forward, a conflict-free scatter backward and the gradient with
  respect to the points (nvf/csrc/hashgrid.cpp), compiled on first use with
  ``torch.utils.cpp_extension`` into the user's cache. float32 CPU tensors only.

``backend="auto"`` uses ``cpp`` where it applies and the extension builds (a compiler and the
``ninja`` package are needed), ``torch`` otherwise.
"""

import math
from types import ModuleType

import torch
from jaxtyping import Float, Int
from torch import Tensor, nn

from nvf import kernels

BACKENDS = ("auto", "torch", "cpp")
_PRIMES = (1, 2654435761, 805459861)  # METHOD section 3 (pi)
# The C++ kernel requests table rows this many samples ahead of their use (software prefetch, 0 = off); the
# outputs do not depend on it. 16 was the fastest at the paper's 2^19 table and costs nothing at 2^15
# (results/bench/paper_profile.md).
PREFETCH_AHEAD = 16


def _to_int32(value: int) -> int:
    """Two's-complement int32 of ``value`` (multiplication then wraps like uint32)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value


def level_resolutions(num_levels: int, base_resolution: int, max_resolution: int) -> list[int]:
    """``N_l = floor(base * b^l)``, ``b = (max / base)^(1/(L-1))`` (METHOD section 3)."""
    if num_levels == 1:
        return [base_resolution]
    growth = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (num_levels - 1))
    # +1e-9 guards floor() against 511.99999... at exact powers of the growth factor.
    return [int(math.floor(base_resolution * growth**level + 1e-9)) for level in range(num_levels)]


def cpp_extension() -> ModuleType | None:
    """The compiled hash-grid kernels (``nvf.kernels.hashgrid``); ``None`` if they cannot be built."""
    return kernels.hashgrid()


class _GatherInterp(torch.autograd.Function):
    """``out[n, l] = sum_c w[n, l, c] * table[idx[n, l, c]]``: one gather forward, one scatter backward."""

    @staticmethod
    def forward(ctx, table: Tensor, idx: Tensor, weights: Tensor) -> Tensor:
        n, levels, corners = weights.shape
        feats = table.index_select(0, idx.reshape(-1)).view(n * levels, corners, table.shape[1])
        out = torch.bmm(weights.reshape(n * levels, 1, corners), feats).view(n, levels, table.shape[1])
        ctx.save_for_backward(table, idx, weights)
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor | None, None, Tensor | None]:
        table, idx, weights = ctx.saved_tensors
        n, levels, corners = weights.shape
        features = table.shape[1]
        g = grad_out.reshape(n * levels, 1, features)
        grad_table = grad_weights = None
        if ctx.needs_input_grad[0]:
            # A 1-D scatter over flat (row, feature) indices is ~5x faster than index_add_ of 2-D rows.
            values = torch.bmm(weights.reshape(n * levels, corners, 1), g).view(-1)
            flat = (idx.reshape(-1, 1).long() * features + torch.arange(features, device=idx.device)).view(-1)
            grad_table = torch.zeros_like(table).view(-1).index_add_(0, flat, values).view_as(table)
        if ctx.needs_input_grad[2]:
            feats = table.index_select(0, idx.reshape(-1)).view(n * levels, corners, features)
            grad_weights = torch.bmm(feats, g.transpose(1, 2)).view(n, levels, corners)
        return grad_table, None, grad_weights


class _CppHashGrid(torch.autograd.Function):
    """Fused C++ forward (skipped when the output is ``known``); backward gives the table gradient
    (scatter) and, if needed, the points' gradient."""

    @staticmethod
    def forward(
        ctx,
        table: Tensor,
        u: Tensor,
        levels: Tensor,
        offsets: Tensor,
        n_dense: int,
        hash_mask: int,
        known: Tensor | None,
        ahead: int,
    ):
        ctx.save_for_backward(table, u, levels, offsets)
        ctx.meta = (n_dense, hash_mask, ahead)
        if known is not None:
            return known.clone()
        ext = cpp_extension()
        assert ext is not None, "the C++ kernel is used only once it has built"
        return ext.forward(u, table, levels, offsets, n_dense, hash_mask, ahead)

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        table, u, levels, offsets = ctx.saved_tensors
        n_dense, hash_mask, ahead = ctx.meta
        grad_out = grad_out.contiguous()
        ext = cpp_extension()
        assert ext is not None, "the C++ kernel is used only once it has built"
        grad_table = grad_u = None
        if ctx.needs_input_grad[0]:
            grad_table = ext.backward(grad_out, u, table.shape[0], levels, offsets, n_dense, hash_mask, ahead)
        if ctx.needs_input_grad[1]:
            grad_u = ext.backward_input(grad_out, u, table, levels, offsets, n_dense, hash_mask, ahead)
        return grad_table, grad_u, None, None, None, None, None, None


class HashEncoding(nn.Module):
    """Hash-grid encoding ``[N,3] -> [N, num_levels * features_per_level]`` (METHOD section 3)."""

    _levels: Tensor
    _offsets: Tensor
    _scale: Tensor
    _strides: Tensor
    _primes: Tensor
    _corner: Tensor
    _offsets32: Tensor

    def __init__(
        self,
        num_levels: int = 16,
        features_per_level: int = 2,
        log2_hashmap_size: int = 19,
        base_resolution: int = 16,
        max_resolution: int = 512,
        backend: str = "auto",
    ) -> None:
        super().__init__()
        if backend not in BACKENDS:
            raise ValueError(f"hash-grid backend must be one of {BACKENDS}, got {backend!r}")
        self.num_levels = num_levels
        self.features_per_level = features_per_level
        self.table_size = 2**log2_hashmap_size
        self.backend = backend
        self.prefetch_ahead = PREFETCH_AHEAD  # the C++ kernel's (no effect on the outputs; benchmarks set 0)
        self.resolutions = level_resolutions(num_levels, base_resolution, max_resolution)
        sizes = [min((res + 1) ** 3, self.table_size) for res in self.resolutions]
        dense = [(res + 1) ** 3 <= self.table_size for res in self.resolutions]
        self.n_dense = sum(dense)
        if dense != [True] * self.n_dense + [False] * (num_levels - self.n_dense):
            raise ValueError("hash-grid resolutions must increase with the level")
        offsets = [0]
        for size in sizes[:-1]:
            offsets.append(offsets[-1] + size)
        self.level_sizes = sizes
        self.out_dim = num_levels * features_per_level
        self.table = nn.Parameter(torch.empty(sum(sizes), features_per_level).uniform_(-1e-4, 1e-4))
        res = torch.tensor(self.resolutions, dtype=torch.int32)
        self.register_buffer("_levels", res, persistent=False)
        self.register_buffer("_offsets", torch.tensor(offsets, dtype=torch.int64), persistent=False)
        self.register_buffer("_scale", res.to(torch.float32).view(-1, 1), persistent=False)
        strides = torch.stack([torch.ones_like(res), res + 1, (res + 1) ** 2], dim=1)
        self.register_buffer("_strides", strides[: self.n_dense].view(1, -1, 3, 1), persistent=False)
        primes = torch.tensor([_to_int32(p) for p in _PRIMES], dtype=torch.int32)
        self.register_buffer("_primes", primes.view(1, 1, 3, 1), persistent=False)
        self.register_buffer("_corner", torch.tensor([0, 1], dtype=torch.int32), persistent=False)
        self.register_buffer("_offsets32", torch.tensor(offsets, dtype=torch.int32).view(1, -1, 1), persistent=False)

    def uses_cpp(self, u: Tensor) -> bool:
        """Whether ``forward(u)`` runs the C++ kernel (float32 CPU tensors, backend auto or cpp)."""
        float32 = u.dtype == self.table.dtype == torch.float32
        if self.backend == "torch" or u.device.type != "cpu" or not float32:
            return False
        if self.backend == "cpp":
            if cpp_extension() is None:
                raise RuntimeError("hash-grid backend 'cpp' requested but the C++ kernel failed to build")
            return True
        return cpp_extension() is not None

    def corner_indices(self, u: Float[Tensor, "N 3"]) -> tuple[Int[Tensor, "N L 8"], Float[Tensor, "N L 8"]]:
        """Table rows (int32, level offset included) and trilinear weights of the 8 cell corners."""
        u = u.clamp(0.0, 1.0)
        scaled = u.unsqueeze(1) * self._scale  # [N, L, 3]
        cell = torch.minimum(scaled.detach().floor(), self._scale - 1.0)
        frac = scaled - cell
        cell = cell.to(torch.int32).unsqueeze(-1) + self._corner  # [N, L, 3, 2]
        n_dense = self.n_dense
        parts = []
        if n_dense > 0:
            t = cell[:, :n_dense] * self._strides
            parts.append((t[:, :, 0, :, None, None] + t[:, :, 1, None, :, None] + t[:, :, 2, None, None, :]).flatten(2))
        if n_dense < self.num_levels:
            t = cell[:, n_dense:] * self._primes
            h = t[:, :, 0, :, None, None] ^ t[:, :, 1, None, :, None] ^ t[:, :, 2, None, None, :]
            parts.append((h & (self.table_size - 1)).flatten(2))
        idx = (parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)) + self._offsets32
        w = torch.stack([1.0 - frac, frac], dim=-1)  # [N, L, 3, 2]
        weights = (w[:, :, 0, :, None, None] * w[:, :, 1, None, :, None] * w[:, :, 2, None, None, :]).flatten(2)
        return idx, weights

    def forward(self, u: Float[Tensor, "N 3"], known: Float[Tensor, "N D"] | None = None) -> Float[Tensor, "N D"]:
        """Encode points ``u`` in ``[0,1]^3`` (clamped) into ``[N, num_levels * features_per_level]``.

        ``known``: this encoding of ``u`` with the current table, computed without autograd (the
        renderer's skipping pass). The C++ path then returns it and only runs the backward; the torch
        path recomputes (its backward needs the corner indices anyway).
        """
        if self.uses_cpp(u):
            return _CppHashGrid.apply(
                self.table,
                u.contiguous(),
                self._levels,
                self._offsets,
                self.n_dense,
                self.table_size - 1,
                known,
                self.prefetch_ahead,
            )
        idx, weights = self.corner_indices(u)
        return _GatherInterp.apply(self.table, idx, weights).reshape(u.shape[0], self.out_dim)
