// Native filling of the pixels the left-right check rejected: the kernel of filling.py
// (fill_disparity), held exactly equal to it by tests/validation/test_filling_native.py.
//
// Occluded pixels take the nearest correct disparity to their left (to their right where the
// row has none on the left); mismatched pixels the median of the nearest correct disparities
// along the 8 directions (the mean of the two middle ones for an even count); a pixel with no
// correct pixel in any direction keeps its value. The 8 "nearest correct so far" maps are one
// pass each over the image (rows on all threads for the horizontal ones).
#include <algorithm>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

constexpr int kCorrect = 0, kMismatch = 1, kOcclusion = 2;

struct Near {
  std::vector<float> v;
  std::vector<uint8_t> ok;
  void init(size_t n) {
    v.assign(n, 0.f);
    ok.assign(n, 0);
  }
};

// nearest correct pixel met walking from p in direction (-dy, -dx), for one of the 8 directions
void propagate(const float* disp, const int32_t* lab, int h, int w, int dy, int dx, Near& out) {
  const int y_first = dy == -1 ? h - 1 : 0, y_step = dy == -1 ? -1 : 1;
  const int x_first = dx == -1 ? w - 1 : 0, x_step = dx == -1 ? -1 : 1;
  for (int iy = 0; iy < h; ++iy) {
    const int y = y_first + iy * y_step;
    const int yp = y - dy;
    for (int ix = 0; ix < w; ++ix) {
      const int x = x_first + ix * x_step;
      const size_t p = static_cast<size_t>(y) * w + x;
      if (lab[p] == kCorrect) {
        out.v[p] = disp[p];
        out.ok[p] = 1;
        continue;
      }
      const int xp = x - dx;
      if (yp >= 0 && yp < h && xp >= 0 && xp < w) {
        const size_t q = static_cast<size_t>(yp) * w + xp;
        out.v[p] = out.v[q];
        out.ok[p] = out.ok[q];
      } else {
        out.v[p] = 0.f;
        out.ok[p] = 0;
      }
    }
  }
}

ffi::Error FillImpl(ffi::Buffer<ffi::F32> disp, ffi::Buffer<ffi::S32> labels, ffi::ResultBuffer<ffi::F32> out,
                    int32_t threads) {
  int h, w, one;
  dims3(disp, h, w, one);
  const size_t n = static_cast<size_t>(h) * w;
  const float* d = disp.typed_data();
  const int32_t* lab = labels.typed_data();
  float* dst = out->typed_data();
  // the order of the JAX kernel's candidates: left, right, up, down, then the diagonals
  // (1, 1), (1, -1), (-1, 1), (-1, -1); only the sorted values matter
  static const int dirs[8][2] = {{0, 1}, {0, -1}, {1, 0}, {-1, 0}, {1, 1}, {1, -1}, {-1, 1}, {-1, -1}};
  Near near[8];
  parallel_for(8, threads, [&](int b, int e) {
    for (int i = b; i < e; ++i) {
      near[i].init(n);
      propagate(d, lab, h, w, dirs[i][0], dirs[i][1], near[i]);
    }
  });
  parallel_for(h, threads, [&](int y0, int y1) {
    for (size_t p = static_cast<size_t>(y0) * w; p < static_cast<size_t>(y1) * w; ++p) {
      const int l = lab[p];
      float v = d[p];
      if (l == kOcclusion) {
        v = near[0].ok[p] ? near[0].v[p] : (near[1].ok[p] ? near[1].v[p] : d[p]);
      } else if (l == kMismatch) {
        float c[8];
        int cnt = 0;
        for (int i = 0; i < 8; ++i)
          if (near[i].ok[p]) c[cnt++] = near[i].v[p];
        if (cnt > 0) {
          std::sort(c, c + cnt);
          v = 0.5f * (c[(cnt - 1) / 2] + c[cnt / 2]);
        }
      }
      dst[p] = v;
    }
  });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxFill);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxFill, stereojax::FillImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // disparity [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // labels of the left-right check [H, W]
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // filled disparity [H, W]
                                  .Attr<int32_t>("threads"));
