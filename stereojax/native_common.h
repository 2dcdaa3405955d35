// Shared by the native kernels (stereojax/kernels.py loads them): the sentinel, the
// runtime-dispatched clones, and a minimal parallel-for over std::thread.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <thread>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace stereojax {

namespace ffi = xla::ffi;

// stereojax.volume.BIG: the cost of an entry outside a band, as f32
constexpr float kBig = 1e9f;

// The hot functions are compiled for AVX-512, AVX2 (with POPCNT) and the baseline of the target, and the
// loader picks one at run time (GCC/Clang ifunc); elsewhere (aarch64, other compilers) one
// portable build that the compiler vectorises for the baseline.
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && !defined(STEREOJAX_NO_CLONES) && \
    !defined(STEREOJAX_MARCH_NATIVE)
#if defined(__clang__)
#define SJ_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else  // GCC: the x86-64 levels (v3: AVX2, FMA, BMI2, POPCNT; v4: AVX-512)
#define SJ_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#endif
#else
#define SJ_CLONES
#endif
#define SJ_INLINE inline __attribute__((always_inline))
// the one symbol of a kernel that the library exports (the build hides all others)
#define SJ_EXPORT(name) extern "C" __attribute__((visibility("default"))) XLA_FFI_Error* name(XLA_FFI_CallFrame*)

// fn(begin, end) over [0, n) cut into `threads` contiguous chunks, one per thread (the calling
// thread takes the first).
template <class F>
void parallel_for(int n, int threads, F&& fn) {
  threads = std::max(1, std::min(threads, n));
  if (threads == 1) {
    fn(0, n);
    return;
  }
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int t = 1; t < threads; ++t) {
    int b = static_cast<int>(static_cast<long>(n) * t / threads);
    int e = static_cast<int>(static_cast<long>(n) * (t + 1) / threads);
    pool.emplace_back([&fn, b, e] { fn(b, e); });
  }
  fn(0, static_cast<int>(static_cast<long>(n) / threads));
  for (auto& th : pool) th.join();
}

// The dimensions of a buffer as (H, W, K) for a rank-3 buffer, (H, W, 1) for rank 2.
template <class B>
void dims3(const B& buf, int& h, int& w, int& k) {
  auto d = buf.dimensions();
  h = static_cast<int>(d[0]);
  w = d.size() > 1 ? static_cast<int>(d[1]) : 1;
  k = d.size() > 2 ? static_cast<int>(d[2]) : 1;
}

}  // namespace stereojax
