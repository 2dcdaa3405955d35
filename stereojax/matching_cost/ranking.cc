// Native top-K candidate ranking: the kernel of learned.py's rank (lax.top_k of the negated
// cost), held exactly equal to it by tests/matching_cost/test_ranking_native.py.
//
// For every pixel the K2 entries of lowest cost, best first; among equal costs the lower index
// first (as top_k keeps the order of equal values); plus the pixel's band offset (0 for the full
// range). An insertion into a sorted list of K2, one pixel at a time, rows on all threads.
#include <algorithm>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

SJ_CLONES void rank_rows(const float* cost, const int32_t* off, int32_t* out, int w, int k, int k2, bool banded,
                         int y0, int y1) {
  std::vector<float> val(k2);
  std::vector<int32_t> idx(k2);
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t p = static_cast<size_t>(y) * w + x;
      const float* c = cost + p * k;
      int n = 0;
      for (int j = 0; j < k; ++j) {
        const float v = c[j];
        if (n == k2 && !(v < val[k2 - 1])) continue;  // not better than the worst kept
        int i = n < k2 ? n++ : k2 - 1;
        while (i > 0 && v < val[i - 1]) {  // strictly better moves up: ties keep index order
          val[i] = val[i - 1];
          idx[i] = idx[i - 1];
          --i;
        }
        val[i] = v;
        idx[i] = j;
      }
      const int32_t base = banded ? off[p] : 0;
      int32_t* o = out + p * k2;
      for (int i = 0; i < k2; ++i) o[i] = idx[i] + base;
    }
  }
}

ffi::Error RankImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::ResultBuffer<ffi::S32> out,
                    int32_t banded, int32_t threads) {
  int h, w, k, ho, wo, k2;
  dims3(cost, h, w, k);
  dims3(*out, ho, wo, k2);
  if (k2 > k || k2 < 1) return ffi::Error::InvalidArgument("rank: need 1 <= K2 <= K");
  const float* c = cost.typed_data();
  const int32_t* off = offset.typed_data();
  int32_t* dst = out->typed_data();
  parallel_for(h, threads, [&](int y0, int y1) { rank_rows(c, off, dst, w, k, k2, banded != 0, y0, y1); });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxRank);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxRank, stereojax::RankImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // cost [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W]
                                  .Ret<xla::ffi::Buffer<xla::ffi::S32>>()  // ranked disparities [H, W, K2]
                                  .Attr<int32_t>("banded")
                                  .Attr<int32_t>("threads"));
