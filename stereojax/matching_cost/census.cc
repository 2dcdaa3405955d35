// Native census matching cost: the kernel of classical.py (census_cost / census_band) after
// the census transform, band and full range. Held exactly equal to the JAX kernel by
// tests/matching_cost/test_classical_native.py.
//
// cost(y, x, k) = popcount(CL(y, x) ^ CR(y, max(x - off - k, 0))) * scale for the band
// [off, off + K) (the full range: off = 0, K = D); right columns left of the image repeat
// column 0, as the JAX kernel does; border "worst": INVALID_COST (1) where x - off - k < 0.
#include <algorithm>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

SJ_CLONES void census_rows(const uint32_t* cl, const uint32_t* cr, const int32_t* off, float* out, int w, int k,
                           int nw, bool worst, float scale, int y0, int y1) {
  for (int y = y0; y < y1; ++y) {
    const uint32_t* rrow = cr + static_cast<size_t>(y) * w * nw;
    for (int x = 0; x < w; ++x) {
      const size_t p = static_cast<size_t>(y) * w + x;
      const uint32_t* a = cl + p * nw;
      float* o = out + p * k;
      const int base = x - off[p];
      for (int j = 0; j < k; ++j) {
        const int u = base - j;
        const uint32_t* b = rrow + static_cast<size_t>(u > 0 ? u : 0) * nw;
        int bits = 0;
        for (int t = 0; t < nw; ++t) bits += __builtin_popcount(a[t] ^ b[t]);
        float v = static_cast<float>(bits) * scale;
        if (worst && u < 0) v = 1.0f;
        o[j] = v;
      }
    }
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
