// Native census matching cost: the kernel of classical.py (census_cost / census_band) after
// the census transform, band and full range. Held exactly equal to the JAX kernel by
// tests/matching_cost/test_classical_native.py.
//
// cost(y, x, k) = popcount(CL(y, x) ^ CR(y, max(x - off - k, 0))) * scale for the band
// [off, off + K) (the full range: off = 0, K = D); right columns left of the image repeat
// column 0, as the JAX kernel does; border "worst": INVALID_COST (1) where x - off - k < 0.
#include <algorithm>
#include <cstring>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

// NW census words per pixel; NW = 2 (the 7x9 window's 62 bits) reads them as one 64-bit word
template <int NW>
SJ_INLINE int hamming(const uint32_t* a, const uint32_t* b, int nw) {
  if (NW == 2) {
    uint64_t u, v;
    std::memcpy(&u, a, 8);
    std::memcpy(&v, b, 8);
    return __builtin_popcountll(u ^ v);
  }
  int bits = 0;
  for (int t = 0; t < (NW > 0 ? NW : nw); ++t) bits += __builtin_popcount(a[t] ^ b[t]);
  return bits;
}

template <int NW>
SJ_INLINE void census_row(const uint32_t* cl, const uint32_t* rrow, const int32_t* off, float* out, int w, int k,
                          int nw, bool worst, float scale) {
  for (int x = 0; x < w; ++x) {
    const uint32_t* a = cl + static_cast<size_t>(x) * nw;
    float* o = out + static_cast<size_t>(x) * k;
    const int base = x - off[x];
    const int inside = std::min(k, base + 1);  // entries j < inside have their match in the image
    for (int j = 0; j < inside; ++j)
      o[j] = static_cast<float>(hamming<NW>(a, rrow + static_cast<size_t>(base - j) * nw, nw)) * scale;
    if (inside < k) {  // the match leaves the image: column 0 repeats (or "worst": INVALID_COST)
      const float edge = worst ? 1.0f : static_cast<float>(hamming<NW>(a, rrow, nw)) * scale;
      for (int j = std::max(inside, 0); j < k; ++j) o[j] = edge;
    }
  }
}

SJ_CLONES void census_rows(const uint32_t* cl, const uint32_t* cr, const int32_t* off, float* out, int w, int k,
                           int nw, bool worst, float scale, int y0, int y1) {
  for (int y = y0; y < y1; ++y) {
    const size_t p = static_cast<size_t>(y) * w;
    const uint32_t* a = cl + p * nw;
    const uint32_t* b = cr + p * nw;
    if (nw == 2)
      census_row<2>(a, b, off + p, out + p * k, w, k, nw, worst, scale);
    else if (nw == 1)
      census_row<1>(a, b, off + p, out + p * k, w, k, nw, worst, scale);
    else
      census_row<0>(a, b, off + p, out + p * k, w, k, nw, worst, scale);
  }
}

ffi::Error CensusImpl(ffi::Buffer<ffi::U32> left, ffi::Buffer<ffi::U32> right, ffi::Buffer<ffi::S32> offset,
                      ffi::ResultBuffer<ffi::F32> out, int32_t worst, float scale, int32_t threads) {
  int h, w, nw, ho, wo, k;
  dims3(left, h, w, nw);
  dims3(*out, ho, wo, k);
  if (ho != h || wo != w) return ffi::Error::InvalidArgument("census: output and census words differ in size");
  const uint32_t* cl = left.typed_data();
  const uint32_t* cr = right.typed_data();
  const int32_t* off = offset.typed_data();
  float* dst = out->typed_data();
  parallel_for(h, threads, [&](int y0, int y1) { census_rows(cl, cr, off, dst, w, k, nw, worst != 0, scale, y0, y1); });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxCensus);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxCensus, stereojax::CensusImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::U32>>()  // left census words [H, W, NW]
                                  .Arg<xla::ffi::Buffer<xla::ffi::U32>>()  // right census words [H, W, NW]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W]
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // cost [H, W, K]
                                  .Attr<int32_t>("worst")
                                  .Attr<float>("scale")
                                  .Attr<int32_t>("threads"));
