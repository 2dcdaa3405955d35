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
};

// One path step of one pixel; returns min_k of the new path costs. prev points at the
// predecessor's first entry, with at least `m` BIG entries before and after its K entries.
// p1v, p2v: the penalties of each entry (they differ with the right image's step at the match
// column), or null for the scalar penalties p1, p2.
SJ_INLINE float step(const float* __restrict prev, int s, float m, const float* __restrict c,
                     float* __restrict out, int k, const float* __restrict p1v, const float* __restrict p2v,
                     float p1, float p2) {
  const float* __restrict ps = prev + s;
  float nm = kBig;
  if (p1v) {
    for (int j = 0; j < k; ++j) {
      const float same = ps[j];
      const float lo = ps[j - 1], hi = ps[j + 1];
      const float near = lo < hi ? lo : hi;
      float best = near + p1v[j];
      best = same < best ? same : best;
      const float jump = m + p2v[j];
      best = best < jump ? best : jump;
      const float v = c[j] + best - m;
      out[j] = v;
      nm = v < nm ? v : nm;
    }
  } else {
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

// A line of pixels' path costs (K entries each, with one BIG entry before and after them), their
// minima and band offsets. A pixel whose predecessor has the same band offset (always, over the
// full range) reads the predecessor's entries where they lie; a band shift first copies them
// into a small buffer with wider BIG margins (Ext).
struct Line {
  std::vector<float> buf;
  std::vector<float> mins;
  std::vector<int32_t> offs;
  int k = 0;
  size_t stride = 0;
  void init(int n, int k_) {
    k = k_;
    stride = static_cast<size_t>(k) + 2;
    buf.assign(static_cast<size_t>(n) * stride, kBig);
    mins.assign(n, 0.f);
    offs.assign(n, 0);
  }
  float* at(int i) { return buf.data() + static_cast<size_t>(i) * stride + 1; }
  void swap(Line& o) {
    buf.swap(o.buf);
    mins.swap(o.mins);
    offs.swap(o.offs);
  }
};

// The predecessor's K entries with K + 2 BIG entries each side (a band shift |s| <= K + 1 then
// reads BIG where it leaves the predecessor's band).
struct Ext {
  std::vector<float> buf;
  int k = 0;
  void init(int k_) {
    k = k_;
    buf.assign(3 * static_cast<size_t>(k) + 4, kBig);
  }
  const float* load(const float* __restrict prev) {
    float* __restrict mid = buf.data() + k + 2;
    for (int j = 0; j < k; ++j) mid[j] = prev[j];
    return mid;
  }
  // the predecessor's entries as step() reads them: in place without a band shift
  const float* pred(const float* prev, int s) { return s == 0 ? prev : load(prev); }
};

SJ_INLINE bool big_step(float a, float b, float thr) { return std::fabs(a - b) >= thr; }

// The penalties of a path that counts the right image's steps, for row y: the right image's
// large steps along (dy, dx) at the match columns, laid out so that the pixel at column x with
// band offset o reads its entries k = 0 .. K-1 (match columns max(x - o - k, 0)) at
// [W - 1 - x + o + k], ascending in k; one plane of P1 and one of P2 for a pixel without (bl = 0)
// and with (bl = 1) a large step in the left image.
struct RightPen {
  std::vector<float> p1[2], p2[2];
  void init(int len) {
    for (int b = 0; b < 2; ++b) {
      p1[b].resize(len);
      p2[b].resize(len);
    }
  }
  void fill(const Ctx& cx, int y, int dy, int dx, const Pen& pen) {
    const int w = cx.w, h = cx.h;
    const float* row = cx.right + static_cast<size_t>(y) * w;
    const int yp = y - dy;
    const bool row_ok = yp >= 0 && yp < h;
    const float* prow = cx.right + static_cast<size_t>(row_ok ? yp : y) * w;
    const int len = static_cast<int>(p1[0].size());
    for (int j = 0; j < len; ++j) {
      const int x = std::max(w - 1 - j, 0);
      const int xp = x - dx;
      const int br = row_ok && xp >= 0 && xp < w && big_step(row[x], prow[xp], cx.thr);
      p1[0][j] = pen.p1[br];
      p2[0][j] = pen.p2[br];
      p1[1][j] = pen.p1[1 + br];
      p2[1][j] = pen.p2[1 + br];
    }
  }
};

SJ_INLINE int band_shift(const Ctx& cx, int o, int op) {
  if (!cx.banded) return 0;
  const int s = o - op;
  const int lim = cx.k + 1;
  return s < -lim ? -lim : (s > lim ? lim : s);
}

// Where the two sweeps meet: per row, whether one sweep has stored its sum there yet.
struct Merge {
  std::vector<std::mutex> locks;
  std::vector<uint8_t> seen;
  explicit Merge(int h) : locks(h), seen(h, 0) {}
};

// One sweep (dy = +1 down, -1 up) over every row, with the horizontal path dx = dy; merges its
// row sums into out.
template <int KC>
SJ_INLINE void sweep_k(const Ctx& cx, int dy, Merge& merge) {
  const int h = cx.h, w = cx.w, k = KC > 0 ? KC : cx.k;
  const int dx = dy;
  const size_t row_len = static_cast<size_t>(w) * k;
  const int n_row_paths = cx.dirs == 8 ? 3 : 1;
  Line sum;  // this sweep's paths of the row, summed; the horizontal path writes it first
  sum.init(w, k);
  // line[0]: the vertical path's row, written while vprev (the previous row) is read, then the two
  // swap; the diagonals update their line in place (see below)
  Line line[3], vprev;
  for (int p = 0; p < n_row_paths; ++p) line[p].init(w, k);
  vprev.init(w, k);
  Ext ext;
  ext.init(k);
  RightPen pen_h, pen_v;
  if (cx.adaptive) {
    pen_h.init(w + cx.max_disp);
    pen_v.init(w + cx.max_disp);
  }
  const bool adaptive = cx.adaptive;
  bool started = false;  // a row of the vertical paths exists

  for (int i = 0; i < h; ++i) {
    const int y = dy == 1 ? i : h - 1 - i;
    const float* crow = cx.cost + static_cast<size_t>(y) * row_len;
    const int32_t* orow = cx.off + static_cast<size_t>(y) * w;
    const float* lrow = cx.left + static_cast<size_t>(y) * w;

    // horizontal path over the real columns [c0, c1), every row; 0 elsewhere
    for (int x = 0; x < w; ++x)
      if (x < cx.c0 || x >= cx.c1) std::fill(sum.at(x), sum.at(x) + k, 0.f);
    if (cx.c1 > cx.c0) {
      if (adaptive) pen_h.fill(cx, y, 0, dx, cx.pen[0]);
      float m = 0.f;
      int op = 0;
      for (int t = 0; t < cx.c1 - cx.c0; ++t) {
        const int x = dx == 1 ? cx.c0 + t : cx.c1 - 1 - t;
        const float* c = crow + static_cast<size_t>(x) * k;
        float* o = sum.at(x);
        const int xo = orow[x];
        float nm;
        if (t == 0) {
          nm = fresh(c, o, k);
        } else {
          const int xp = x - dx;
          const int bl = big_step(lrow[x], lrow[xp], cx.thr);
          const int s = band_shift(cx, xo, op);
          const int at = w - 1 - x + xo;
          const float* pv = ext.pred(sum.at(xp), s);
          if (adaptive)
            nm = step(pv, s, m, c, o, k, pen_h.p1[bl].data() + at, pen_h.p2[bl].data() + at, 0.f, 0.f);
          else
            nm = step(pv, s, m, c, o, k, nullptr, nullptr, cx.pen[0].p1[0], cx.pen[0].p2[0]);
        }
        m = nm;
        op = xo;
      }
    }

    // the vertical (and diagonal) paths over the real rows [r0, r1), every column
    if (y >= cx.r0 && y < cx.r1) {
      const bool first = !started;
      const int yp = y - dy;
      const bool yp_in = yp >= 0 && yp < h;
      const float* lprev = cx.left + static_cast<size_t>(yp_in ? yp : y) * w;
      if (adaptive) pen_v.fill(cx, y, dy, 0, cx.pen[1]);
      for (int p = 0; p < n_row_paths; ++p) {
        const int sx = p == 0 ? 0 : (p == 1 ? 1 : -1);  // the predecessor of x is x - sx
        const Pen& pen = p == 0 ? cx.pen[1] : cx.pen[2];
        Line& ln = line[p];
        Line& src = p == 0 ? vprev : ln;
        // in place: a diagonal from the left (sx = 1) runs right to left, so that x - 1 still
        // holds the previous row when x reads it; from the right, left to right
        for (int t = 0; t < w; ++t) {
          const int x = sx == 1 ? w - 1 - t : t;
          const float* c = crow + static_cast<size_t>(x) * k;
          float* o = ln.at(x);
          const int xo = orow[x];
          const int xp = x - sx;
          float nm;
          // a fresh start: the first row, a diagonal predecessor outside the real columns
          if (first || (sx != 0 && (xp < cx.c0 || xp >= cx.c1 || xp < 0 || xp >= w))) {
            nm = fresh(c, o, k);
          } else {
            const int bl = yp_in && big_step(lrow[x], lprev[xp], cx.thr);
            const int s = band_shift(cx, xo, src.offs[xp]);
            const float* pv = ext.pred(src.at(xp), s);
            const float pm = src.mins[xp];
            if (sx == 0 && adaptive) {
              const int at = w - 1 - x + xo;
              nm = step(pv, s, pm, c, o, k, pen_v.p1[bl].data() + at, pen_v.p2[bl].data() + at, 0.f, 0.f);
            } else {
              const int b = adaptive ? bl : 0;  // diagonals count the left image's step only
              nm = step(pv, s, pm, c, o, k, nullptr, nullptr, pen.p1[b], pen.p2[b]);
            }
          }
          ln.mins[x] = nm;
          ln.offs[x] = xo;
          float* __restrict sm = sum.at(x);
          for (int j = 0; j < k; ++j) sm[j] += o[j];
        }
      }
      line[0].swap(vprev);
      started = true;
    }

    // meet the other sweep's row in the output
    float* orow_out = cx.out + static_cast<size_t>(y) * row_len;
    std::lock_guard<std::mutex> lock(merge.locks[y]);
    if (!merge.seen[y]) {
      for (int x = 0; x < w; ++x) std::memcpy(orow_out + static_cast<size_t>(x) * k, sum.at(x), k * sizeof(float));
      merge.seen[y] = 1;
    } else {
      const float dirs = static_cast<float>(cx.dirs);
      for (int x = 0; x < w; ++x) {
        const float* __restrict sm = sum.at(x);
        float* __restrict dst = orow_out + static_cast<size_t>(x) * k;
        for (int j = 0; j < k; ++j) dst[j] = (dst[j] + sm[j]) / dirs;
      }
    }
  }
}

// The band width of the shipped chains (48) compiled as a constant (fixed trip counts, no
// remainder loops); any other K at run time.
SJ_CLONES void sweep(const Ctx& cx, int dy, Merge& merge) {
  if (cx.k == 48)
    sweep_k<48>(cx, dy, merge);
  else
    sweep_k<0>(cx, dy, merge);
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
