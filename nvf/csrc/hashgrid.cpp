// Fused multi-resolution hash-grid kernels for CPU (METHOD.md section 3), used by nvf/encoding.py.
//
// forward:  out[n, l*F + f] = sum_c w_c(u_n) * table[offset_l + idx_c(u_n), f]   (gather + trilinear)
// backward: grad_table[offset_l + idx_c(u_n), f] += w_c(u_n) * grad_out[n, l*F + f]
// backward_input: the gradient with respect to u (for -OPT pose refinement)
//
// Index arithmetic matches the torch reference bit for bit: u clamped to [0,1], scaled by N_l,
// cell = min(floor, N_l - 1); dense levels (the first n_dense) use x + y (N_l+1) + z (N_l+1)^2,
// hashed levels (x*1 ^ y*2654435761 ^ z*805459861) & mask in uint32. The forward runs level-outer
// over blocks of samples; the backward is conflict free without atomics: each task owns one level
// and a 16-float slice of the features, i.e. disjoint table entries. Both find a block's cells for one
// level first, as structure-of-arrays loops the compiler vectorises (that arithmetic, not the table
// reads, was three quarters of the forward's time), then read or write the table sample by sample.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

namespace {

struct Levels {
  std::vector<int32_t> res;
  std::vector<int64_t> offset;
};

Levels read_levels(const torch::Tensor& levels, const torch::Tensor& offsets) {
  TORCH_CHECK(levels.scalar_type() == at::kInt && offsets.scalar_type() == at::kLong, "levels int32, offsets int64");
  auto l = levels.contiguous().cpu();
  auto o = offsets.contiguous().cpu();
  Levels out;
  out.res.assign(l.data_ptr<int32_t>(), l.data_ptr<int32_t>() + l.numel());
  out.offset.assign(o.data_ptr<int64_t>(), o.data_ptr<int64_t>() + o.numel());
  return out;
}

// Level-outer loop over blocks of samples: a level's table stays in cache while its block is read
// (3x faster than sample-outer on ray-coherent samples). 256 samples keep a block's cells (BlockCells,
// 22 KiB) in L1: the forward took 2.2 ms for 16k samples x 16 levels against 4.2 ms with 1024 and 3.1 ms
// for the sample-by-sample lookup it replaced.
constexpr int64_t kBlock = 256;

// Every kernel takes `ahead`: table rows are requested that many samples before they are used (software
// prefetch; 0 turns it off). At the paper's 2^19 rows a level no longer fits in the caches and each corner
// read waits on memory (nvf/encoding.py's PREFETCH_AHEAD, results/bench/paper_profile.md). The arithmetic
// and its order do not depend on it, so the outputs are bitwise the same for every value.

// Prefetch the 8 corner rows of sample s (for reading, or for writing with write = 1).
template <int write>
inline void prefetch_corners(const float* base, const uint32_t (&idx)[8][kBlock], int64_t s, int64_t row, int64_t col) {
  for (int c = 0; c < 8; ++c) __builtin_prefetch(base + static_cast<int64_t>(idx[c][s]) * row + col, write);
}

// A block of samples' coordinates, one array per axis: block_points reads them once per block.
struct BlockPoints {
  alignas(64) float xyz[3][kBlock];
};

void block_points(const float* u, int64_t m, BlockPoints& points) {
  for (int64_t s = 0; s < m; ++s)
    for (int k = 0; k < 3; ++k) points.xyz[k][s] = u[3 * s + k];
}

// The 8 corners' table rows and trilinear weights of m <= kBlock samples at one level, corner-major;
// in loops over the samples without branches, which the compiler vectorises.
struct BlockCells {
  alignas(64) int32_t cell[3][kBlock];
  alignas(64) float frac[3][kBlock];
  alignas(64) uint32_t idx[8][kBlock];
  alignas(64) float w[8][kBlock];
};

void locate_block(const BlockPoints& points, int64_t m, int32_t res, bool dense, uint32_t mask, BlockCells& out) {
  const float scale = static_cast<float>(res), top = static_cast<float>(res - 1);
  for (int k = 0; k < 3; ++k) {
    const float* p = points.xyz[k];
    int32_t* cell = out.cell[k];
    float* frac = out.frac[k];
    for (int64_t s = 0; s < m; ++s) {
      const float x = std::min(std::max(p[s], 0.0f), 1.0f) * scale;
      const float fl = std::min(std::floor(x), top);
      cell[s] = static_cast<int32_t>(fl);
      frac[s] = x - fl;
    }
  }
  const uint32_t r1 = static_cast<uint32_t>(res) + 1u;
  const uint32_t sy = dense ? r1 : 2654435761u, sz = dense ? r1 * r1 : 805459861u;
  for (int c = 0; c < 8; ++c) {
    const uint32_t a = (c >> 2) & 1u, b = (c >> 1) & 1u, e = c & 1u;  // corner c = (a, b, e): x outer, z inner
    const int32_t *cx = out.cell[0], *cy = out.cell[1], *cz = out.cell[2];
    const float *fx = out.frac[0], *fy = out.frac[1], *fz = out.frac[2];
    uint32_t* idx = out.idx[c];
    float* w = out.w[c];
    if (dense) {
      for (int64_t s = 0; s < m; ++s)
        idx[s] = (static_cast<uint32_t>(cx[s]) + a) + (static_cast<uint32_t>(cy[s]) + b) * sy +
                 (static_cast<uint32_t>(cz[s]) + e) * sz;
    } else {
      for (int64_t s = 0; s < m; ++s)
        idx[s] = ((static_cast<uint32_t>(cx[s]) + a) ^ ((static_cast<uint32_t>(cy[s]) + b) * sy) ^
                  ((static_cast<uint32_t>(cz[s]) + e) * sz)) & mask;
    }
    for (int64_t s = 0; s < m; ++s) {
      const float wx = a ? fx[s] : 1.0f - fx[s], wy = b ? fy[s] : 1.0f - fy[s], wz = e ? fz[s] : 1.0f - fz[s];
      w[s] = wx * wy * wz;
    }
  }
}

template <int FS>
void forward_kernel(const float* u, const float* table, float* out, int64_t n, const Levels& lv, int64_t n_dense,
                    uint32_t mask, int64_t f_dyn, int64_t ahead) {
  const int64_t F = FS > 0 ? FS : f_dyn;
  const int64_t L = static_cast<int64_t>(lv.res.size());
  at::parallel_for(0, n, kBlock, [&](int64_t begin, int64_t end) {
    auto points = std::make_unique<BlockPoints>();
    auto cells = std::make_unique<BlockCells>();
    for (int64_t b0 = begin; b0 < end; b0 += kBlock) {
      const int64_t m = std::min(end, b0 + kBlock) - b0;
      block_points(u + 3 * b0, m, *points);
      for (int64_t l = 0; l < L; ++l) {
        locate_block(*points, m, lv.res[l], l < n_dense, mask, *cells);
        const float* base = table + lv.offset[l] * F;
        for (int64_t s = 0; s < std::min(m, ahead); ++s) prefetch_corners<0>(base, cells->idx, s, F, 0);
        for (int64_t s = 0; s < m; ++s) {
          if (ahead > 0 && s + ahead < m) prefetch_corners<0>(base, cells->idx, s + ahead, F, 0);
          float* o = out + (b0 + s) * L * F + l * F;
          for (int64_t f = 0; f < F; ++f) {  // accumulated in a register: out may alias table
            float acc = 0.0f;
            for (int c = 0; c < 8; ++c) acc += cells->w[c][s] * base[static_cast<int64_t>(cells->idx[c][s]) * F + f];
            o[f] = acc;
          }
        }
      }
    }
  });
}

torch::Tensor forward(torch::Tensor u, torch::Tensor table, torch::Tensor levels, torch::Tensor offsets,
                      int64_t n_dense, int64_t hash_mask, int64_t ahead) {
  TORCH_CHECK(u.device().is_cpu() && table.device().is_cpu(), "hashgrid kernel: CPU tensors only");
  TORCH_CHECK(u.scalar_type() == at::kFloat && table.scalar_type() == at::kFloat, "hashgrid kernel: float32 only");
  u = u.contiguous();
  table = table.contiguous();
  const Levels lv = read_levels(levels, offsets);
  const int64_t n = u.size(0), L = static_cast<int64_t>(lv.res.size()), F = table.size(1);
  auto out = torch::empty({n, L * F}, u.options());
  const uint32_t mask = static_cast<uint32_t>(hash_mask);
  if (F == 2)
    forward_kernel<2>(u.data_ptr<float>(), table.data_ptr<float>(), out.data_ptr<float>(), n, lv, n_dense, mask, F, ahead);
  else
    forward_kernel<0>(u.data_ptr<float>(), table.data_ptr<float>(), out.data_ptr<float>(), n, lv, n_dense, mask, F, ahead);
  return out;
}

torch::Tensor backward(torch::Tensor grad_out, torch::Tensor u, int64_t rows, torch::Tensor levels,
                       torch::Tensor offsets, int64_t n_dense, int64_t hash_mask, int64_t ahead) {
  grad_out = grad_out.contiguous();
  u = u.contiguous();
  const Levels lv = read_levels(levels, offsets);
  const int64_t n = u.size(0), L = static_cast<int64_t>(lv.res.size());
  const int64_t F = grad_out.size(1) / L;
  auto grad_table = torch::zeros({rows, F}, grad_out.options());
  const int64_t chunk = std::min<int64_t>(F, 16);  // 16 floats = one cache line: no false sharing
  const int64_t n_chunks = (F + chunk - 1) / chunk;
  const float* up = u.data_ptr<float>();
  const float* gp = grad_out.data_ptr<float>();
  float* tp = grad_table.data_ptr<float>();
  const uint32_t mask = static_cast<uint32_t>(hash_mask);
  // One task per (level, feature slice); tasks are dealt round-robin so that coarse (cache-friendly)
  // and fine levels spread evenly over the threads. Samples are visited in blocks so that a block's
  // rows of grad_out stay in cache while every task of the thread reads them.
  const int64_t n_tasks = L * n_chunks;
  const int64_t n_threads = std::min<int64_t>(at::get_num_threads(), n_tasks);
  at::parallel_for(0, n_threads, 1, [&](int64_t begin, int64_t end) {
    auto points = std::make_unique<BlockPoints>();
    auto cells = std::make_unique<BlockCells>();
    for (int64_t worker = begin; worker < end; ++worker) {
      for (int64_t b0 = 0; b0 < n; b0 += kBlock) {
        const int64_t m = std::min(n, b0 + kBlock) - b0;
        block_points(up + 3 * b0, m, *points);
        for (int64_t task = worker; task < n_tasks; task += n_threads) {
          const int64_t l = task / n_chunks;
          const int64_t f0 = (task % n_chunks) * chunk, f1 = std::min(F, f0 + chunk);
          float* base = tp + lv.offset[l] * F;
          locate_block(*points, m, lv.res[l], l < n_dense, mask, *cells);
          for (int64_t s = 0; s < std::min(m, ahead); ++s) prefetch_corners<1>(base, cells->idx, s, F, f0);
          for (int64_t s = 0; s < m; ++s) {
            if (ahead > 0 && s + ahead < m) prefetch_corners<1>(base, cells->idx, s + ahead, F, f0);
            const float* g = gp + (b0 + s) * L * F + l * F;
            for (int c = 0; c < 8; ++c) {
              float* t = base + static_cast<int64_t>(cells->idx[c][s]) * F;
              const float w = cells->w[c][s];
              for (int64_t f = f0; f < f1; ++f) t[f] += w * g[f];
            }
          }
        }
      }
    }
  });
  return grad_table;
}

// grad_u[n, k] = sum_l sum_c <grad_out[n, l], table[idx_c]> * dw_c/du_k, with dw_c/du_k = N_l * (+-1) *
// (the other two axes' weights); zero where u_k was clamped (u_k outside (0,1)), as torch's clamp.
torch::Tensor backward_input(torch::Tensor grad_out, torch::Tensor u, torch::Tensor table, torch::Tensor levels,
                             torch::Tensor offsets, int64_t n_dense, int64_t hash_mask, int64_t ahead) {
  grad_out = grad_out.contiguous();
  u = u.contiguous();
  table = table.contiguous();
  const Levels lv = read_levels(levels, offsets);
  const int64_t n = u.size(0), L = static_cast<int64_t>(lv.res.size()), F = table.size(1);
  auto grad_u = torch::empty({n, 3}, u.options());
  const float* up = u.data_ptr<float>();
  const float* gp = grad_out.data_ptr<float>();
  const float* tp = table.data_ptr<float>();
  float* gu = grad_u.data_ptr<float>();
  const uint32_t mask = static_cast<uint32_t>(hash_mask);
  at::parallel_for(0, n, kBlock, [&](int64_t begin, int64_t end) {
    auto points = std::make_unique<BlockPoints>();
    auto cells = std::make_unique<BlockCells>();
    for (int64_t b0 = begin; b0 < end; b0 += kBlock) {
      const int64_t m = std::min(end, b0 + kBlock) - b0;
      block_points(up + 3 * b0, m, *points);
      float acc[kBlock][3] = {};
      for (int64_t l = 0; l < L; ++l) {
        locate_block(*points, m, lv.res[l], l < n_dense, mask, *cells);
        const float* base = tp + lv.offset[l] * F;
        const float res = static_cast<float>(lv.res[l]);
        for (int64_t s = 0; s < std::min(m, ahead); ++s) prefetch_corners<0>(base, cells->idx, s, F, 0);
        for (int64_t s = 0; s < m; ++s) {
          if (ahead > 0 && s + ahead < m) prefetch_corners<0>(base, cells->idx, s + ahead, F, 0);
          const float* g = gp + (b0 + s) * L * F + l * F;
          const float w[3][2] = {{1.0f - cells->frac[0][s], cells->frac[0][s]},
                                 {1.0f - cells->frac[1][s], cells->frac[1][s]},
                                 {1.0f - cells->frac[2][s], cells->frac[2][s]}};
          int c = 0;
          for (int a = 0; a < 2; ++a)
            for (int b = 0; b < 2; ++b)
              for (int e = 0; e < 2; ++e, ++c) {
                const float* t = base + static_cast<int64_t>(cells->idx[c][s]) * F;
                float dot = 0.0f;
                for (int64_t f = 0; f < F; ++f) dot += g[f] * t[f];
                dot *= res;
                acc[s][0] += dot * (a ? 1.0f : -1.0f) * w[1][b] * w[2][e];
                acc[s][1] += dot * w[0][a] * (b ? 1.0f : -1.0f) * w[2][e];
                acc[s][2] += dot * w[0][a] * w[1][b] * (e ? 1.0f : -1.0f);
              }
        }
      }
      for (int64_t s = 0; s < m; ++s)
        for (int k = 0; k < 3; ++k) {
          const float p = points->xyz[k][s];
          gu[3 * (b0 + s) + k] = (p > 0.0f && p < 1.0f) ? acc[s][k] : 0.0f;
        }
    }
  });
  return grad_u;
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("forward", &forward, "hash-grid gather + trilinear interpolation");
  m.def("backward", &backward, "hash-grid table gradient (scatter-add)");
  m.def("backward_input", &backward_input, "hash-grid gradient with respect to the points");
}
