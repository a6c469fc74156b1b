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
// and a 16-float slice of the features, i.e. disjoint table entries.
#include <torch/extension.h>
#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

struct Cell {
  uint32_t idx[8];
  float w[8];
  float frac[3];  // position inside the cell, per axis
};

inline void locate(const float* p, int32_t res, bool dense, uint32_t mask, Cell& cell) {
  uint32_t i[3];
  float f[3];
  for (int k = 0; k < 3; ++k) {
    const float x = std::min(std::max(p[k], 0.0f), 1.0f) * static_cast<float>(res);
    const float fl = std::min(std::floor(x), static_cast<float>(res - 1));
    i[k] = static_cast<uint32_t>(fl);
    f[k] = x - fl;
    cell.frac[k] = f[k];
  }
  const float wx[2] = {1.0f - f[0], f[0]}, wy[2] = {1.0f - f[1], f[1]}, wz[2] = {1.0f - f[2], f[2]};
  uint32_t tx[2], ty[2], tz[2];
  if (dense) {
    const uint32_t r1 = static_cast<uint32_t>(res) + 1u;
    for (int d = 0; d < 2; ++d) {
      tx[d] = i[0] + d;
      ty[d] = (i[1] + d) * r1;
      tz[d] = (i[2] + d) * r1 * r1;
    }
  } else {
    for (int d = 0; d < 2; ++d) {
      tx[d] = i[0] + d;
      ty[d] = (i[1] + d) * 2654435761u;
      tz[d] = (i[2] + d) * 805459861u;
    }
  }
  int c = 0;
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b)
      for (int e = 0; e < 2; ++e, ++c) {
        cell.idx[c] = dense ? tx[a] + ty[b] + tz[e] : ((tx[a] ^ ty[b] ^ tz[e]) & mask);
        cell.w[c] = wx[a] * wy[b] * wz[e];
      }
}

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
// (3x faster than sample-outer on ray-coherent samples).
constexpr int64_t kBlock = 1024;

template <int FS>
void forward_kernel(const float* u, const float* table, float* out, int64_t n, const Levels& lv, int64_t n_dense,
                    uint32_t mask, int64_t f_dyn) {
  const int64_t F = FS > 0 ? FS : f_dyn;
  const int64_t L = static_cast<int64_t>(lv.res.size());
  at::parallel_for(0, n, kBlock, [&](int64_t begin, int64_t end) {
    Cell cell;
    for (int64_t b0 = begin; b0 < end; b0 += kBlock) {
      const int64_t b1 = std::min(end, b0 + kBlock);
      for (int64_t l = 0; l < L; ++l) {
        const float* base = table + lv.offset[l] * F;
        for (int64_t s = b0; s < b1; ++s) {
          locate(u + 3 * s, lv.res[l], l < n_dense, mask, cell);
          float* o = out + s * L * F + l * F;
          for (int64_t f = 0; f < F; ++f) o[f] = 0.0f;
          for (int c = 0; c < 8; ++c) {
            const float* t = base + static_cast<int64_t>(cell.idx[c]) * F;
            const float w = cell.w[c];
            for (int64_t f = 0; f < F; ++f) o[f] += w * t[f];
          }
        }
      }
    }
  });
}

torch::Tensor forward(torch::Tensor u, torch::Tensor table, torch::Tensor levels, torch::Tensor offsets,
                      int64_t n_dense, int64_t hash_mask) {
  TORCH_CHECK(u.device().is_cpu() && table.device().is_cpu(), "hashgrid kernel: CPU tensors only");
  TORCH_CHECK(u.scalar_type() == at::kFloat && table.scalar_type() == at::kFloat, "hashgrid kernel: float32 only");
  u = u.contiguous();
  table = table.contiguous();
  const Levels lv = read_levels(levels, offsets);
  const int64_t n = u.size(0), L = static_cast<int64_t>(lv.res.size()), F = table.size(1);
  auto out = torch::empty({n, L * F}, u.options());
  const uint32_t mask = static_cast<uint32_t>(hash_mask);
  if (F == 2)
    forward_kernel<2>(u.data_ptr<float>(), table.data_ptr<float>(), out.data_ptr<float>(), n, lv, n_dense, mask, F);
  else
    forward_kernel<0>(u.data_ptr<float>(), table.data_ptr<float>(), out.data_ptr<float>(), n, lv, n_dense, mask, F);
  return out;
}

torch::Tensor backward(torch::Tensor grad_out, torch::Tensor u, int64_t rows, torch::Tensor levels,
                       torch::Tensor offsets, int64_t n_dense, int64_t hash_mask) {
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
    Cell cell;
    for (int64_t worker = begin; worker < end; ++worker) {
      for (int64_t b0 = 0; b0 < n; b0 += kBlock) {
        const int64_t b1 = std::min(n, b0 + kBlock);
        for (int64_t task = worker; task < n_tasks; task += n_threads) {
          const int64_t l = task / n_chunks;
          const int64_t f0 = (task % n_chunks) * chunk, f1 = std::min(F, f0 + chunk);
          float* base = tp + lv.offset[l] * F;
          for (int64_t s = b0; s < b1; ++s) {
            locate(up + 3 * s, lv.res[l], l < n_dense, mask, cell);
            const float* g = gp + s * L * F + l * F;
            for (int c = 0; c < 8; ++c) {
              float* t = base + static_cast<int64_t>(cell.idx[c]) * F;
              const float w = cell.w[c];
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
                             torch::Tensor offsets, int64_t n_dense, int64_t hash_mask) {
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
    Cell cell;
    for (int64_t s = begin; s < end; ++s) {
      const float* p = up + 3 * s;
      float acc[3] = {0.0f, 0.0f, 0.0f};
      for (int64_t l = 0; l < L; ++l) {
        locate(p, lv.res[l], l < n_dense, mask, cell);
        const float* base = tp + lv.offset[l] * F;
        const float* g = gp + s * L * F + l * F;
        const float res = static_cast<float>(lv.res[l]);
        const float w[3][2] = {{1.0f - cell.frac[0], cell.frac[0]},
                               {1.0f - cell.frac[1], cell.frac[1]},
                               {1.0f - cell.frac[2], cell.frac[2]}};
        int c = 0;
        for (int a = 0; a < 2; ++a)
          for (int b = 0; b < 2; ++b)
            for (int e = 0; e < 2; ++e, ++c) {
              const float* t = base + static_cast<int64_t>(cell.idx[c]) * F;
              float dot = 0.0f;
              for (int64_t f = 0; f < F; ++f) dot += g[f] * t[f];
              dot *= res;
              acc[0] += dot * (a ? 1.0f : -1.0f) * w[1][b] * w[2][e];
              acc[1] += dot * w[0][a] * (b ? 1.0f : -1.0f) * w[2][e];
              acc[2] += dot * w[0][a] * w[1][b] * (e ? 1.0f : -1.0f);
            }
      }
      for (int k = 0; k < 3; ++k) gu[3 * s + k] = (p[k] > 0.0f && p[k] < 1.0f) ? acc[k] : 0.0f;
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
