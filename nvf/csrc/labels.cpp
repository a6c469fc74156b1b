// The samples of visibility labels (METHOD.md M17) that can have density, for CPU; used by nvf/visibility.py.
//
// occupied_bins: for each segment r of a chunk (origin o, offset s_r) and each bin k in [first_r, first_r +
// count_r), the sample y = o + ((k + offset_rk) / K) s_r; kept if it lies in the box [lo, hi] and in an occupied
// cell of the grid (cell = floor((y - grid_lo) / cell_size), inside [0, res)^3, x-major flat index). Returns the
// kept samples' flat bin index r * B + k (B = offsets' columns) and positions, in row-major order.
//
// It computes what the torch path of nvf/visibility.py computes, operation for operation in float32, so the
// kept samples and their positions are bitwise the same: the file is compiled with -ffp-contract=off (no
// fused multiply-adds, which would round differently).
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

std::vector<torch::Tensor> occupied_bins(torch::Tensor origin, torch::Tensor seg, torch::Tensor offsets,
                                         torch::Tensor first, torch::Tensor count, int64_t num_samples,
                                         torch::Tensor box, torch::Tensor occupied, torch::Tensor grid_lo,
                                         torch::Tensor cell_size, int64_t res) {
  TORCH_CHECK(seg.device().is_cpu() && seg.scalar_type() == at::kFloat, "label kernel: float32 CPU tensors");
  TORCH_CHECK(first.scalar_type() == at::kLong && count.scalar_type() == at::kLong, "first, count int64");
  TORCH_CHECK(occupied.scalar_type() == at::kBool, "occupied: bool");
  origin = origin.contiguous();
  seg = seg.contiguous();
  offsets = offsets.contiguous();
  first = first.contiguous();
  count = count.contiguous();
  box = box.contiguous();
  occupied = occupied.contiguous();
  grid_lo = grid_lo.contiguous();
  cell_size = cell_size.contiguous();
  const int64_t rows = seg.size(0), bins = offsets.size(1);
  const float* o = origin.data_ptr<float>();
  const float* s = seg.data_ptr<float>();
  const float* off = offsets.data_ptr<float>();
  const int64_t* f0 = first.data_ptr<int64_t>();
  const int64_t* n = count.data_ptr<int64_t>();
  const float* b = box.data_ptr<float>();
  const bool* occ = occupied.data_ptr<bool>();
  const float* glo = grid_lo.data_ptr<float>();
  const float* cs = cell_size.data_ptr<float>();
  const float k_samples = static_cast<float>(num_samples);
  const float top = static_cast<float>(res);

  // Rows in blocks, each block's kept samples gathered on its own, then concatenated in block order.
  constexpr int64_t kRows = 512;
  const int64_t blocks = (rows + kRows - 1) / kRows;
  std::vector<std::vector<int64_t>> flat(blocks);
  std::vector<std::vector<float>> pos(blocks);
  at::parallel_for(0, blocks, 1, [&](int64_t begin, int64_t end) {
    for (int64_t blk = begin; blk < end; ++blk) {
      for (int64_t r = blk * kRows; r < std::min(rows, (blk + 1) * kRows); ++r) {
        const float sx = s[3 * r], sy = s[3 * r + 1], sz = s[3 * r + 2];
        for (int64_t k = f0[r]; k < f0[r] + n[r]; ++k) {
          const float frac = (static_cast<float>(k) + off[r * bins + k]) / k_samples;
          const float y[3] = {o[0] + frac * sx, o[1] + frac * sy, o[2] + frac * sz};
          bool keep = true;
          int64_t cell = 0;
          for (int a = 0; a < 3; ++a) {
            keep &= y[a] >= b[a] && y[a] <= b[3 + a];
            const float c = std::floor((y[a] - glo[a]) / cs[a]);
            keep &= c >= 0.0f && c < top;
            cell = cell * res + static_cast<int64_t>(std::min(std::max(c, 0.0f), top - 1.0f));
          }
          if (keep && occ[cell]) {
            flat[blk].push_back(r * bins + k);
            pos[blk].insert(pos[blk].end(), y, y + 3);
          }
        }
      }
    }
  });
  int64_t total = 0;
  for (const auto& part : flat) total += static_cast<int64_t>(part.size());
  auto out_flat = torch::empty({total}, first.options());
  auto out_pos = torch::empty({total, 3}, seg.options());
  int64_t at = 0;
  for (int64_t blk = 0; blk < blocks; ++blk) {
    std::copy(flat[blk].begin(), flat[blk].end(), out_flat.data_ptr<int64_t>() + at);
    std::copy(pos[blk].begin(), pos[blk].end(), out_pos.data_ptr<float>() + 3 * at);
    at += static_cast<int64_t>(flat[blk].size());
  }
  return {out_flat, out_pos};
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("occupied_bins", &occupied_bins, "label samples inside a box and in occupied grid cells");
}
