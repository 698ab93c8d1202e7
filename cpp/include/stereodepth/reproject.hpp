// Disparity maps to 3-D points: [X Y Z W]^T = Q [x y d 1]^T, point = (X, Y, Z) / W.
//
// Q is OpenCV's 4x4 reprojection matrix (cv::stereoRectify); x is the column and y the row of
// the pixel within its frame, d its disparity in pixels. Pixels whose disparity is invalid or
// whose point is not strictly in front of the camera, within the depth limits, get NaN in all
// three coordinates.
#pragma once

#include <limits>

#include "stereodepth/depth.hpp"
#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth {

struct ReprojectParams {
  // Row-major Q; must be finite.
  double q[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 1, 0};
  double scale = 1.0;  // disparity in pixels = raw value * scale
  // Points whose Z leaves [min_depth, max_depth] are invalid, as are points with Z <= 0.
  double min_depth = 0.0;
  double max_depth = static_cast<double>(std::numeric_limits<float>::max());
  // Raw values equal to `invalid_value` are invalid (when has_invalid_value); compared in
  // float32, or float64 for float64 input.
  bool has_invalid_value = false;
  double invalid_value = 0.0;
  // Raw values below `invalid_below` are invalid (when has_invalid_below): OpenCV's int16
  // disparities mark holes with (minDisparity - 1) * 16, below minDisparity * 16; compared in
  // float64 (exact for int16 and every threshold that is a multiple of 1/16 within range).
  bool has_invalid_below = false;
  double invalid_below = 0.0;
};

// Throws std::invalid_argument when a parameter is out of range.
void validate(const ReprojectParams& params);

// `in`: float32, float64, int16 or uint16 (float16 throws). `out`: the same frames and rows
// with 3 * in.cols floats per row, X Y Z interleaved.
//
// Arithmetic, in float64 with one rounding per operation and no contraction, per pixel:
//   d  = raw * scale
//   w  = (q30 x + q32 d) + (q31 y + q33)          and likewise for X (row 0), Y (1), Z (2)
//   iw = 1 / w,  X = float(x_num * iw), Y = ..., Z = ...
// valid when every coordinate is finite and min_depth <= Z <= max_depth with Z > 0 (compared
// as float32). Rows are split over threads; the result does not depend on their number.
void reproject(const DisparityStack& in, const StackView<float>& out,
               const ReprojectParams& params, int threads = 0, Isa isa = default_isa());

}  // namespace stereodepth
