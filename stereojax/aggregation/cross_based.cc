// Native CBCA: the kernel of cross_based.py (cbca / cbca_volume), band and full range. Held
// equal to the JAX kernel by tests/aggregation/test_cross_based_native.py.
//
// One pass: a horizontal sum over each pixel's left..right arm, then a vertical sum of those
// over its up..down arm, times 1 / (the pixels of the support region). A neighbour q is read at
// the same absolute disparity as p (entry j + off(p) - off(q) of its band); where that lies
// outside q's band, q counts with p's own value (horizontal: p's cost; vertical: p's horizontal
// mean times q's horizontal arm count). The full range is off = 0, where no entry is outside.
// The terms are added in the order of the JAX kernel (arm offsets ascending), so the two agree
// to the last bit. Rows run on all threads; each thread keeps the horizontal sums that its
// vertical sums read in a ring of 2 arm + 1 rows of a block of columns (no volume-sized scratch).
#include <algorithm>
#include <cstring>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

struct Arms {
  const int32_t *left, *right, *up, *down;
};

// acc[j] (+)= v[j + sh] where 0 <= j + sh < k, else nu[j] (times wq when WEIGHTED). FIRST sets
// acc to the term instead of adding it: the same float as 0 + term, without a pass that zeroes
// acc (a K-float memset per pixel measured 14 % of the kernel).
template <bool FIRST, bool WEIGHTED>
SJ_INLINE void add_band(float* __restrict acc, const float* __restrict v, const float* __restrict nu, float wq, int k,
                        int sh) {
  auto put = [acc](int j, float t) {
    if (FIRST)
      acc[j] = t;
    else
      acc[j] += t;
  };
  if (sh == 0) {
    for (int j = 0; j < k; ++j) put(j, v[j]);
    return;
  }
  const int lo = std::min(k, std::max(0, -sh)), hi = std::max(lo, std::min(k, k - sh));
  for (int j = 0; j < lo; ++j) put(j, WEIGHTED ? nu[j] * wq : nu[j]);
  const float* __restrict vs = v + sh;
  for (int j = lo; j < hi; ++j) put(j, vs[j]);
  for (int j = hi; j < k; ++j) put(j, WEIGHTED ? nu[j] * wq : nu[j]);
}

struct Pass {
  const float* src;
  float* dst;
  const int32_t* off;
  Arms a;
  int h, w, k, reach;  // reach: the longest vertical arm
  bool banded;
};

// The horizontal sums of row y, columns [xb, xe), into hrow [xe - xb, K].
template <int KC>
SJ_INLINE void horizontal_row(const Pass& ps, int y, int xb, int xe, float* __restrict hrow) {
  const int w = ps.w, k = KC > 0 ? KC : ps.k;
  for (int x = xb; x < xe; ++x) {
    const size_t p = static_cast<size_t>(y) * w + x;
    const float* nu = ps.src + p * k;
    float* __restrict acc = hrow + static_cast<size_t>(x - xb) * k;
    const int op = ps.off[p];
    // the arms of padding pixels (grey BIG) may run past the image: read inside it only
    const int q0 = std::max(0, x - ps.a.left[p]), q1 = std::min(w - 1, x + ps.a.right[p]);
    for (int q = q0; q <= q1; ++q) {  // q0 <= x <= q1: at least one term
      const size_t pq = static_cast<size_t>(y) * w + q;
      const int sh = ps.banded ? op - ps.off[pq] : 0;
      if (q == q0)
        add_band<true, false>(acc, ps.src + pq * k, nu, 1.f, k, sh);
      else
        add_band<false, false>(acc, ps.src + pq * k, nu, 1.f, k, sh);
    }
  }
}

