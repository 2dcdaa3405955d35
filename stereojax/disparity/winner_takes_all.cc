// Native winner-takes-all: the kernel of winner_takes_all.py (wta_volume), held exactly equal to
// it by tests/disparity/test_winner_takes_all.py: the first entry of least cost (jnp.argmin)
// plus the pixel's band offset (0 for the full range). Rows run on all threads.
#include "../native_common.h"

namespace stereojax {
namespace {

template <int KC>
SJ_INLINE void wta_row(const float* __restrict c, const int32_t* off, int32_t* out, int w, int kk, bool banded) {
  const int k = KC > 0 ? KC : kk;
  for (int x = 0; x < w; ++x) {
    const float* __restrict v = c + static_cast<size_t>(x) * k;
    float best = v[0];
    for (int j = 1; j < k; ++j) best = v[j] < best ? v[j] : best;
    int arg = 0;
    while (v[arg] != best) ++arg;
    out[x] = arg + (banded ? off[x] : 0);
  }
}

SJ_CLONES void wta_rows(const float* cost, const int32_t* off, int32_t* out, int w, int k, bool banded, int y0,
                        int y1) {
  for (int y = y0; y < y1; ++y) {
    const size_t p = static_cast<size_t>(y) * w;
    if (k == 48)
      wta_row<48>(cost + p * k, off + p, out + p, w, k, banded);
    else
      wta_row<0>(cost + p * k, off + p, out + p, w, k, banded);
  }
}

ffi::Error WtaImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::ResultBuffer<ffi::S32> out,
                   int32_t banded, int32_t threads) {
  int h, w, k;
  dims3(cost, h, w, k);
  const float* c = cost.typed_data();
  const int32_t* off = offset.typed_data();
  int32_t* dst = out->typed_data();
  parallel_for(h, threads, [&](int y0, int y1) { wta_rows(c, off, dst, w, k, banded != 0, y0, y1); });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxWta);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxWta, stereojax::WtaImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // cost [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W]
                                  .Ret<xla::ffi::Buffer<xla::ffi::S32>>()  // disparity [H, W]
                                  .Attr<int32_t>("banded")
                                  .Attr<int32_t>("threads"));
