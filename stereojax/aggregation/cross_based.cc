// Native CBCA: the kernel of cross_based.py (cbca / cbca_volume), band and full range. Held
// equal to the JAX kernel by tests/aggregation/test_cross_based_native.py.
//
// One pass: a horizontal sum over each pixel's left..right arm, then a vertical sum of those
// over its up..down arm, times 1 / (the pixels of the support region). A neighbour q is read at
// the same absolute disparity as p (entry j + off(p) - off(q) of its band); where that lies
// outside q's band, q counts with p's own value (horizontal: p's cost; vertical: p's horizontal
// mean times q's horizontal arm count). The full range is off = 0, where no entry is outside.
// The terms are added in the order of the JAX kernel (arm offsets ascending), so the two agree
// to the last bit. Both sums run over rows on all threads; the horizontal sums go to one scratch
// volume allocated once per call.
#include <algorithm>
#include <cstring>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

struct Arms {
  const int32_t *left, *right, *up, *down;
};

SJ_INLINE void add_band(float* __restrict acc, const float* __restrict v, const float* __restrict nu, int k,
                        int sh) {
  // acc[j] += v[j + sh] where 0 <= j + sh < k, else nu[j]
  const int lo = std::min(k, std::max(0, -sh)), hi = std::max(lo, std::min(k, k - sh));
  for (int j = 0; j < lo; ++j) acc[j] += nu[j];
  const float* __restrict vs = v + sh;
  for (int j = lo; j < hi; ++j) acc[j] += vs[j];
  for (int j = hi; j < k; ++j) acc[j] += nu[j];
}

SJ_INLINE void add_band_weighted(float* __restrict acc, const float* __restrict v, const float* __restrict nu,
                                 float wq, int k, int sh) {
  const int lo = std::min(k, std::max(0, -sh)), hi = std::max(lo, std::min(k, k - sh));
  for (int j = 0; j < lo; ++j) acc[j] += nu[j] * wq;
  const float* __restrict vs = v + sh;
  for (int j = lo; j < hi; ++j) acc[j] += vs[j];
  for (int j = hi; j < k; ++j) acc[j] += nu[j] * wq;
}

SJ_CLONES void horizontal_rows(const float* src, float* dst, const int32_t* off, Arms a, int w, int k, bool banded,
                               int y0, int y1) {
  std::vector<float> acc(k);
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t p = static_cast<size_t>(y) * w + x;
      const float* nu = src + p * k;
      std::fill(acc.begin(), acc.end(), 0.f);
      const int op = off[p];
      for (int q = x - a.left[p]; q <= x + a.right[p]; ++q) {
        const size_t pq = static_cast<size_t>(y) * w + q;
        const int sh = banded ? op - off[pq] : 0;
        add_band(acc.data(), src + pq * k, nu, k, sh);
      }
      std::memcpy(dst + p * k, acc.data(), k * sizeof(float));
    }
  }
}

SJ_CLONES void vertical_rows(const float* hs, float* dst, const int32_t* off, Arms a, int w, int k, bool banded,
                             int y0, int y1) {
  std::vector<float> acc(k), nrm(k);
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t p = static_cast<size_t>(y) * w + x;
      const float* hp = hs + p * k;
      const float hl = static_cast<float>(a.left[p] + a.right[p] + 1);
      for (int j = 0; j < k; ++j) nrm[j] = hp[j] / hl;
      std::fill(acc.begin(), acc.end(), 0.f);
      const int op = off[p];
      float support = 0.f;
      for (int q = y - a.up[p]; q <= y + a.down[p]; ++q) {
        const size_t pq = static_cast<size_t>(q) * w + x;
        const float wq = static_cast<float>(a.left[pq] + a.right[pq] + 1);
        support += wq;
        const int sh = banded ? op - off[pq] : 0;
        add_band_weighted(acc.data(), hs + pq * k, nrm.data(), wq, k, sh);
      }
      const float norm = 1.0f / support;
      float* o = dst + p * k;
      for (int j = 0; j < k; ++j) o[j] = acc[j] * norm;
    }
  }
}

ffi::Error CbcaImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::Buffer<ffi::S32> left,
                    ffi::Buffer<ffi::S32> right, ffi::Buffer<ffi::S32> up, ffi::Buffer<ffi::S32> down,
                    ffi::ResultBuffer<ffi::F32> out, int32_t iterations, int32_t banded, int32_t threads) {
  int h, w, k;
  dims3(cost, h, w, k);
  if (cost.dimensions().size() != 3) return ffi::Error::InvalidArgument("cbca: cost must be [H, W, K]");
  Arms a{left.typed_data(), right.typed_data(), up.typed_data(), down.typed_data()};
  const int32_t* off = offset.typed_data();
  float* dst = out->typed_data();
  const size_t n = static_cast<size_t>(h) * w * k;
  if (iterations <= 0) {
    std::memcpy(dst, cost.typed_data(), n * sizeof(float));
    return ffi::Error::Success();
  }
  std::vector<float> hs(n);
  const float* src = cost.typed_data();
  for (int it = 0; it < iterations; ++it) {
    parallel_for(h, threads, [&](int y0, int y1) { horizontal_rows(src, hs.data(), off, a, w, k, banded != 0, y0, y1); });
    parallel_for(h, threads, [&](int y0, int y1) { vertical_rows(hs.data(), dst, off, a, w, k, banded != 0, y0, y1); });
    src = dst;
  }
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxCbca);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxCbca, stereojax::CbcaImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // cost [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // arm left [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // arm right
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // arm up
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // arm down
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()
                                  .Attr<int32_t>("iterations")
                                  .Attr<int32_t>("banded")
                                  .Attr<int32_t>("threads"));
