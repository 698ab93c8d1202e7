#include "stereodepth/reproject.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

#include "module_support.hpp"
#include "reproject_kernels.hpp"
#include "stereodepth/parallel.hpp"

namespace stereodepth {
namespace {

const detail::ReprojectKernels& kernels_for(Isa isa) {
  return STEREODEPTH_KERNELS_FOR(isa, reproject_kernels);
}

using detail::fail;

int kernel_index(DisparityType type) {
  switch (type) {
    case DisparityType::kFloat32:
      return 0;
    case DisparityType::kFloat64:
      return 1;
    case DisparityType::kInt16:
      return 2;
    case DisparityType::kUint16:
      return 3;
    case DisparityType::kFloat16:
      break;
  }
  throw std::invalid_argument("reproject reads float32, float64, int16 or uint16 disparity");
}

}  // namespace

void validate(const ReprojectParams& p) {
  for (double v : p.q) {
    if (!std::isfinite(v)) fail("Q must be finite", v);
  }
  if (!(std::isfinite(p.scale) && p.scale > 0)) fail("scale must be finite and > 0", p.scale);
  if (!(std::isfinite(p.min_depth) && p.min_depth >= 0)) {
    fail("min_depth must be finite and >= 0", p.min_depth);
  }
  if (!(p.max_depth > 0)) fail("max_depth must be > 0", p.max_depth);
  if (!(p.max_depth >= p.min_depth)) fail("max_depth must be >= min_depth", p.max_depth);
  if (p.has_invalid_below && std::isnan(p.invalid_below)) {
    fail("invalid_below must not be NaN", p.invalid_below);
  }
}

void reproject(const DisparityStack& in, const StackView<float>& out,
               const ReprojectParams& params, int threads, Isa isa) {
  validate(params);
  if (in.frames < 0 || in.rows < 0 || in.cols < 0) {
    throw std::invalid_argument("disparity has a negative dimension");
  }
  if (out.frames != in.frames || out.rows != in.rows || out.cols != 3 * in.cols) {
    throw std::invalid_argument("out must have the shape of disparity plus an axis of 3");
  }
  if (in.cols > std::numeric_limits<int>::max() / 3) {
    throw std::invalid_argument("disparity has too many columns");
  }
  const detail::ReprojectRow kernel = kernels_for(isa).rows[kernel_index(in.type)];
  if (in.frames == 0 || in.rows == 0 || in.cols == 0) return;

  const double* q = params.q;
  detail::ReprojectRowParams base{};
  base.q00 = q[0];
  base.q02 = q[2];
  base.q10 = q[4];
  base.q12 = q[6];
  base.q20 = q[8];
  base.q22 = q[10];
  base.q30 = q[12];
  base.q32 = q[14];
  base.scale = params.scale;
  base.invalid = params.invalid_value;
  base.zmin = static_cast<float>(params.min_depth);
  base.zmax = static_cast<float>(params.max_depth);
  base.has_invalid = params.has_invalid_value;
  base.below = params.invalid_below;
  base.has_below = params.has_invalid_below;

  static constexpr std::ptrdiff_t kSize[] = {2, 4, 8, 2, 2};  // by DisparityType
  const std::ptrdiff_t elem = kSize[static_cast<int>(in.type)];
  // Rows per band: enough that starting a thread (tens of microseconds) is worth it.
  const std::ptrdiff_t min_rows =
      std::max<std::ptrdiff_t>(1, (1 << 14) / std::max<std::ptrdiff_t>(in.cols, 1));
  parallel_for_rows(
      in.frames * in.rows, resolve_threads(threads), min_rows,
      [&](std::ptrdiff_t begin, std::ptrdiff_t end) {
        detail::ReprojectRowParams p = base;
        for (std::ptrdiff_t i = begin; i < end; ++i) {
          const std::ptrdiff_t f = i / in.rows, r = i % in.rows;
          const char* src = static_cast<const char*>(in.data) +
                            (f * in.frame_stride + r * in.row_stride) * elem;
          const double y = static_cast<double>(r);
          p.row_x = q[1] * y + q[3];
          p.row_y = q[5] * y + q[7];
          p.row_z = q[9] * y + q[11];
          p.row_w = q[13] * y + q[15];
          kernel(src, out.row(i), in.cols, p);
        }
      });
}

}  // namespace stereodepth
