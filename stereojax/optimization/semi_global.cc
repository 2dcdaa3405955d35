// Native SGM: the kernel of semi_global.py (sgm / sgm_volume), band and full range, 4 and 8
// paths, MC-CNN's adaptive penalties, the real-pixel bounds of a padded pair. Held equal to the
// JAX kernel by tests/optimization/test_semi_global_native.py.
//
// Layout: cost f32[H, W, K], K contiguous and innermost; a pixel's band is [off, off + K) (the
// full range is off = 0, K = D). The recurrence of one path step (semi_global._band_step):
//   L(p, k) = C(p, k) + min(Lp(k + s), min(Lp(k + s - 1), Lp(k + s + 1)) + P1, m + P2) - m
// with Lp the predecessor's path costs, s = off(p) - off(p - r) its band shift, m = min Lp,
// BIG outside the predecessor's band. A fresh start (first line of a path, a predecessor in the
// padding or outside the image) gives L = C.
//
// Work split: one sweep runs down the rows (the left-to-right path, the vertical path down and
// the two diagonals down), the other up (right to left, up, the diagonals up); they run on two
// threads, each keeps its lines of path costs (no allocation inside the sweep) and sums its
// paths of a row into one private row, and the two rows meet in the output: the first to
// arrive stores its row, the second adds its own and divides by the number of paths. Float
// addition commutes, so the result does not depend on which arrives first.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <thread>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

// P1 and P2 by the number (0, 1, 2) of large grey-level steps (left image, right image at the
// match) for one kind of path: horizontal, vertical, diagonal.
struct Pen {
  float p1[3];
  float p2[3];
};

struct Ctx {
  const float* cost;
  const int32_t* off;
  const float* left;
  const float* right;
  float* out;
  int h, w, k, max_disp, dirs;
  int r0, r1, c0, c1;
  bool banded, adaptive;
  float thr;
  Pen pen[3];  // horizontal, vertical, diagonal
  int m;       // margin of BIG each side of a stored line of path costs
  int stride;  // k + 2 m
};

// One path step of one pixel; returns min_k of the new path costs. prev points at the
// predecessor's first entry, with at least `m` BIG entries before and after its K entries.
// RIGHT: the penalties also count the right image's step at the match columns (br[k]).
template <bool RIGHT>
SJ_INLINE float step(const float* __restrict prev, int s, float m, const float* __restrict c,
                     float* __restrict out, int k, const uint8_t* __restrict br, int bl, const Pen& pen) {
  const float* __restrict ps = prev + s;
  float nm = kBig;
  if (RIGHT) {
    const float a0 = pen.p1[0], a1 = pen.p1[1], a2 = pen.p1[2];
    const float b0 = pen.p2[0], b1 = pen.p2[1], b2 = pen.p2[2];
    for (int j = 0; j < k; ++j) {
      const int n = bl + br[j];
      const float p1 = n == 0 ? a0 : (n == 1 ? a1 : a2);
      const float p2 = n == 0 ? b0 : (n == 1 ? b1 : b2);
      const float same = ps[j];
      const float lo = ps[j - 1], hi = ps[j + 1];
      const float near = lo < hi ? lo : hi;
      float best = near + p1;
      best = same < best ? same : best;
      const float jump = m + p2;
      best = best < jump ? best : jump;
      const float v = c[j] + best - m;
      out[j] = v;
      nm = v < nm ? v : nm;
    }
  } else {
    const float p1 = pen.p1[bl], p2 = pen.p2[bl];
    const float jump = m + p2;
    for (int j = 0; j < k; ++j) {
      const float same = ps[j];
      const float lo = ps[j - 1], hi = ps[j + 1];
      const float near = lo < hi ? lo : hi;
      float best = near + p1;
      best = same < best ? same : best;
      best = best < jump ? best : jump;
      const float v = c[j] + best - m;
      out[j] = v;
      nm = v < nm ? v : nm;
    }
  }
  return nm;
}

// A fresh start: L = C.
SJ_INLINE float fresh(const float* __restrict c, float* __restrict out, int k) {
  float nm = kBig;
  for (int j = 0; j < k; ++j) {
    out[j] = c[j];
    nm = c[j] < nm ? c[j] : nm;
  }
  return nm;
}

// The lines a sweep carries: per path, the path costs of the previous and the current line
// (with BIG margins), their minima and band offsets.
struct Line {
  std::vector<float> buf;
  std::vector<float> mins;
  std::vector<int32_t> offs;
  void init(int n, const Ctx& cx) {
    buf.assign(static_cast<size_t>(n) * cx.stride, kBig);
    mins.assign(n, 0.f);
    offs.assign(n, 0);
  }
  float* at(int i, const Ctx& cx) { return buf.data() + static_cast<size_t>(i) * cx.stride + cx.m; }
};

SJ_INLINE bool big_step(float a, float b, float thr) { return std::fabs(a - b) >= thr; }

