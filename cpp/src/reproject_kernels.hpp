// Internal: the per-row reprojection kernels, compiled once per instruction set.
#pragma once

#include <cstddef>

#include "stereodepth/reproject.hpp"

namespace stereodepth::detail {

// ReprojectParams pre-converted for the inner loop, plus the row's constants
// q_i1 * y + q_i3 for the four rows of Q.
struct ReprojectRowParams {
  double q00, q02, q10, q12, q20, q22, q30, q32;
  double row_x, row_y, row_z, row_w;
  double scale, invalid, below;
  float zmin, zmax;
  bool has_invalid, has_below;
};

using ReprojectRow = void (*)(const void* in, float* out, std::ptrdiff_t n,
                              const ReprojectRowParams& p);

// One entry per input type: float32, float64, int16, uint16.
struct ReprojectKernels {
  ReprojectRow rows[4];
};

#define STEREODEPTH_DECLARE_REPROJECT_KERNELS(ns) \
  namespace ns {                                  \
  const ReprojectKernels& reproject_kernels();    \
  }
STEREODEPTH_DECLARE_REPROJECT_KERNELS(baseline)
STEREODEPTH_DECLARE_REPROJECT_KERNELS(avx2)
STEREODEPTH_DECLARE_REPROJECT_KERNELS(avx512)
#undef STEREODEPTH_DECLARE_REPROJECT_KERNELS

}  // namespace stereodepth::detail
