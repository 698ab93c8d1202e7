// The min-max stretch of a uint16 pair onto the scale of uint8 (step 1 of the rules in
// python/stereodepth/matching.py's docstring), which both matchers apply before matching: the
// numpy forms there (stretch_uint16_pair) and in the block-matching oracle (stretched) are the
// references this code is tested against.
#pragma once

#include <cstddef>
#include <cstdint>

#include "stereodepth/dispatch.hpp"

namespace stereodepth {

// A rows x cols uint16 image; `stride` is in elements.
struct Uint16Image {
  const std::uint16_t* data;
  std::ptrdiff_t rows, cols, stride;
};

// The least and the largest value of both images, with `isa`'s kernel on up to `threads`
// threads (0: one per CPU).
void joint_range(const Uint16Image& a, const Uint16Image& b, int threads, Isa isa, int& lo,
                 int& hi);

// out = ((clamp(v, lo, hi) - lo) * 65280 + (hi - lo) / 2) / (hi - lo) for every value v of
// each image (integer arithmetic: rounded to nearest, halves up), into out_a and out_b
// (C-contiguous, the images' size); 0 <= lo < hi <= 65535 (std::invalid_argument
// otherwise). `isa`'s kernel (no division per pixel: see stretch_row16), on up to `threads`
// threads (0: one per CPU).
void stretch_uint16_pair(const Uint16Image& a, const Uint16Image& b, int lo, int hi,
                         std::uint16_t* out_a, std::uint16_t* out_b, int threads, Isa isa);

}  // namespace stereodepth
