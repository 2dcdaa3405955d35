// Native confidence: the kernel of confidence_measure.py (confidence_volume), held equal to it by
// tests/validation/test_confidence_measure_native.py (1e-6: exp may differ in its last bit).
//
// The margin (c2 - c1) / c2 between the WTA entry c1 and the best entry at least 2 away c2
// (c2 = c1 when there is none), clipped to [0, 1] and 0 where c2 <= 0; times the left-right
// agreement exp(-max(|d1 - D_R(x - d1)| - tolerance, 0)), 0.5 where x - d1 leaves the image.
#include <algorithm>
#include <cfloat>
#include <cmath>

#include "../native_common.h"

namespace stereojax {
namespace {

SJ_CLONES void confidence_rows(const float* cost, const int32_t* off, const int32_t* disp, const int32_t* dright,
                               float* out, int w, int k, bool banded, bool has_right, float tol, int y0, int y1) {
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t p = static_cast<size_t>(y) * w + x;
      const float* __restrict c = cost + p * k;
      const int d1 = disp[p] - (banded ? off[p] : 0);  // the WTA entry within the band
      const float c1 = c[d1 < 0 ? 0 : (d1 >= k ? k - 1 : d1)];
      // (the build assumes finite math: FLT_MAX, above every cost, marks the near entries)
      float c2 = FLT_MAX;
      for (int j = 0; j < k; ++j) {
        const bool near = j - d1 <= 1 && d1 - j <= 1;
        const float v = near ? FLT_MAX : c[j];
        c2 = v < c2 ? v : c2;
      }
      const int n_near = std::min(k - 1, d1 + 1) - std::max(0, d1 - 1) + 1;
      if (k <= n_near) c2 = c1;  // no entry at least 2 away
      float margin = 0.f;
      if (c2 > 0.f) {
        margin = (c2 - c1) / std::max(c2, 1e-12f);
        margin = std::min(std::max(margin, 0.f), 1.f);
      }
      if (!has_right) {
        out[p] = margin;
        continue;
      }
      const int xr = x - disp[p];
      const int xc = xr < 0 ? 0 : (xr >= w ? w - 1 : xr);
      const float dr = static_cast<float>(dright[static_cast<size_t>(y) * w + xc]);
      const float agree = std::exp(-std::max(std::fabs(static_cast<float>(disp[p]) - dr) - tol, 0.f));
      out[p] = margin * (xr >= 0 ? agree : 0.5f);
    }
  }
}

ffi::Error ConfidenceImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::Buffer<ffi::S32> disp,
                          ffi::Buffer<ffi::S32> disp_right, ffi::ResultBuffer<ffi::F32> out, int32_t banded,
                          int32_t has_right, float tolerance, int32_t threads) {
  int h, w, k;
  dims3(cost, h, w, k);
  const float* c = cost.typed_data();
  const int32_t* off = offset.typed_data();
  const int32_t* d = disp.typed_data();
  const int32_t* dr = disp_right.typed_data();
  float* dst = out->typed_data();
  parallel_for(h, threads, [&](int y0, int y1) {
    confidence_rows(c, off, d, dr, dst, w, k, banded != 0, has_right != 0, tolerance, y0, y1);
  });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxConfidence);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxConfidence, stereojax::ConfidenceImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // cost [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // WTA disparity [H, W] (absolute)
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // right view's disparity [H, W]
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // confidence [H, W]
                                  .Attr<int32_t>("banded")
                                  .Attr<int32_t>("has_right")
                                  .Attr<float>("tolerance")
                                  .Attr<int32_t>("threads"));
