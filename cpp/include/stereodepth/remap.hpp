// Bilinear resampling of an image through a map (cv::remap with INTER_LINEAR and
// BORDER_CONSTANT 0), in exactly specified arithmetic.
//
// The float32 map is first turned into a RemapTable, once: each position is clamped to
// [-2, cols + 1] x [-2, rows + 1] (NaN -> -2; this changes no result, since every neighbour
// of such a position is outside the image). p(r, c) below is the source value, 0 outside.
//
// 8-bit images (grey and RGB, RemapPrecision::kFixed): positions rounded half to even to
// 1/1024 px, X = nearbyint(x * 1024), ix = X >> 10 (floor), fx = X & 1023 (likewise y), then
// per channel, in integers:
//   top = p(iy, ix) * (1024 - fx) + p(iy, ix + 1) * fx
//   bot = p(iy + 1, ix) * (1024 - fx) + p(iy + 1, ix + 1) * fx
//   out = (top * (1024 - fy) + bot * fy + 2^19) >> 20
// (the bilinear value at the rounded position, rounded half up). Positions move by at most
// 1/2048 px, values by at most 255/1024, so results are within 1 grey level of cv::remap with
// float maps, which interpolates in float32 (OpenCV 5).
//
// 16-bit images (RemapPrecision::kFloat): the positions as they are, in float64:
//   ix = floor(x), fx = x - ix (exact), likewise y;
//   top = p(iy, ix) * (1 - fx) + p(iy, ix + 1) * fx, bot likewise for row iy + 1,
//   out = nearbyint(top * (1 - fy) + bot * fy), one rounding per operation, in this order.
// (1/1024 px steps would move 16-bit values by up to 64 levels.)
//
// stereodepth.reference.remap is the numpy oracle of both specifications.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "stereodepth/block_match.hpp"  // PixelFormat, StereoImage
#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth {

inline constexpr int kRemapFractionBits = 10;
// Largest source side: positions are held in int16.
inline constexpr std::ptrdiff_t kRemapMaxSourceSide = 32000;

// kFixed serves 8-bit images (grey8, rgb8), kFloat 16-bit ones (grey16).
enum class RemapPrecision { kFixed = 0, kFloat = 1 };

// The precision a pixel format is resampled with.
RemapPrecision remap_precision(PixelFormat format);

// The map in the kernels' form, for a source image of a given size. kFixed: per output pixel
// the top-left neighbour (int16 x, y) and the fractions (fx | fy << 16, in 1/1024 px).
// kFloat: the clamped float32 positions.
class RemapTable {
 public:
  // map_x, map_y: rows x cols float32 source positions (column, row). Throws
  // std::invalid_argument for unequal shapes or a source side outside [1, 32000].
  RemapTable(const ImageView<const float>& map_x, const ImageView<const float>& map_y,
             std::ptrdiff_t src_rows, std::ptrdiff_t src_cols,
             RemapPrecision precision = RemapPrecision::kFixed, int threads = 0);

  // Samples `src` (src_rows x src_cols, a PixelFormat of this table's precision) into `dst`,
  // rows() x cols() pixels of the same format at `dst` with `dst_row_stride` bytes between
  // rows. Rows are split over
  // threads; the result does not depend on their number nor on the instruction set.
  void apply(const StereoImage& src, void* dst, std::ptrdiff_t dst_row_stride,
             int threads = 0, Isa isa = default_isa()) const;

  std::ptrdiff_t rows() const { return rows_; }
  std::ptrdiff_t cols() const { return cols_; }
  std::ptrdiff_t src_rows() const { return src_rows_; }
  std::ptrdiff_t src_cols() const { return src_cols_; }
  RemapPrecision precision() const { return precision_; }

 private:
  std::ptrdiff_t rows_ = 0, cols_ = 0, src_rows_ = 0, src_cols_ = 0;
  RemapPrecision precision_ = RemapPrecision::kFixed;
  std::vector<std::int16_t> xy_;    // kFixed: 2 per pixel, row-major
  std::vector<std::uint32_t> frac_;  // kFixed: 1 per pixel
  std::vector<float> pos_;           // kFloat: x, y per pixel
};

}  // namespace stereodepth
