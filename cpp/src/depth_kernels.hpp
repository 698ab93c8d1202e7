// Internal: the per-row disparity-to-depth kernels, compiled once per instruction set.
#pragma once

#include <cstddef>
#include <cstdint>

#include "stereodepth/depth.hpp"

namespace stereodepth::detail {

// DepthParams pre-converted for the inner loop, in both working precisions.
struct DepthRowParams {
  float k_f, scale_f, doffs_f, min_f, max_f, invalid_f, below_f;
  double k, scale, doffs, min, max, invalid, below;
  bool has_invalid, has_below;
};

using DepthRowToF32 = void (*)(const void* in, float* out, std::ptrdiff_t n,
                               const DepthRowParams& p);
using DepthRowToU16 = void (*)(const void* in, std::uint16_t* out, std::ptrdiff_t n,
                               const DepthRowParams& p);

// One entry per DisparityType, in enum order.
struct DepthKernels {
  DepthRowToF32 to_f32[5];
  DepthRowToU16 to_u16[5];
};

#define STEREODEPTH_DECLARE_DEPTH_KERNELS(ns) \
  namespace ns {                              \
  const DepthKernels& depth_kernels();        \
  }
STEREODEPTH_DECLARE_DEPTH_KERNELS(baseline)
STEREODEPTH_DECLARE_DEPTH_KERNELS(avx2)
STEREODEPTH_DECLARE_DEPTH_KERNELS(avx512)
#undef STEREODEPTH_DECLARE_DEPTH_KERNELS

}  // namespace stereodepth::detail