// Rows [y0, y1), in blocks of columns: for each block, the horizontal sums of rows
// y0 - reach .. y1 + reach go through a ring of 2 reach + 1 rows of the block (small enough to
// stay in the core's L2 cache), and the vertical sums of each row read them there.
template <int KC>
SJ_INLINE void cbca_rows_k(const Pass& ps, int y0, int y1) {
  const int w = ps.w, k = KC > 0 ? KC : ps.k, span = 2 * ps.reach + 1;
  const int block = std::max(8, std::min(w, static_cast<int>((192 * 1024) / (sizeof(float) * span * k))));
  const size_t blk_len = static_cast<size_t>(block) * k;
  std::vector<float> ring(blk_len * span);
  std::vector<float> acc(k), nrm(k);
  auto slot = [&](int row) { return ring.data() + static_cast<size_t>(row % span) * blk_len; };
  for (int xb = 0; xb < w; xb += block) {
    const int xe = std::min(w, xb + block);
    int next = std::max(0, y0 - ps.reach);  // the next row whose horizontal sums are due
    for (int y = y0; y < y1; ++y) {
      const int need = std::min(ps.h, y + ps.reach + 1);
      for (; next < need; ++next) horizontal_row<KC>(ps, next, xb, xe, slot(next));
      for (int x = xb; x < xe; ++x) {
        const size_t p = static_cast<size_t>(y) * w + x;
        const size_t xi = static_cast<size_t>(x - xb) * k;
        const float* hp = slot(y) + xi;
        const float hl = static_cast<float>(ps.a.left[p] + ps.a.right[p] + 1);
        const float inv_hl = 1.0f / hl;  // as XLA compiles hs / h_len: times the reciprocal
        const int op = ps.off[p];
        float support = 0.f;
        const int q0 = std::max(0, y - ps.a.up[p]), q1 = std::min(ps.h - 1, y + ps.a.down[p]);
        bool any_shift = false;  // the neutral term is needed only where a band shifts
        for (int q = q0; q <= q1 && ps.banded; ++q) any_shift |= ps.off[static_cast<size_t>(q) * w + x] != op;
        if (any_shift)
          for (int j = 0; j < k; ++j) nrm[j] = hp[j] * inv_hl;
        for (int q = q0; q <= q1; ++q) {  // q0 <= y <= q1: at least one term
          const size_t pq = static_cast<size_t>(q) * w + x;
          const float wq = static_cast<float>(ps.a.left[pq] + ps.a.right[pq] + 1);
          support += wq;
          const int sh = ps.banded ? op - ps.off[pq] : 0;
          if (q == q0)
            add_band<true, true>(acc.data(), slot(q) + xi, nrm.data(), wq, k, sh);
          else
            add_band<false, true>(acc.data(), slot(q) + xi, nrm.data(), wq, k, sh);
        }
        const float norm = 1.0f / support;
        float* o = ps.dst + p * k;
        for (int j = 0; j < k; ++j) o[j] = acc[j] * norm;
      }
    }
  }
}

// The band width of the shipped chains (48) compiled as a constant: the inner loops then have a
// fixed trip count and no remainder, which measured about 2x faster; any other K at run time.
SJ_CLONES void cbca_rows(const Pass& ps, int y0, int y1) {
  if (ps.k == 48)
    cbca_rows_k<48>(ps, y0, y1);
  else
    cbca_rows_k<0>(ps, y0, y1);
}

ffi::Error CbcaImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::Buffer<ffi::S32> left,
                    ffi::Buffer<ffi::S32> right, ffi::Buffer<ffi::S32> up, ffi::Buffer<ffi::S32> down,
                    ffi::ResultBuffer<ffi::F32> out, int32_t iterations, int32_t banded, int32_t threads) {
  int h, w, k;
  dims3(cost, h, w, k);
  if (cost.dimensions().size() != 3) return ffi::Error::InvalidArgument("cbca: cost must be [H, W, K]");
  Arms a{left.typed_data(), right.typed_data(), up.typed_data(), down.typed_data()};
  float* dst = out->typed_data();
  const size_t n = static_cast<size_t>(h) * w * k;
  if (iterations <= 0) {
    std::memcpy(dst, cost.typed_data(), n * sizeof(float));
    return ffi::Error::Success();
  }
  int reach = 0;
  for (size_t i = 0; i < static_cast<size_t>(h) * w; ++i) reach = std::max({reach, a.up[i], a.down[i]});
  reach = std::min(reach, h);
  // a pass reads its whole input while it writes: from the second pass on, the input is the
  // previous pass's output, kept in a volume of its own
  std::vector<float> prev(iterations > 1 ? n : 0);
  const float* src = cost.typed_data();
  for (int it = 0; it < iterations; ++it) {
    if (it > 0) {
      std::memcpy(prev.data(), dst, n * sizeof(float));
      src = prev.data();
    }
    Pass ps{src, dst, offset.typed_data(), a, h, w, k, reach, banded != 0};
    parallel_for(h, threads, [&](int y0, int y1) { cbca_rows(ps, y0, y1); });
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
