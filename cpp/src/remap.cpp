#include "stereodepth/remap.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "module_support.hpp"
#include "remap_kernels.hpp"
#include "stereodepth/parallel.hpp"

namespace stereodepth {
namespace {

const detail::RemapKernels& kernels_for(Isa isa) {
  return STEREODEPTH_KERNELS_FOR(isa, remap_kernels);
}

// Rows per band: enough work that starting a thread is worth it.
std::ptrdiff_t min_rows(std::ptrdiff_t cols) {
  return std::max<std::ptrdiff_t>(1, (1 << 14) / std::max<std::ptrdiff_t>(cols, 1));
}

std::ptrdiff_t bytes_per_pixel(PixelFormat f) {
  return f == PixelFormat::kGrey8 ? 1 : f == PixelFormat::kGrey16 ? 2 : 3;
}

// Clamped to [lo, hi], NaN -> lo.
float clamp(float v, float lo, float hi) { return !(v >= lo) ? lo : (v > hi ? hi : v); }

// A map coordinate in 1/1024 px, clamped to [lo, hi] px first (NaN -> lo).
std::int32_t fixed(float v, float lo, float hi) {
  return static_cast<std::int32_t>(std::nearbyint(clamp(v, lo, hi) * 1024.0f));
}

}  // namespace

RemapPrecision remap_precision(PixelFormat format) {
  return format == PixelFormat::kGrey16 ? RemapPrecision::kFloat : RemapPrecision::kFixed;
}

RemapTable::RemapTable(const ImageView<const float>& map_x, const ImageView<const float>& map_y,
                       std::ptrdiff_t src_rows, std::ptrdiff_t src_cols, RemapPrecision precision,
                       int threads)
    : rows_(map_x.rows),
      cols_(map_x.cols),
      src_rows_(src_rows),
      src_cols_(src_cols),
      precision_(precision) {
  if (map_x.rows != map_y.rows || map_x.cols != map_y.cols || map_x.rows < 0 || map_x.cols < 0) {
    throw std::invalid_argument("map_x and map_y must have the same shape");
  }
  if (src_rows < 1 || src_cols < 1 || src_rows > kRemapMaxSourceSide ||
      src_cols > kRemapMaxSourceSide) {
    throw std::invalid_argument("the source image must have 1 to " +
                                std::to_string(kRemapMaxSourceSide) + " rows and columns, got " +
                                std::to_string(src_rows) + " x " + std::to_string(src_cols));
  }
  const float hx = static_cast<float>(src_cols + 1), hy = static_cast<float>(src_rows + 1);
  if (precision == RemapPrecision::kFloat) {
    pos_.resize(static_cast<std::size_t>(2 * rows_ * cols_));
    parallel_for_rows(rows_, resolve_threads(threads), min_rows(cols_),
                      [&](std::ptrdiff_t begin, std::ptrdiff_t end) {
                        for (std::ptrdiff_t r = begin; r < end; ++r) {
                          const float* mx = map_x.row(r);
                          const float* my = map_y.row(r);
                          float* p = pos_.data() + 2 * r * cols_;
                          for (std::ptrdiff_t c = 0; c < cols_; ++c) {
                            p[2 * c] = clamp(mx[c], -2.0f, hx);
                            p[2 * c + 1] = clamp(my[c], -2.0f, hy);
                          }
                        }
                      });
    return;
  }
  xy_.resize(static_cast<std::size_t>(2 * rows_ * cols_));
  frac_.resize(static_cast<std::size_t>(rows_ * cols_));
  parallel_for_rows(rows_, resolve_threads(threads), min_rows(cols_),
                    [&](std::ptrdiff_t begin, std::ptrdiff_t end) {
                      for (std::ptrdiff_t r = begin; r < end; ++r) {
                        const float* mx = map_x.row(r);
                        const float* my = map_y.row(r);
                        std::int16_t* xy = xy_.data() + 2 * r * cols_;
                        std::uint32_t* fr = frac_.data() + r * cols_;
                        for (std::ptrdiff_t c = 0; c < cols_; ++c) {
                          const std::int32_t X = fixed(mx[c], -2.0f, hx);
                          const std::int32_t Y = fixed(my[c], -2.0f, hy);
                          xy[2 * c] = static_cast<std::int16_t>(X >> kRemapFractionBits);
                          xy[2 * c + 1] = static_cast<std::int16_t>(Y >> kRemapFractionBits);
                          fr[c] = static_cast<std::uint32_t>(X & 1023) |
                                  (static_cast<std::uint32_t>(Y & 1023) << 16);
                        }
                      }
                    });
}

void RemapTable::apply(const StereoImage& src, void* dst, std::ptrdiff_t dst_row_stride,
                       int threads, Isa isa) const {
  if (src.rows != src_rows_ || src.cols != src_cols_) {
    throw std::invalid_argument("image must have " + std::to_string(src_rows_) + " x " +
                                std::to_string(src_cols_) +
                                " pixels (the maps' source size), got " + std::to_string(src.rows) +
                                " x " + std::to_string(src.cols));
  }
  if (remap_precision(src.format) != precision_) {
    throw std::invalid_argument(precision_ == RemapPrecision::kFixed
                                    ? "this remap table serves 8-bit images, got a 16-bit one"
                                    : "this remap table serves 16-bit images, got an 8-bit one");
  }
  const std::ptrdiff_t bpp = bytes_per_pixel(src.format);
  if (src.row_stride < src.cols * bpp || dst_row_stride < cols_ * bpp) {
    throw std::invalid_argument("row strides must cover a row");
  }
  const detail::RemapRow kernel = kernels_for(isa).rows[static_cast<int>(src.format)];
  const auto* base = static_cast<const std::uint8_t*>(src.data);
  auto* out = static_cast<std::uint8_t*>(dst);
  parallel_for_rows(rows_, resolve_threads(threads), min_rows(cols_),
                    [&](std::ptrdiff_t begin, std::ptrdiff_t end) {
                      detail::RemapRowArgs a{};
                      a.src = base;
                      a.src_rows = src_rows_;
                      a.src_cols = src_cols_;
                      a.src_stride = src.row_stride;
                      a.n = cols_;
                      const bool fixed = precision_ == RemapPrecision::kFixed;
                      for (std::ptrdiff_t r = begin; r < end; ++r) {
                        const std::ptrdiff_t ahead = r + detail::kRemapAhead < rows_
                                                         ? r + detail::kRemapAhead
                                                         : r;
                        a.xy = fixed ? xy_.data() + 2 * r * cols_ : nullptr;
                        a.frac = fixed ? frac_.data() + r * cols_ : nullptr;
                        a.pos = fixed ? nullptr : pos_.data() + 2 * r * cols_;
                        a.xy_ahead = fixed ? xy_.data() + 2 * ahead * cols_ : nullptr;
                        a.pos_ahead = fixed ? nullptr : pos_.data() + 2 * ahead * cols_;
                        a.dst = out + r * dst_row_stride;
                        kernel(a);
                      }
                    });
}

}  // namespace stereodepth
