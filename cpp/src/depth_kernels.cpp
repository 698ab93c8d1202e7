// Per-row disparity-to-depth loops. Compiled once per instruction set (STEREODEPTH_ISA_NS);
// everything here stays inside that namespace (see dispatch.hpp).
#include "depth_kernels.hpp"

#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>

#ifndef STEREODEPTH_ISA_NS
#error "STEREODEPTH_ISA_NS must name the instruction set this file is compiled for"
#endif

namespace stereodepth::detail::STEREODEPTH_ISA_NS {
namespace {

// IEEE binary16 bits to float, exactly (normals, subnormals, infinities and NaN).
inline float half_to_float(std::uint16_t h) {
  const std::uint32_t sign = static_cast<std::uint32_t>(h & 0x8000u) << 16;
  const std::uint32_t rest = static_cast<std::uint32_t>(h & 0x7fffu);
  std::uint32_t bits;
  float f;
  if (rest >= 0x7c00u) {  // infinity or NaN
    bits = sign | 0x7f800000u | ((rest & 0x03ffu) << 13);
    std::memcpy(&f, &bits, sizeof f);
    return f;
  }
  bits = rest << 13;  // exponent and mantissa in float position, exponent bias still 15
  std::memcpy(&f, &bits, sizeof f);
  f *= 0x1p112f;      // rebias by 2^(127-15): exact for normals and subnormals alike
  std::memcpy(&bits, &f, sizeof f);
  bits |= sign;
  std::memcpy(&f, &bits, sizeof f);
  return f;
}

struct Half {};  // tag for float16 input stored as raw bits

// Float32 output, float32 arithmetic (float16, float32, int16, uint16 input).
constexpr float kInfF = std::numeric_limits<float>::infinity();
constexpr double kInf = std::numeric_limits<double>::infinity();

template <typename Tag, typename In>
void row_to_f32(const void* vin, float* out, std::ptrdiff_t n, const DepthRowParams& p) {
  const In* in = static_cast<const In*>(vin);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float k = p.k_f, scale = p.scale_f, doffs = p.doffs_f, zmin = p.min_f, zmax = p.max_f;
  const float invalid = p.invalid_f, below = p.below_f;
  const bool has_invalid = p.has_invalid, has_below = p.has_below;
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    float d;
    if constexpr (std::is_same_v<Tag, Half>) {
      d = half_to_float(in[i]);
    } else {
      d = static_cast<float>(in[i]);
    }
    const float den = d * scale + doffs;
    const float z = k / den;
    // An infinite disparity (den = inf) is no match: its depth 0 would read as valid.
    bool ok = (den > 0.0f) & (den < kInfF) & (z >= zmin) & (z <= zmax);
    if (has_invalid) ok &= (d != invalid);
    if (has_below) ok &= (d >= below);
    out[i] = ok ? z : nan;
  }
}

// Float32 output from float64 input: float64 arithmetic, rounded once at the end.
void row_f64_to_f32(const void* vin, float* out, std::ptrdiff_t n, const DepthRowParams& p) {
  const double* in = static_cast<const double*>(vin);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    const double d = in[i];
    const double den = d * p.scale + p.doffs;
    const double z = p.k / den;
    const float zf = static_cast<float>(z);
    bool ok = (den > 0.0) & (den < kInf) & (zf >= p.min_f) & (zf <= p.max_f);
    if (p.has_invalid) ok &= (d != p.invalid);
    if (p.has_below) ok &= (d >= p.below);
    out[i] = ok ? zf : nan;
  }
}

// Uint16 millimetres, float64 arithmetic for every input type.
template <typename Tag, typename In>
void row_to_u16(const void* vin, std::uint16_t* out, std::ptrdiff_t n,
                const DepthRowParams& p) {
  const In* in = static_cast<const In*>(vin);
  for (std::ptrdiff_t i = 0; i < n; ++i) {
    double d;
    if constexpr (std::is_same_v<Tag, Half>) {
      d = static_cast<double>(half_to_float(in[i]));
    } else {
      d = static_cast<double>(in[i]);
    }
    const double den = d * p.scale + p.doffs;
    const double z = p.k / den;
    bool ok = (den > 0.0) & (den < kInf) & (z >= p.min) & (z <= p.max);
    if (p.has_invalid) ok &= (d != p.invalid);
    if (p.has_below) ok &= (d >= p.below);
    // Round half to even (the default rounding mode), clamp to the format's valid range:
    // 65535 for 65.535 m and farther, 1 for 1 mm and nearer (0.5 mm or less rounded to 0,
    // which the format reads as "no depth": a valid pixel became a hole).
    double mm = std::nearbyint(z * 1000.0);
    mm = mm < 65535.0 ? mm : 65535.0;
    mm = mm > 1.0 ? mm : 1.0;
    out[i] = ok ? static_cast<std::uint16_t>(mm) : std::uint16_t{0};
  }
}

}  // namespace

const DepthKernels& depth_kernels() {
  static const DepthKernels kernels = {
      {
          &row_to_f32<Half, std::uint16_t>,
          &row_to_f32<float, float>,
          &row_f64_to_f32,
          &row_to_f32<std::int16_t, std::int16_t>,
          &row_to_f32<std::uint16_t, std::uint16_t>,
      },
      {
          &row_to_u16<Half, std::uint16_t>,
          &row_to_u16<float, float>,
          &row_to_u16<double, double>,
          &row_to_u16<std::int16_t, std::int16_t>,
          &row_to_u16<std::uint16_t, std::uint16_t>,
      },
  };
  return kernels;
}

}  // namespace stereodepth::detail::STEREODEPTH_ISA_NS
