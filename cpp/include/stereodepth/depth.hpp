// Disparity to depth: Z = focal_px * baseline_m / (d * scale + doffs_px).
#pragma once

#include <cstdint>
#include <limits>

#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth {

struct DepthParams {
  double focal_px = 0.0;    // > 0
  double baseline_m = 0.0;  // > 0
  double doffs_px = 0.0;    // principal point offset between the cameras, in pixels
  double scale = 1.0;       // disparity in pixels = raw value * scale
  // Depths outside [min_depth_m, max_depth_m] are invalid. The default maximum is the
  // largest finite float, so an infinite depth is invalid too.
  double min_depth_m = 0.0;
  double max_depth_m = static_cast<double>(std::numeric_limits<float>::max());
  // Raw values equal to `invalid_value` are invalid (when has_invalid_value).
  bool has_invalid_value = false;
  double invalid_value = 0.0;
  // Raw values below `invalid_below` are invalid (when has_invalid_below): OpenCV's int16
  // disparities mark holes with (minDisparity - 1) * 16, below minDisparity * 16; compared in
  // float32, or float64 for float64 input (and for uint16 output).
  bool has_invalid_below = false;
  double invalid_below = 0.0;
};

// Throws std::invalid_argument when a parameter is out of range.
void validate(const DepthParams& params);

// Input element types the kernel reads.
enum class DisparityType { kFloat16, kFloat32, kFloat64, kInt16, kUint16 };

// A stack of disparity maps of any supported type (element strides as in StackView).
struct DisparityStack {
  const void* data = nullptr;
  DisparityType type = DisparityType::kFloat32;
  std::ptrdiff_t frames = 1, rows = 0, cols = 0, frame_stride = 0, row_stride = 0;
};

// Float32 metres with NaN where invalid. Computed in float32 arithmetic (float64 for float64
// input), so a result is within one rounding of the exact quotient of the rounded operands.
void disparity_to_depth(const DisparityStack& in, const StackView<float>& out,
                        const DepthParams& params, int threads = 0, Isa isa = default_isa());

// Uint16 millimetres, rounded half to even, with 0 where invalid, 65535 for anything
// farther and 1 for any valid depth of 1 mm and nearer. Computed in float64.
void disparity_to_depth(const DisparityStack& in, const StackView<std::uint16_t>& out,
                        const DepthParams& params, int threads = 0, Isa isa = default_isa());

}  // namespace stereodepth
