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

// popcount of 32 bits in plain integer steps, which the compiler vectorises over k (a popcount
// instruction works on one word at a time; vector popcounts need AVX-512 VPOPCNTDQ)
SJ_INLINE uint32_t pop32(uint32_t v) {
  v = v - ((v >> 1) & 0x55555555u);
  v = (v & 0x33333333u) + ((v >> 2) & 0x33333333u);
  v = (v + (v >> 4)) & 0x0F0F0F0Fu;
  return (v * 0x01010101u) >> 24;
}

// One row. The right row's words are first laid out reversed and word by word (rev[t][i] =
// word t of column W - 1 - i), so that entry k of the pixel x (match column x - off - k) reads
// rev[t][W - 1 - x + off + k], ascending in k.
template <int NW>
SJ_INLINE void census_row(const uint32_t* __restrict cl, const uint32_t* __restrict rrow, const int32_t* off,
                          float* __restrict out, int w, int k, int nw_rt, bool worst, float scale,
                          std::vector<uint32_t>& rev, std::vector<uint64_t>& rev64) {
  const int nw = NW > 0 ? NW : nw_rt;
  if (NW == 2) {  // both words as one 64-bit word: one popcount instruction per entry
    rev64.resize(w);
    for (int i = 0; i < w; ++i) std::memcpy(&rev64[i], rrow + static_cast<size_t>(w - 1 - i) * 2, 8);
  } else {
    rev.resize(static_cast<size_t>(nw) * w);
    for (int t = 0; t < nw; ++t)
      for (int i = 0; i < w; ++i) rev[static_cast<size_t>(t) * w + i] = rrow[static_cast<size_t>(w - 1 - i) * nw + t];
  }
  for (int x = 0; x < w; ++x) {
    const uint32_t* a = cl + static_cast<size_t>(x) * nw;
    float* __restrict o = out + static_cast<size_t>(x) * k;
    const int base = x - off[x];
    const int inside = std::max(0, std::min(k, base + 1));  // entries j < inside match inside the image
    const int start = w - 1 - base;
    if (NW == 2) {  // one pass (the sum of two small integers is exact, as the JAX kernel's f32 sum)
      uint64_t av;
      std::memcpy(&av, a, 8);
      const uint64_t* __restrict r = rev64.data() + start;
      for (int j = 0; j < inside; ++j) o[j] = static_cast<float>(__builtin_popcountll(av ^ r[j])) * scale;
    } else {
      for (int j = 0; j < inside; ++j) o[j] = 0.f;
      for (int t = 0; t < nw; ++t) {
        const uint32_t at = a[t];
        const uint32_t* __restrict r = rev.data() + static_cast<size_t>(t) * w + start;
        for (int j = 0; j < inside; ++j) o[j] += static_cast<float>(static_cast<int>(pop32(at ^ r[j])));
      }
      for (int j = 0; j < inside; ++j) o[j] *= scale;
    }
    if (inside < k) {  // the match leaves the image: column 0 repeats (or "worst": INVALID_COST)
      float edge = 1.0f;
      if (!worst) {
        int bits = 0;
        for (int t = 0; t < nw; ++t) bits += static_cast<int>(pop32(a[t] ^ rrow[t]));
        edge = static_cast<float>(bits) * scale;
      }
      for (int j = inside; j < k; ++j) o[j] = edge;
    }
  }
}

SJ_CLONES void census_rows(const uint32_t* cl, const uint32_t* cr, const int32_t* off, float* out, int w, int k,
                           int nw, bool worst, float scale, int y0, int y1) {
  std::vector<uint32_t> rev;
  std::vector<uint64_t> rev64;
  for (int y = y0; y < y1; ++y) {
    const size_t p = static_cast<size_t>(y) * w;
    const uint32_t* a = cl + p * nw;
    const uint32_t* b = cr + p * nw;
    if (nw == 2)
      census_row<2>(a, b, off + p, out + p * k, w, k, nw, worst, scale, rev, rev64);
    else
      census_row<0>(a, b, off + p, out + p * k, w, k, nw, worst, scale, rev, rev64);
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
