// Native right view + WTA: the kernel of right_view.py (right_wta), band and full range. Held
// exactly equal to the JAX kernel by tests/disparity/test_right_view_native.py.
//
// For the right pixel (y, x) and each d of its band [roff, roff + K) (the full range: roff = 0,
// K = D): C_R(x, d) = C_L(x + d, d), read from the left pixel x + d's band (BIG where d lies
// outside it), `invalid` where x + d lies beyond the real width. The result is the first d of
// least cost (JAX's argmin), as an absolute disparity. Rows run on all threads.
//
// The full range reads the volume in its own order instead of along its diagonals: each left
// pixel xl offers C(xl, d) to the right pixel xl - d, d ascending, and every right pixel keeps the
// first least cost it was offered (one pass over the volume, the running minima of a row in L1).
#include <algorithm>
#include <cfloat>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

// The right pixel x's costs C_L(x + d, d) for its band, gathered into c[0 .. K) (a loop the
// compiler vectorises with gathers), then the first index of their minimum.
template <int KC>
SJ_INLINE void right_row(const float* crow, const int32_t* orow, const int32_t* rrow, int32_t* out, int w, int kk,
                         int width, bool banded, float invalid, float* __restrict c) {
  const int k = KC > 0 ? KC : kk;
  for (int x = 0; x < w; ++x) {
    const int r0 = banded ? rrow[x] : 0;
    const int n_in = std::max(0, std::min(k, width - x - r0));  // entries with x + d inside the width
    for (int j = 0; j < n_in; ++j) {
      const int d = r0 + j;
      const int xl = x + d;
      const int jl = banded ? d - orow[xl] : d;
      const bool in_band = static_cast<unsigned>(jl) < static_cast<unsigned>(k);
      const float v = crow[static_cast<size_t>(xl) * k + (in_band ? jl : 0)];
      c[j] = in_band ? v : kBig;
    }
    for (int j = n_in; j < k; ++j) c[j] = invalid;
    float best = c[0];
    for (int j = 1; j < k; ++j) best = c[j] < best ? c[j] : best;
    int arg = 0;
    while (c[arg] != best) ++arg;
    out[x] = arg + r0;
  }
}

// The full range, rows [y0, y1): the running minimum of the right pixel x sits at i = W - 1 - x,
// so the pixels xl - d (d = 0 .. K-1) that one left pixel serves are ascending in memory.
SJ_CLONES void right_rows_full(const float* cost, int32_t* out, int w, int k, int width, float invalid, int y0,
                               int y1) {
  std::vector<float> best_v(w + k);
  std::vector<int32_t> arg_v(w + k);
  float* __restrict best = best_v.data();
  int32_t* __restrict arg = arg_v.data();
  const int wl = std::min(w, width);  // left pixels inside the real width
  for (int y = y0; y < y1; ++y) {
    std::fill(best, best + w + k, FLT_MAX);
    std::fill(arg, arg + w + k, 0);
    const float* crow = cost + static_cast<size_t>(y) * w * k;
    for (int xl = 0; xl < wl; ++xl) {
      const float* __restrict c = crow + static_cast<size_t>(xl) * k;
      const int n = std::min(k, xl + 1);  // d <= xl: the right pixel xl - d lies in the image
      float* __restrict b = best + (w - 1 - xl);
      int32_t* __restrict a = arg + (w - 1 - xl);
      for (int d = 0; d < n; ++d) {
        const bool lt = c[d] < b[d];
        b[d] = lt ? c[d] : b[d];
        a[d] = lt ? d : a[d];
      }
    }
    int32_t* o = out + static_cast<size_t>(y) * w;
    for (int x = 0; x < w; ++x) {
      const int i = w - 1 - x;
      const int n_in = std::max(0, std::min(k, width - x));  // entries with x + d inside the width
      int r = arg[i];
      if (n_in == 0)
        r = 0;
      else if (n_in < k && invalid < best[i])
        r = n_in;  // the first entry beyond the width costs `invalid`
      o[x] = r;
    }
  }
}

SJ_CLONES void right_rows(const float* cost, const int32_t* off, const int32_t* roff, int32_t* out, int w, int k,
                          int width, bool banded, float invalid, int y0, int y1) {
  std::vector<float> c(k);
  for (int y = y0; y < y1; ++y) {
    const float* crow = cost + static_cast<size_t>(y) * w * k;
    const int32_t* orow = off + static_cast<size_t>(y) * w;
    const int32_t* rrow = roff + static_cast<size_t>(y) * w;
    int32_t* o = out + static_cast<size_t>(y) * w;
    if (k == 48)
      right_row<48>(crow, orow, rrow, o, w, k, width, banded, invalid, c.data());
    else
      right_row<0>(crow, orow, rrow, o, w, k, width, banded, invalid, c.data());
  }
}

ffi::Error RightWtaImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::Buffer<ffi::S32> right_offset,
                        ffi::Buffer<ffi::S32> width, ffi::ResultBuffer<ffi::S32> out, int32_t banded, float invalid,
                        int32_t threads) {
  int h, w, k;
  dims3(cost, h, w, k);
  const int wd = std::min(w, width.typed_data()[0]);
  const float* c = cost.typed_data();
  const int32_t* off = offset.typed_data();
  const int32_t* roff = right_offset.typed_data();
  int32_t* dst = out->typed_data();
  if (banded)
    parallel_for(h, threads, [&](int y0, int y1) { right_rows(c, off, roff, dst, w, k, wd, true, invalid, y0, y1); });
  else
    parallel_for(h, threads, [&](int y0, int y1) { right_rows_full(c, dst, w, k, wd, invalid, y0, y1); });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxRightWta);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxRightWta, stereojax::RightWtaImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // left-view cost [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // left band offsets [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // right band offsets [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // real width [1]
                                  .Ret<xla::ffi::Buffer<xla::ffi::S32>>()  // right disparity [H, W]
                                  .Attr<int32_t>("banded")
                                  .Attr<float>("invalid")
                                  .Attr<int32_t>("threads"));
