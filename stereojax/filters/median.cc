// Native median filter: the kernel of median.py (median_filter), held exactly equal to it by
// tests/filters/test_median_native.py: the median of the size x size window of each pixel, the
// image's edge repeated outside it (an odd window: the middle value itself, so both kernels give
// the same float). Rows run on all threads; each pixel's window goes through nth_element.
#include <algorithm>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

SJ_CLONES void median_rows(const float* img, float* out, int h, int w, int r, int y0, int y1) {
  const int size = 2 * r + 1, n = size * size;
  std::vector<float> win(n);
  std::vector<int> cols(w + 2 * r);
  for (int i = 0; i < w + 2 * r; ++i) cols[i] = std::min(std::max(i - r, 0), w - 1);
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < w; ++x) {
      int m = 0;
      for (int dy = -r; dy <= r; ++dy) {
        const float* row = img + static_cast<size_t>(std::min(std::max(y + dy, 0), h - 1)) * w;
        for (int dx = 0; dx < size; ++dx) win[m++] = row[cols[x + dx]];
      }
      std::nth_element(win.begin(), win.begin() + n / 2, win.end());
      out[static_cast<size_t>(y) * w + x] = win[n / 2];
    }
  }
}

ffi::Error MedianImpl(ffi::Buffer<ffi::F32> img, ffi::ResultBuffer<ffi::F32> out, int32_t size, int32_t threads) {
  int h, w, one;
  dims3(img, h, w, one);
  if (size < 1 || size % 2 == 0) return ffi::Error::InvalidArgument("median: size must be odd");
  const float* src = img.typed_data();
  float* dst = out->typed_data();
  parallel_for(h, threads, [&](int y0, int y1) { median_rows(src, dst, h, w, size / 2, y0, y1); });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxMedian);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxMedian, stereojax::MedianImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // disparity [H, W]
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // its median [H, W]
                                  .Attr<int32_t>("size")
                                  .Attr<int32_t>("threads"));
