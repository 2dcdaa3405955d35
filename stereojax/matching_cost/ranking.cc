// Native top-K candidate ranking: the kernel of learned.py's rank (lax.top_k of the negated
// cost), held exactly equal to it by tests/matching_cost/test_ranking_native.py.
//
// For every pixel the K2 entries of lowest cost, best first; among equal costs the lower index
// first (as top_k keeps the order of equal values); plus the pixel's band offset (0 for the full
// range). Each entry's place is counted, not searched for: place(j) = #{i : c_i < c_j} +
// #{i < j : c_i == c_j}, a branch-free loop over the pixel's K entries that the compiler
// vectorises, among the entries that can rank at all (rank_pixel); the entries of place < K2
// are written there (K <= 64, the bands). Over a wider
// range (K^2 comparisons would cost more than they save) an insertion into a sorted list of K2.
// Rows on all threads.
#include <algorithm>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

template <int KC>
SJ_INLINE void rank_pixel(const float* __restrict c, int32_t* __restrict o, int kk, int k2, int32_t base) {
  constexpr int kMax = 64;
  const int k = KC > 0 ? KC : kk;
  // a bound u with at least K2 entries <= u: cut the entries into K2 strided groups, u = the
  // largest of the groups' minima; only the entries <= u can rank among the first K2, and they
  // rank among themselves as among all (every other entry is larger)
  float gmin[kMax];
  for (int g = 0; g < k2; ++g) gmin[g] = c[g];
  for (int i = k2; i < k; i += k2) {
    const int n = std::min(k2, k - i);
    for (int g = 0; g < n; ++g) gmin[g] = c[i + g] < gmin[g] ? c[i + g] : gmin[g];
  }
  float u = gmin[0];
  for (int g = 1; g < k2; ++g) u = gmin[g] > u ? gmin[g] : u;
  float val[kMax];
  int32_t idx[kMax], place[kMax];
  int n = 0;
  for (int j = 0; j < k; ++j) {  // branch-free compaction, index order kept
    val[n] = c[j];
    idx[n] = j;
    n += c[j] <= u;
  }
  for (int j = 0; j < n; ++j) place[j] = 0;
  // one entry i against all j at once (the loop over j is the vector loop); idx ascends, so the
  // position in the list orders ties as the index does
  for (int i = 0; i < n; ++i) {
    const float vi = val[i];
    for (int j = 0; j < n; ++j) place[j] += (vi < val[j]) | ((vi == val[j]) & (i < j));
  }
  for (int j = 0; j < n; ++j)
    if (place[j] < k2) o[place[j]] = idx[j] + base;
}

// Insertion into a sorted list of K2 (the wide ranges): the same order, ties included.
SJ_INLINE void rank_insert(const float* __restrict c, int32_t* __restrict o, int k, int k2, int32_t base,
                           float* val, int32_t* idx) {
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
  for (int i = 0; i < k2; ++i) o[i] = idx[i] + base;
}

SJ_CLONES void rank_rows(const float* cost, const int32_t* off, int32_t* out, int w, int k, int k2, bool banded,
                         int y0, int y1) {
  std::vector<float> val(k2);
  std::vector<int32_t> idx(k2);
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t p = static_cast<size_t>(y) * w + x;
      const int32_t base = banded ? off[p] : 0;
      if (k == 48)
        rank_pixel<48>(cost + p * k, out + p * k2, k, k2, base);
      else if (k <= 64)
        rank_pixel<0>(cost + p * k, out + p * k2, k, k2, base);
      else
        rank_insert(cost + p * k, out + p * k2, k, k2, base, val.data(), idx.data());
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