// The right image's large steps along (dy, dx) on row y, laid out so that the pixel at column x
// with band offset o reads its match columns max(x - o - k, 0), k = 0 .. K-1, as
// rev[W - 1 - x + o + k] (ascending in k).
void right_steps(const Ctx& cx, int y, int dy, int dx, uint8_t* rev) {
  const int w = cx.w, h = cx.h;
  const float* row = cx.right + static_cast<size_t>(y) * w;
  const int yp = y - dy;
  const bool row_ok = yp >= 0 && yp < h;
  const float* prow = cx.right + static_cast<size_t>(row_ok ? yp : y) * w;
  const int len = w + cx.max_disp;
  for (int j = 0; j < len; ++j) {
    const int x = std::max(w - 1 - j, 0);
    const int xp = x - dx;
    uint8_t b = 0;
    if (row_ok && xp >= 0 && xp < w) b = big_step(row[x], prow[xp], cx.thr);
    rev[j] = b;
  }
}

SJ_INLINE int band_shift(const Ctx& cx, int o, int op) {
  if (!cx.banded) return 0;
  const int s = o - op;
  const int lim = cx.k + 1;
  return s < -lim ? -lim : (s > lim ? lim : s);
}

// One sweep (dy = +1 down, -1 up) over every row; merges its row sums into out.
struct Merge {
  std::vector<std::mutex> locks;
  std::vector<uint8_t> seen;
  explicit Merge(int h) : locks(h), seen(h, 0) {}
};

SJ_CLONES void sweep(const Ctx& cx, int dy, Merge& merge) {
  const int h = cx.h, w = cx.w, k = cx.k;
  const int dx = dy;  // the horizontal path of this sweep: left to right going down
  const size_t row_len = static_cast<size_t>(w) * k;
  std::vector<float> sum(row_len);
  std::vector<float> hbuf(2 * static_cast<size_t>(cx.stride), kBig);  // horizontal carry, ping-pong
  const int n_row_paths = cx.dirs == 8 ? 3 : 1;
  Line prev[3], cur[3];
  for (int p = 0; p < n_row_paths; ++p) {
    prev[p].init(w, cx);
    cur[p].init(w, cx);
  }
  std::vector<float> path(static_cast<size_t>(cx.stride));
  std::vector<uint8_t> rev_h(w + cx.max_disp), rev_v(w + cx.max_disp);
  const bool adaptive = cx.adaptive;
  bool started = false;  // a row of the vertical paths exists

  for (int i = 0; i < h; ++i) {
    const int y = dy == 1 ? i : h - 1 - i;
    const float* crow = cx.cost + static_cast<size_t>(y) * row_len;
    const int32_t* orow = cx.off + static_cast<size_t>(y) * w;
    const float* lrow = cx.left + static_cast<size_t>(y) * w;
    std::fill(sum.begin(), sum.end(), 0.f);

    // horizontal path over the real columns [c0, c1), every row
    if (cx.c1 > cx.c0) {
      if (adaptive) right_steps(cx, y, 0, dx, rev_h.data());
      float m = 0.f;
      int op = 0;
      int slot = 0;
      for (int t = 0; t < cx.c1 - cx.c0; ++t) {
        const int x = dx == 1 ? cx.c0 + t : cx.c1 - 1 - t;
        const float* c = crow + static_cast<size_t>(x) * k;
        float* o = hbuf.data() + static_cast<size_t>(slot) * cx.stride + cx.m;
        const int xo = orow[x];
        float nm;
        if (t == 0) {
          nm = fresh(c, o, k);
        } else {
          const float* pv = hbuf.data() + static_cast<size_t>(1 - slot) * cx.stride + cx.m;
          const int xp = x - dx;
          const int bl = big_step(lrow[x], lrow[xp], cx.thr);
          const int s = band_shift(cx, xo, op);
          if (adaptive)
            nm = step<true>(pv, s, m, c, o, k, rev_h.data() + (w - 1 - x + xo), bl, cx.pen[0]);
          else
            nm = step<false>(pv, s, m, c, o, k, nullptr, 0, cx.pen[0]);
        }
        float* sm = sum.data() + static_cast<size_t>(x) * k;
        for (int j = 0; j < k; ++j) sm[j] = o[j];
        m = nm;
        op = xo;
        slot = 1 - slot;
      }
    }

    // the vertical (and diagonal) paths over the real rows [r0, r1), every column
    if (y >= cx.r0 && y < cx.r1) {
      const bool first = !started;
      const int yp = y - dy;
      const float* lprev = cx.left + static_cast<size_t>(yp >= 0 && yp < h ? yp : y) * w;
      const bool yp_in = yp >= 0 && yp < h;
      if (adaptive) right_steps(cx, y, dy, 0, rev_v.data());
      for (int p = 0; p < n_row_paths; ++p) {
        const int sx = p == 0 ? 0 : (p == 1 ? 1 : -1);  // the predecessor of x is x - sx
        const Pen& pen = p == 0 ? cx.pen[1] : cx.pen[2];
        Line& pl = prev[p];
        Line& cl = cur[p];
        for (int x = 0; x < w; ++x) {
          const float* c = crow + static_cast<size_t>(x) * k;
          float* o = cl.at(x, cx);
          const int xo = orow[x];
          const int xp = x - sx;
          float nm;
          if (first || xp < cx.c0 || xp >= cx.c1 || xp < 0 || xp >= w) {
            // a fresh start; a vertical path (sx = 0) always has its predecessor after row one
            if (first || sx != 0) {
              nm = fresh(c, o, k);
            } else {
              const int bl = yp_in && big_step(lrow[x], lprev[x], cx.thr);
              const int s = band_shift(cx, xo, pl.offs[x]);
              nm = adaptive ? step<true>(pl.at(x, cx), s, pl.mins[x], c, o, k, rev_v.data() + (w - 1 - x + xo), bl, pen)
                            : step<false>(pl.at(x, cx), s, pl.mins[x], c, o, k, nullptr, 0, pen);
            }
          } else {
            const int bl = yp_in && big_step(lrow[x], lprev[xp], cx.thr);
            const int s = band_shift(cx, xo, pl.offs[xp]);
            if (sx == 0 && adaptive)
              nm = step<true>(pl.at(xp, cx), s, pl.mins[xp], c, o, k, rev_v.data() + (w - 1 - x + xo), bl, pen);
            else if (sx != 0 && adaptive)
              nm = step<false>(pl.at(xp, cx), s, pl.mins[xp], c, o, k, nullptr, bl, pen);
            else
              nm = step<false>(pl.at(xp, cx), s, pl.mins[xp], c, o, k, nullptr, 0, pen);
          }
          cl.mins[x] = nm;
          cl.offs[x] = xo;
          float* sm = sum.data() + static_cast<size_t>(x) * k;
          for (int j = 0; j < k; ++j) sm[j] += o[j];
        }
        std::swap(prev[p], cur[p]);
      }
      started = true;
    }

    // meet the other sweep's row in the output
    float* orow_out = cx.out + static_cast<size_t>(y) * row_len;
    std::lock_guard<std::mutex> lock(merge.locks[y]);
    if (!merge.seen[y]) {
      std::memcpy(orow_out, sum.data(), row_len * sizeof(float));
      merge.seen[y] = 1;
    } else {
      const float dirs = static_cast<float>(cx.dirs);
      const float* __restrict sm = sum.data();
      float* __restrict dst = orow_out;
      for (size_t j = 0; j < row_len; ++j) dst[j] = (dst[j] + sm[j]) / dirs;
    }
  }
}

