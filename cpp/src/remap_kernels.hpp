// Internal: the per-row remap kernels, compiled once per instruction set.
#pragma once

#include <cstddef>
#include <cstdint>

#include "stereodepth/remap.hpp"

namespace stereodepth::detail {

struct RemapRowArgs {
  const std::uint8_t* src;
  std::ptrdiff_t src_rows, src_cols, src_stride;  // stride in bytes
  const std::int16_t* xy;                          // this output row's entries (kFixed)
  const std::uint32_t* frac;
  const float* pos;                                // this output row's x, y pairs (kFloat)
  // The xy or pos entries of a row kRemapAhead rows further down (this row's own in the last
  // rows): the kernels prefetch the source lines it will read.
  const std::int16_t* xy_ahead;
  const float* pos_ahead;
  std::ptrdiff_t n;                                // output pixels in the row
  void* dst;
};

// How many output rows ahead the kernels prefetch their source lines.
inline constexpr std::ptrdiff_t kRemapAhead = 2;

using RemapRow = void (*)(const RemapRowArgs& args);

// One entry per PixelFormat, in enum order: grey8, grey16, rgb8.
struct RemapKernels {
  RemapRow rows[3];
};

#define STEREODEPTH_DECLARE_REMAP_KERNELS(ns) \
  namespace ns {                              \
  const RemapKernels& remap_kernels();        \
  }
STEREODEPTH_DECLARE_REMAP_KERNELS(baseline)
STEREODEPTH_DECLARE_REMAP_KERNELS(avx2)
STEREODEPTH_DECLARE_REMAP_KERNELS(avx512)
#undef STEREODEPTH_DECLARE_REMAP_KERNELS

}  // namespace stereodepth::detail
