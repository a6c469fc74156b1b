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
//
// lattice_depth: the same kept samples, each one's density read by trilinear interpolation from a lattice of
// n^3 values (x-major, vertex v at lattice_lo + v step; nvf/density_lattice.py) and summed along its segment:
// returns each segment's sum of densities, its samples taken in bin order and no more once sum x delta_r reaches
// limit (M17's early stop, per sample; infinity: every sample). The torch path reads the same lattice with
// grid_sample, so the two agree to rounding, not bitwise.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

// The inputs both kernels place their samples from, checked, contiguous and held while their pointers are read.
struct LabelSamples {
  torch::Tensor origin, seg, offsets, first, count, box, occupied, grid_lo, cell_size;
  const float *o, *s, *off, *b, *glo, *cs;
  const int64_t *f0, *n;
  const bool* occ;
  int64_t rows, bins, res;
  float k_samples, top;

  LabelSamples(torch::Tensor origin_, torch::Tensor seg_, torch::Tensor offsets_, torch::Tensor first_,
               torch::Tensor count_, int64_t num_samples, torch::Tensor box_, torch::Tensor occupied_,
               torch::Tensor grid_lo_, torch::Tensor cell_size_, int64_t res_)
      : origin(origin_.contiguous()), seg(seg_.contiguous()), offsets(offsets_.contiguous()),
        first(first_.contiguous()), count(count_.contiguous()), box(box_.contiguous()),
        occupied(occupied_.contiguous()), grid_lo(grid_lo_.contiguous()), cell_size(cell_size_.contiguous()),
        res(res_), k_samples(static_cast<float>(num_samples)), top(static_cast<float>(res_)) {
    TORCH_CHECK(seg.device().is_cpu() && seg.scalar_type() == at::kFloat, "label kernel: float32 CPU tensors");
    TORCH_CHECK(first.scalar_type() == at::kLong && count.scalar_type() == at::kLong, "first, count int64");
    TORCH_CHECK(occupied.scalar_type() == at::kBool, "occupied: bool");
    rows = seg.size(0);
    bins = offsets.size(1);
    o = origin.data_ptr<float>();
    s = seg.data_ptr<float>();
    off = offsets.data_ptr<float>();
    f0 = first.data_ptr<int64_t>();
    n = count.data_ptr<int64_t>();
    b = box.data_ptr<float>();
    occ = occupied.data_ptr<bool>();
    glo = grid_lo.data_ptr<float>();
    cs = cell_size.data_ptr<float>();
  }

  // Sample k of segment r, y = o + ((k + offset_rk) / K) s_r, written to y; whether it is kept (in the box and in
  // an occupied cell).
  bool kept(int64_t r, int64_t k, float y[3]) const {
    const float frac = (static_cast<float>(k) + off[r * bins + k]) / k_samples;
    for (int a = 0; a < 3; ++a) y[a] = o[a] + frac * s[3 * r + a];
    bool keep = true;
    int64_t cell = 0;
    for (int a = 0; a < 3; ++a) {
      keep &= y[a] >= b[a] && y[a] <= b[3 + a];
      const float c = std::floor((y[a] - glo[a]) / cs[a]);
      keep &= c >= 0.0f && c < top;
      cell = cell * res + static_cast<int64_t>(std::min(std::max(c, 0.0f), top - 1.0f));
    }
    return keep && occ[cell];
  }
};

