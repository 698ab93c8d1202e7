// The border band's last rule, shared by the matchers' second passes (block matching and
// semi-global matching, every ISA build): see drop_unrivalled.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>

namespace stereodepth {
namespace detail {

// With border="clip", a pixel whose search range leaves the right image is matched over the
// candidates inside it. Next to the image's edge those are one to three disparities, and when
// every one of them lies within one disparity of the winner, the winner has no rival to be
// told from (no second-best cost): at the left edge it is mostly a pixel whose true match has
// left the right image, matched to whatever lies at column 0. Such a pixel is NaN (and its
// confidence 0). A pixel searching its whole range keeps its winner whatever num_disparities
// is.
//
// Applied to a row of the second pass's output, before any later filter. The rule needs the
// winner's index k, which the output keeps: a pixel with at most 2 candidates inside has no
// rival whatever wins; with 3 (klo .. klo + 2) only the middle one has none, and only it may
// have moved by the sub-pixel fit, by at most 0.5 (both fits are bounded so), while the ends
// keep integer disparities one away from it.
inline void drop_unrivalled(float* disp, float* conf, std::ptrdiff_t cols, std::ptrdiff_t min_d,
                            std::ptrdiff_t nd) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  auto check = [&](std::ptrdiff_t x) {
    // The candidates k inside the image: 0 <= x - (min_d + k) <= cols - 1.
    const std::ptrdiff_t klo = std::max<std::ptrdiff_t>(0, x - min_d - cols + 1);
    const std::ptrdiff_t khi = std::min<std::ptrdiff_t>(nd - 1, x - min_d);
    const std::ptrdiff_t n = khi - klo + 1;
    if (n <= 0 || n > 3 || n == nd || !(disp[x] == disp[x])) return;
    const double middle = static_cast<double>(min_d + klo + 1);
    const bool unrivalled = n <= 2 || std::fabs(static_cast<double>(disp[x]) - middle) <= 0.5;
    if (unrivalled) {
      disp[x] = nan;
      if (conf) conf[x] = 0.0f;
    }
  };
  // A pixel clipped on one side only has at most 3 candidates at the left edge (x - min_d in
  // 0 .. 2) or at the right one (min_disparity < 0: x - min_d - cols + 1 in nd - 3 .. nd - 1);
  // one clipped on both sides has cols of them, wherever it is: an image of at most 3
  // columns is checked whole. A pixel seen twice is judged the same both times.
  if (cols <= 3) {
    for (std::ptrdiff_t x = 0; x < cols; ++x) check(x);
    return;
  }
  for (std::ptrdiff_t i = 0; i < 3; ++i) {
    const std::ptrdiff_t left = min_d + i;
    const std::ptrdiff_t right = min_d + cols - 1 + nd - 3 + i;
    if (left >= 0 && left < cols) check(left);
    if (right >= 0 && right < cols) check(right);
  }
}

}  // namespace detail
}  // namespace stereodepth
