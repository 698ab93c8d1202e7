#include "stereodepth/stretch.hpp"

#include <algorithm>
#include <mutex>
#include <stdexcept>
#include <string>

#include "block_match_kernels.hpp"
#include "module_support.hpp"
#include "stereodepth/parallel.hpp"

namespace stereodepth {

namespace {

// Rows per band: below this a second thread costs more than it saves.
constexpr std::ptrdiff_t kMinRowsPerBand = 64;

}  // namespace

void joint_range(const Uint16Image& a, const Uint16Image& b, int threads, Isa isa, int& lo,
                 int& hi) {
  const detail::RangeRow16Fn row =
      STEREODEPTH_KERNELS_FOR(isa, block_match_kernels).range_row16;
  std::mutex mu;
  int least = 65535, largest = 0;
  // Rows 0 .. rows - 1 of a, then those of b.
  parallel_for_rows(a.rows + b.rows, resolve_threads(threads), kMinRowsPerBand,
                    [&](std::ptrdiff_t r0, std::ptrdiff_t r1) {
                      std::uint16_t mn = 65535, mx = 0;
                      for (std::ptrdiff_t y = r0; y < r1; ++y) {
                        const bool first = y < a.rows;
                        const Uint16Image& im = first ? a : b;
                        row(im.data + (first ? y : y - a.rows) * im.stride, im.cols, mn, mx);
                      }
                      const std::lock_guard<std::mutex> hold(mu);
                      least = std::min<int>(least, mn);
                      largest = std::max<int>(largest, mx);
                    });
  lo = least;
  hi = largest;
}

void stretch_uint16_pair(const Uint16Image& a, const Uint16Image& b, int lo, int hi,
                         std::uint16_t* out_a, std::uint16_t* out_b, int threads, Isa isa) {
  if (!(0 <= lo && lo < hi && hi <= 65535)) {
    throw std::invalid_argument("stretch_uint16_pair needs 0 <= lo < hi <= 65535, got lo " +
                                std::to_string(lo) + ", hi " + std::to_string(hi));
  }
  const detail::StretchRow16Fn row =
      STEREODEPTH_KERNELS_FOR(isa, block_match_kernels).stretch_row16;
  // Rows 0 .. rows - 1 of a, then those of b, in one pass.
  parallel_for_rows(a.rows + b.rows, resolve_threads(threads), kMinRowsPerBand,
                    [&](std::ptrdiff_t r0, std::ptrdiff_t r1) {
                      for (std::ptrdiff_t y = r0; y < r1; ++y) {
                        throw_if_stopped();
                        const bool first = y < a.rows;
                        const Uint16Image& im = first ? a : b;
                        const std::ptrdiff_t yy = first ? y : y - a.rows;
                        row(im.data + yy * im.stride, (first ? out_a : out_b) + yy * im.cols,
                            im.cols, lo, hi);
                      }
                    });
}

}  // namespace stereodepth