std::vector<torch::Tensor> occupied_bins(torch::Tensor origin, torch::Tensor seg, torch::Tensor offsets,
                                         torch::Tensor first, torch::Tensor count, int64_t num_samples,
                                         torch::Tensor box, torch::Tensor occupied, torch::Tensor grid_lo,
                                         torch::Tensor cell_size, int64_t res) {
  const LabelSamples in(origin, seg, offsets, first, count, num_samples, box, occupied, grid_lo, cell_size, res);
  const int64_t rows = in.rows;

  // Rows in blocks, each block's kept samples gathered on its own, then concatenated in block order.
  constexpr int64_t kRows = 512;
  const int64_t blocks = (rows + kRows - 1) / kRows;
  std::vector<std::vector<int64_t>> flat(blocks);
  std::vector<std::vector<float>> pos(blocks);
  at::parallel_for(0, blocks, 1, [&](int64_t begin, int64_t end) {
    for (int64_t blk = begin; blk < end; ++blk) {
      for (int64_t r = blk * kRows; r < std::min(rows, (blk + 1) * kRows); ++r) {
        for (int64_t k = in.f0[r]; k < in.f0[r] + in.n[r]; ++k) {
          float y[3];
          if (in.kept(r, k, y)) {
            flat[blk].push_back(r * in.bins + k);
            pos[blk].insert(pos[blk].end(), y, y + 3);
          }
        }
      }
    }
  });
  int64_t total = 0;
  for (const auto& part : flat) total += static_cast<int64_t>(part.size());
  auto out_flat = torch::empty({total}, in.first.options());
  auto out_pos = torch::empty({total, 3}, in.seg.options());
  int64_t at = 0;
  for (int64_t blk = 0; blk < blocks; ++blk) {
    std::copy(flat[blk].begin(), flat[blk].end(), out_flat.data_ptr<int64_t>() + at);
    std::copy(pos[blk].begin(), pos[blk].end(), out_pos.data_ptr<float>() + 3 * at);
    at += static_cast<int64_t>(flat[blk].size());
  }
  return {out_flat, out_pos};
}

torch::Tensor lattice_depth(torch::Tensor origin, torch::Tensor seg, torch::Tensor offsets, torch::Tensor first,
                            torch::Tensor count, int64_t num_samples, torch::Tensor box, torch::Tensor occupied,
                            torch::Tensor grid_lo, torch::Tensor cell_size, int64_t res, torch::Tensor values,
                            int64_t n, torch::Tensor lattice_lo, torch::Tensor step, torch::Tensor delta,
                            double limit) {
  const LabelSamples in(origin, seg, offsets, first, count, num_samples, box, occupied, grid_lo, cell_size, res);
  TORCH_CHECK(values.scalar_type() == at::kFloat && values.numel() == n * n * n, "values: float32, n^3");
  values = values.contiguous();
  lattice_lo = lattice_lo.contiguous();
  step = step.contiguous();
  delta = delta.contiguous();
  const float* v = values.data_ptr<float>();
  const float* llo = lattice_lo.data_ptr<float>();
  const float* st = step.data_ptr<float>();
  const float* dl = delta.data_ptr<float>();
  const float last = static_cast<float>(n - 2);
  auto out = torch::zeros({in.rows}, in.seg.options());
  float* sum = out.data_ptr<float>();
  at::parallel_for(0, in.rows, 256, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      double total = 0.0;
      for (int64_t k = in.f0[r]; k < in.f0[r] + in.n[r]; ++k) {
        float y[3];
        if (!in.kept(r, k, y)) continue;
        int64_t i[3];
        float f[3];
        for (int a = 0; a < 3; ++a) {
          const float u = (y[a] - llo[a]) / st[a];
          const float base = std::min(std::max(std::floor(u), 0.0f), last);
          i[a] = static_cast<int64_t>(base);
          f[a] = std::min(std::max(u - base, 0.0f), 1.0f);
        }
        const float* c0 = v + (i[0] * n + i[1]) * n + i[2];
        const float* c1 = c0 + n * n;
        const float x00 = c0[0] + (c0[1] - c0[0]) * f[2], x01 = c0[n] + (c0[n + 1] - c0[n]) * f[2];
        const float x10 = c1[0] + (c1[1] - c1[0]) * f[2], x11 = c1[n] + (c1[n + 1] - c1[n]) * f[2];
        const float y0 = x00 + (x01 - x00) * f[1], y1 = x10 + (x11 - x10) * f[1];
        total += y0 + (y1 - y0) * f[0];
        if (total * dl[r] >= limit) break;
      }
      sum[r] = static_cast<float>(total);
    }
  });
  return out;
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("occupied_bins", &occupied_bins, "label samples inside a box and in occupied grid cells");
  m.def("lattice_depth", &lattice_depth, "label segments' density sums read from a lattice");
}
