// Native learned head at candidate disparities: the kernel of learned.py's head_at (the dense
// head after its split first layer), held equal to it by tests/matching_cost/test_head_native.py
// (to float rounding: the sums run in another order than XLA's matmuls).
//
// For every pixel (y, x) and each of its K candidates d:
//   h1 = relu(A(y, x) + B(y, max(x - d, 0)))     A = fl @ first_left + bias, B = fr @ first_right
//   h  = relu(h @ W_l + b_l)                      for the hidden layers
//   cost = 1 - sigmoid(h @ w_out + b_out)
// A row's projections A and B are made once per row (per thread, no image-sized scratch); the
// candidates of a row then go through the layers in tiles of kTile (pixel, candidate) pairs, each
// layer a small matrix product in register blocks of 4 rows x 16 outputs (two 8-float vectors). Rows run on all threads.
#include <algorithm>
#include <cmath>
#include <vector>

#include "../native_common.h"

namespace stereojax {
namespace {

constexpr int kTile = 64;  // (pixel, candidate) pairs per tile, a multiple of 4

// Eight floats as one value (GCC / Clang vector extension: portable, lowered to AVX / AVX-512 or
// SSE / NEON halves by each clone), loaded and stored unaligned.
typedef float v8 __attribute__((vector_size(32)));
SJ_INLINE v8 load8(const float* p) {
  v8 v;
  __builtin_memcpy(&v, p, sizeof(v));
  return v;
}
SJ_INLINE void store8(float* p, v8 v) { __builtin_memcpy(p, &v, sizeof(v)); }

// out[t][co] = act(in[t][ci] @ w[ci][co] + b[co]) for t rows (t % 4 == 0): blocks of 4 rows x 16
// outputs held in eight vector accumulators while the ci inputs stream by.
template <bool RELU>
SJ_INLINE void dense(const float* __restrict in, int ci, const float* __restrict w, const float* __restrict b,
                     int co, float* __restrict out, int t) {
  const v8 zero = {0, 0, 0, 0, 0, 0, 0, 0};
  int o0 = 0;
  for (; o0 + 16 <= co; o0 += 16) {
    const v8 b0 = load8(b + o0), b1 = load8(b + o0 + 8);
    for (int r0 = 0; r0 < t; r0 += 4) {
      v8 a00 = b0, a01 = b1, a10 = b0, a11 = b1, a20 = b0, a21 = b1, a30 = b0, a31 = b1;
      const float* x0 = in + static_cast<size_t>(r0) * ci;
      const float* x1 = x0 + ci;
      const float* x2 = x1 + ci;
      const float* x3 = x2 + ci;
      for (int i = 0; i < ci; ++i) {
        const float* wr = w + static_cast<size_t>(i) * co + o0;
        const v8 w0 = load8(wr), w1 = load8(wr + 8);
        const v8 h0 = zero + x0[i], h1 = zero + x1[i], h2 = zero + x2[i], h3 = zero + x3[i];
        a00 += h0 * w0;
        a01 += h0 * w1;
        a10 += h1 * w0;
        a11 += h1 * w1;
        a20 += h2 * w0;
        a21 += h2 * w1;
        a30 += h3 * w0;
        a31 += h3 * w1;
      }
      if (RELU) {
        a00 = a00 > zero ? a00 : zero;
        a01 = a01 > zero ? a01 : zero;
        a10 = a10 > zero ? a10 : zero;
        a11 = a11 > zero ? a11 : zero;
        a20 = a20 > zero ? a20 : zero;
        a21 = a21 > zero ? a21 : zero;
        a30 = a30 > zero ? a30 : zero;
        a31 = a31 > zero ? a31 : zero;
      }
      float* d = out + static_cast<size_t>(r0) * co + o0;
      store8(d, a00);
      store8(d + 8, a01);
      store8(d + co, a10);
      store8(d + co + 8, a11);
      store8(d + 2 * co, a20);
      store8(d + 2 * co + 8, a21);
      store8(d + 3 * co, a30);
      store8(d + 3 * co + 8, a31);
    }
  }
  for (; o0 < co; ++o0) {  // widths that are not a multiple of 16, and the output unit
    for (int r = 0; r < t; ++r) {
      const float* x = in + static_cast<size_t>(r) * ci;
      float s = b[o0];
      for (int i = 0; i < ci; ++i) s += x[i] * w[static_cast<size_t>(i) * co + o0];
      out[static_cast<size_t>(r) * co + o0] = RELU ? (s > 0.f ? s : 0.f) : s;
    }
  }
}

struct Net {
  int f;                     // tower features
  std::vector<int> widths;   // C1, hidden widths..., 1
  const float *wl, *bl, *wr;  // first layer: left kernel [F, C1], its bias, right kernel [F, C1]
  std::vector<const float*> w, b;  // the later layers (hidden..., out): kernel [Cin, Cout], bias
};

// vol (optional): the band volume [H, W, size] the costs go into as well, `fill` everywhere else,
// entry cand - off(y, x) of each pixel (candidates outside [0, size) are dropped, as JAX drops them)
struct Band {
  const int32_t* off = nullptr;
  float* vol = nullptr;
  int size = 0;
  float fill = 1.f;
};

SJ_CLONES void head_rows(const Net& net, const float* fl, const float* fr, const int32_t* cand, float* cost, int w,
                         int k, const Band& band, int y0, int y1) {
  const int c1 = net.widths[0];
  int widest = 0;
  for (int c : net.widths) widest = std::max(widest, c);
  std::vector<float> a(static_cast<size_t>(w) * c1), bproj(static_cast<size_t>(w) * c1);
  const size_t tile_len = std::max(static_cast<size_t>(kTile) * widest, static_cast<size_t>(4) * net.f);
  std::vector<float> t0(tile_len), t1(tile_len);
  std::vector<float> zero(c1, 0.f);
  const int n_later = static_cast<int>(net.w.size());
  const int pairs = w * k;
  for (int y = y0; y < y1; ++y) {
    const float* flr = fl + static_cast<size_t>(y) * w * net.f;
    const float* frr = fr + static_cast<size_t>(y) * w * net.f;
    dense<false>(flr, net.f, net.wl, net.bl, c1, a.data(), w & ~3);
    dense<false>(frr, net.f, net.wr, zero.data(), c1, bproj.data(), w & ~3);
    if (w & 3) {  // the last w % 4 pixels, through a padded tile
      const int r0 = w & ~3, rest = w - r0;
      std::fill(t0.begin(), t0.begin() + 4 * net.f, 0.f);
      std::copy(flr + static_cast<size_t>(r0) * net.f, flr + static_cast<size_t>(w) * net.f, t0.begin());
      dense<false>(t0.data(), net.f, net.wl, net.bl, c1, t1.data(), 4);
      std::copy(t1.begin(), t1.begin() + rest * c1, a.begin() + static_cast<size_t>(r0) * c1);
      std::copy(frr + static_cast<size_t>(r0) * net.f, frr + static_cast<size_t>(w) * net.f, t0.begin());
      dense<false>(t0.data(), net.f, net.wr, zero.data(), c1, t1.data(), 4);
      std::copy(t1.begin(), t1.begin() + rest * c1, bproj.begin() + static_cast<size_t>(r0) * c1);
    }
    const int32_t* crow = cand + static_cast<size_t>(y) * w * k;
    float* orow = cost + static_cast<size_t>(y) * w * k;
    for (int p0 = 0; p0 < pairs; p0 += kTile) {
      const int n = std::min(kTile, pairs - p0);
      const int t = (n + 3) & ~3;
      for (int i = 0; i < t; ++i) {  // h1 of each pair (the padding rows: the tile's first pair)
        const int p = p0 + (i < n ? i : 0);
        const int x = p / k;
        const int xr = std::max(x - crow[p], 0);
        const float* __restrict pa = a.data() + static_cast<size_t>(x) * c1;
        const float* __restrict pb = bproj.data() + static_cast<size_t>(xr) * c1;
        float* __restrict h = t0.data() + static_cast<size_t>(i) * c1;
        for (int c = 0; c < c1; ++c) {
          const float v = pa[c] + pb[c];
          h[c] = v > 0.f ? v : 0.f;
        }
      }
      float* src = t0.data();
      float* dst = t1.data();
      for (int l = 0; l < n_later; ++l) {
        const int ci = net.widths[l], co = net.widths[l + 1];
        if (l + 1 < n_later)
          dense<true>(src, ci, net.w[l], net.b[l], co, dst, t);
        else
          dense<false>(src, ci, net.w[l], net.b[l], co, dst, t);
        std::swap(src, dst);
      }
      for (int i = 0; i < n; ++i) orow[p0 + i] = 1.f - 1.f / (1.f + std::exp(-src[i]));
    }
    if (band.vol) {
      float* vrow = band.vol + static_cast<size_t>(y) * w * band.size;
      std::fill(vrow, vrow + static_cast<size_t>(w) * band.size, band.fill);
      const int32_t* orow_off = band.off + static_cast<size_t>(y) * w;
      for (int x = 0; x < w; ++x)
        for (int j = 0; j < k; ++j) {
          const int e = crow[x * k + j] - orow_off[x];
          if (e >= 0 && e < band.size) vrow[static_cast<size_t>(x) * band.size + e] = orow[x * k + j];
        }
    }
  }
}

// The network's layout from the packed parameters (head_params in learned.py); an error message
// or nullptr.
const char* parse_net(Net& net, int f, ffi::Span<const int32_t> widths, const ffi::Buffer<ffi::F32>& params) {
  if (widths.size() < 2 || widths.back() != 1) return "head: widths must end in 1";
  net.f = f;
  net.widths.assign(widths.begin(), widths.end());
  const float* p = params.typed_data();
  const int c1 = net.widths[0];
  net.wl = p;
  p += static_cast<size_t>(f) * c1;
  net.bl = p;
  p += c1;
  net.wr = p;
  p += static_cast<size_t>(f) * c1;
  for (size_t l = 0; l + 1 < net.widths.size(); ++l) {
    net.w.push_back(p);
    p += static_cast<size_t>(net.widths[l]) * net.widths[l + 1];
    net.b.push_back(p);
    p += net.widths[l + 1];
  }
  if (p - params.typed_data() != static_cast<ptrdiff_t>(params.element_count()))
    return "head: the parameters do not match the widths";
  return nullptr;
}

ffi::Error run_head(ffi::Buffer<ffi::F32> fl, ffi::Buffer<ffi::F32> fr, ffi::Buffer<ffi::S32> cand,
                    ffi::Buffer<ffi::F32> params, float* cost, ffi::Span<const int32_t> widths, int32_t threads,
                    const Band& band) {
  int h, w, f, hc, wc, k;
  dims3(fl, h, w, f);
  dims3(cand, hc, wc, k);
  if (hc != h || wc != w) return ffi::Error::InvalidArgument("head: candidates and features differ in size");
  Net net;
  if (const char* err = parse_net(net, f, widths, params)) return ffi::Error::InvalidArgument(err);
  const float* pl = fl.typed_data();
  const float* pr = fr.typed_data();
  const int32_t* pc = cand.typed_data();
  parallel_for(h, threads, [&](int y0, int y1) { head_rows(net, pl, pr, pc, cost, w, k, band, y0, y1); });
  return ffi::Error::Success();
}

ffi::Error HeadImpl(ffi::Buffer<ffi::F32> fl, ffi::Buffer<ffi::F32> fr, ffi::Buffer<ffi::S32> cand,
                    ffi::Buffer<ffi::F32> params, ffi::ResultBuffer<ffi::F32> out, ffi::Span<const int32_t> widths,
                    int32_t threads) {
  return run_head(fl, fr, cand, params, out->typed_data(), widths, threads, Band{});
}

// The same, and the band volume the costs go into (learned.ranked_dense_cost's scatter).
ffi::Error HeadBandImpl(ffi::Buffer<ffi::F32> fl, ffi::Buffer<ffi::F32> fr, ffi::Buffer<ffi::S32> cand,
                        ffi::Buffer<ffi::F32> params, ffi::Buffer<ffi::S32> offset, ffi::ResultBuffer<ffi::F32> out,
                        ffi::ResultBuffer<ffi::F32> vol, ffi::Span<const int32_t> widths, float fill,
                        int32_t threads) {
  int hv, wv, size;
  dims3(*vol, hv, wv, size);
  Band band;
  band.off = offset.typed_data();
  band.vol = vol->typed_data();
  band.size = size;
  band.fill = fill;
  return run_head(fl, fr, cand, params, out->typed_data(), widths, threads, band);
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxHead);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxHead, stereojax::HeadImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // left features [H, W, F]
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // right features [H, W, F]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // candidates [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // the head's parameters, packed
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // cost 1 - s [H, W, K]
                                  .Attr<xla::ffi::Span<const int32_t>>("widths")
                                  .Attr<int32_t>("threads"));

SJ_EXPORT(StereojaxHeadBand);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxHeadBand, stereojax::HeadBandImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // left features [H, W, F]
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // right features [H, W, F]
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // candidates [H, W, K]
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // the head's parameters, packed
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()  // band offsets [H, W] (0: full range)
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // cost 1 - s [H, W, K]
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // band volume [H, W, size]
                                  .Attr<xla::ffi::Span<const int32_t>>("widths")
                                  .Attr<float>("fill")
                                  .Attr<int32_t>("threads"));
