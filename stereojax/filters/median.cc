// Native median filter: the kernel of median.py (median_filter), held exactly equal to it by
// tests/filters/test_median_native.py: the median of the size x size window of each pixel, the
// image's edge repeated outside it (an odd window: the middle value itself, so both kernels give
// the same float).
//
// Forgetful selection (Paeth), as the JAX kernel, on whole rows at once: keep n / 2 + 2 of the
// window's n values, move their minimum to the front and their maximum to the back, drop both,
// take in the next value, until one is left. Each step is an element-wise min / max over a row of
// pixels (the vector loop), so a row's windows are done together; the rows of values live in a
// small ring of row buffers (no allocation per pixel). Rows of the image run on all threads.
#include <algorithm>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

// a[x], b[x] = min, max of (a[x], b[x]) for x in [0, w)
SJ_INLINE void min_max(float* __restrict a, float* __restrict b, int w) {
  for (int x = 0; x < w; ++x) {
    const float lo = a[x] < b[x] ? a[x] : b[x];
    const float hi = a[x] < b[x] ? b[x] : a[x];
    a[x] = lo;
    b[x] = hi;
  }
}

constexpr int kTile = 128;  // columns per tile

SJ_CLONES void median_rows(const float* img, float* out, int h, int w, int r, int y0, int y1) {
  const int size = 2 * r + 1, n = size * size, keep = n / 2 + 2;
  const int pw = w + 2 * r;
  std::vector<float> pad(static_cast<size_t>(size) * pw);        // the window's rows, edge-padded
  std::vector<float> store(static_cast<size_t>(keep + 1) * kTile);  // rows of candidates
  std::vector<float*> cand, free_rows;
  for (int y = y0; y < y1; ++y) {
    for (int dy = 0; dy < size; ++dy) {
      const float* src = img + static_cast<size_t>(std::min(std::max(y + dy - r, 0), h - 1)) * w;
      float* dst = pad.data() + static_cast<size_t>(dy) * pw;
      for (int i = 0; i < r; ++i) dst[i] = src[0];
      std::copy(src, src + w, dst + r);
      for (int i = 0; i < r; ++i) dst[r + w + i] = src[w - 1];
    }
    // value m of the window (row m / size, column m % size) at pixel x: value(m)[x]
    auto value = [&](int m) { return pad.data() + static_cast<size_t>(m / size) * pw + m % size; };
    // in tiles of columns, so that a tile's candidate rows stay in the L1 cache
    for (int x0 = 0; x0 < w; x0 += kTile) {
      const int tw = std::min(kTile, w - x0);
      cand.clear();
      free_rows.clear();
      for (int i = 0; i <= keep; ++i) free_rows.push_back(store.data() + static_cast<size_t>(i) * kTile);
      int next = 0;
      for (; next < keep; ++next) {
        float* row = free_rows.back();
        free_rows.pop_back();
        std::copy(value(next) + x0, value(next) + x0 + tw, row);
        cand.push_back(row);
      }
      for (;;) {
        const int len = static_cast<int>(cand.size());
        for (int i = 1; i < len; ++i) min_max(cand[0], cand[i], tw);            // minimum to the front
        for (int i = 1; i < len - 1; ++i) min_max(cand[i], cand[len - 1], tw);  // maximum to the back
        free_rows.push_back(cand.back());
        free_rows.push_back(cand.front());
        cand.pop_back();
        cand.erase(cand.begin());
        if (next == n) break;
        float* row = free_rows.back();
        free_rows.pop_back();
        std::copy(value(next) + x0, value(next) + x0 + tw, row);
        ++next;
        cand.push_back(row);
      }
      std::copy(cand[0], cand[0] + tw, out + static_cast<size_t>(y) * w + x0);
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