ffi::Error SgmImpl(ffi::Buffer<ffi::F32> cost, ffi::Buffer<ffi::S32> offset, ffi::Buffer<ffi::F32> left,
                   ffi::Buffer<ffi::F32> right, ffi::Buffer<ffi::S32> bounds, ffi::ResultBuffer<ffi::F32> out,
                   int32_t directions, int32_t max_disp, int32_t banded, int32_t adaptive, float threshold,
                   ffi::Span<const float> penalties, int32_t threads) {
  Ctx cx{};
  dims3(cost, cx.h, cx.w, cx.k);
  if (cost.dimensions().size() != 3) return ffi::Error::InvalidArgument("sgm: cost must be [H, W, K]");
  if (penalties.size() != 18) return ffi::Error::InvalidArgument("sgm: 18 penalties expected");
  if (directions != 4 && directions != 8) return ffi::Error::InvalidArgument("sgm: directions must be 4 or 8");
  if (max_disp < cx.k) return ffi::Error::InvalidArgument("sgm: max_disp < K");
  cx.cost = cost.typed_data();
  cx.off = offset.typed_data();
  cx.left = left.typed_data();
  cx.right = right.typed_data();
  cx.out = out->typed_data();
  cx.max_disp = max_disp;
  cx.dirs = directions;
  const int32_t* b = bounds.typed_data();
  cx.r0 = std::max(0, b[0]);
  cx.r1 = std::min(cx.h, b[1]);
  cx.c0 = std::max(0, b[2]);
  cx.c1 = std::min(cx.w, b[3]);
  cx.banded = banded != 0;
  cx.adaptive = adaptive != 0;
  cx.thr = threshold;
  for (int kind = 0; kind < 3; ++kind)
    for (int n = 0; n < 3; ++n) {
      cx.pen[kind].p1[n] = penalties[kind * 6 + n];
      cx.pen[kind].p2[n] = penalties[kind * 6 + 3 + n];
    }
  cx.m = cx.banded ? cx.k + 2 : 1;
  cx.stride = cx.k + 2 * cx.m;
  Merge merge(cx.h);
  if (threads >= 2) {
    std::thread up([&] { sweep(cx, -1, merge); });
    sweep(cx, 1, merge);
    up.join();
  } else {
    sweep(cx, 1, merge);
    sweep(cx, -1, merge);
  }
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxSgm);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxSgm, stereojax::SgmImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // cost [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // left grey [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // right grey [H, W]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // r0, r1, c0, c1
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()
                                  .Attr<int32_t>("directions")
                                  .Attr<int32_t>("max_disp")
                                  .Attr<int32_t>("banded")
                                  .Attr<int32_t>("adaptive")
                                  .Attr<float>("threshold")
                                  .Attr<xla::ffi::Span<const float>>("penalties")
                                  .Attr<int32_t>("threads"));
