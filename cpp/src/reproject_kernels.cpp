// Per-row reprojection loops. Compiled once per instruction set (STEREODEPTH_ISA_NS);
// everything here stays inside that namespace (see dispatch.hpp).
#include "reproject_kernels.hpp"

#include <cmath>
#include <cstdint>
#include <limits>
#include <type_traits>

#ifndef STEREODEPTH_ISA_NS
#error "STEREODEPTH_ISA_NS must name the instruction set this file is compiled for"
#endif

namespace stereodepth::detail::STEREODEPTH_ISA_NS {
namespace {

constexpr float kFloatMax = std::numeric_limits<float>::max();

// Float64 arithmetic, one rounding per operation, in the order stated in reproject.hpp.
// Branch-free so that the loop vectorises.
template <typename In>
void row(const void* vin, float* __restrict out, std::ptrdiff_t n_, const ReprojectRowParams& p) {
  const In* __restrict in = static_cast<const In*>(vin);
  const int n = static_cast<int>(n_);  // int: its conversion to double vectorises everywhere
  const double q00 = p.q00, q02 = p.q02, q10 = p.q10, q12 = p.q12;
  const double q20 = p.q20, q22 = p.q22, q30 = p.q30, q32 = p.q32;
  const double rx = p.row_x, ry = p.row_y, rz = p.row_z, rw = p.row_w, scale = p.scale;
  const float zmin = p.zmin, zmax = p.zmax;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const bool has_invalid = p.has_invalid, has_below = p.has_below;
  const double below = p.below;
  // Raw values are compared with invalid_value in float32 (float64 for float64 input), as
  // disparity_to_depth does.
  using Cmp = std::conditional_t<std::is_same_v<In, double>, double, float>;
  const Cmp invalid = static_cast<Cmp>(p.invalid);
  for (int i = 0; i < n; ++i) {
    const double raw = static_cast<double>(in[i]);
    const double x = static_cast<double>(i);
    const double d = raw * scale;
    const double w = (q30 * x + q32 * d) + rw;
    const double iw = 1.0 / w;
    const float px = static_cast<float>(((q00 * x + q02 * d) + rx) * iw);
    const float py = static_cast<float>(((q10 * x + q12 * d) + ry) * iw);
    const float pz = static_cast<float>(((q20 * x + q22 * d) + rz) * iw);
    // Finite as |v| <= FLT_MAX, which is false for NaN.
    const bool ok = (std::fabs(px) <= kFloatMax) & (std::fabs(py) <= kFloatMax) &
                    (pz > 0.0f) & (pz >= zmin) & (pz <= zmax) &
                    (!has_invalid | (static_cast<Cmp>(in[i]) != invalid)) &
                    (!has_below | (raw >= below));
    out[3 * i + 0] = ok ? px : nan;
    out[3 * i + 1] = ok ? py : nan;
    out[3 * i + 2] = ok ? pz : nan;
  }
}

}  // namespace

const ReprojectKernels& reproject_kernels() {
  static const ReprojectKernels kernels = {{
      &row<float>,
      &row<double>,
      &row<std::int16_t>,
      &row<std::uint16_t>,
  }};
  return kernels;
}

}  // namespace stereodepth::detail::STEREODEPTH_ISA_NS
