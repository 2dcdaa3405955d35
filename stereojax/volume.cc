// The floor of the native kernels' memory traffic: a copy of a cost volume on all threads
// (reads one volume, writes one, as SGM and CBCA must at least). `stereojax bench` times it with
// the chain's own volume beside the kernels (volume.py: copy_native).
#include <cstring>

#include "native_common.h"

namespace stereojax {
namespace {

ffi::Error CopyImpl(ffi::Buffer<ffi::F32> vol, ffi::ResultBuffer<ffi::F32> out, int32_t threads) {
  int h, w, k;
  dims3(vol, h, w, k);
  const size_t row = static_cast<size_t>(w) * k;
  const float* src = vol.typed_data();
  float* dst = out->typed_data();
  parallel_for(h, threads, [&](int y0, int y1) {
    std::memcpy(dst + y0 * row, src + y0 * row, static_cast<size_t>(y1 - y0) * row * sizeof(float));
  });
  return ffi::Error::Success();
}

}  // namespace
}  // namespace stereojax

SJ_EXPORT(StereojaxCopy);
XLA_FFI_DEFINE_HANDLER_SYMBOL(StereojaxCopy, stereojax::CopyImpl,
                              xla::ffi::Ffi::Bind()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F32>>()  // volume [H, W, K]
                                  .Ret<xla::ffi::Buffer<xla::ffi::F32>>()  // its copy
                                  .Attr<int32_t>("threads"));
