// Internal: the block-matching kernels, compiled once per instruction set.
//
// Layout of the costs of one pixel: `dp` lanes (num_disparities rounded up to the kernel's
// lane multiple), lane q holding disparity index k = dp - 1 - q, i.e. disparity
// min_disparity + dp - 1 - q. In this reversed order the right-image column x - d of lane q is
// x + q + jmin (jmin = -min_disparity - dp + 1), which rises with q: one contiguous load per
// vector. Lanes q < dp - num_disparities are padding and never win.
#pragma once

#include <cstddef>
#include <cstdint>

#include "stereodepth/block_match.hpp"

namespace stereodepth::detail {

// Everything the band kernel reads and writes.
struct MatchArgs {
  MatchCost cost;
  // Feature rows: census codes (uint32) or prefiltered pixels (uint8), for the image rows
  // feat_row0 .. (the band's rows and the block's reach above and below them).
  const void* left_feat;
  const void* right_feat;
  std::ptrdiff_t feat_stride;  // elements
  std::ptrdiff_t feat_row0;
  // min(|sobel_x|, 31) of the left image for the same rows, or null when the check is off.
  const std::uint8_t* texture;
  std::ptrdiff_t texture_stride;
  std::ptrdiff_t rows, cols;
  int min_d, num_d, dp, radius;
  SubpixelFit subpixel;
  double uniqueness_factor;  // 100 + uniqueness_ratio, or 0 when the check is off
  // The same check as a table: a winner of cost b passes when every cost more than one
  // disparity away is >= unique_min[b] & 0xFFFF (capped at 0xFFFF; the value is stored in
  // both halves of the word). Null when off.
  const std::uint32_t* unique_min;
  // min(t << 4, cap) for each threshold t of unique_min, the same way (for the AVX2 first
  // pass, which compares costs << 4); cap is 0x7FFF when every block cost << 4 is below it,
  // else 0xFFFF. Null when off.
  const std::uint32_t* unique_min_shifted;
  double texture_sum_min;    // texture_threshold * block_size^2, or 0 when off
  double lr_max_diff;        // negative when off
  // Pixels whose search range leaves the right image: matched over the disparities inside
  // it (true) or NaN (false, OpenCV's rule).
  bool clip_border;
  float* disp;
  std::ptrdiff_t disp_stride;
  float* conf;  // may be null
  std::ptrdiff_t conf_stride;
  // Diagnostics only (BlockMatcher::stage_times): run the first pass of each row and skip
  // the second, leaving the outputs unwritten.
  bool first_pass_only = false;
};

// One pixel's winner, written by the first pass of a row and read by the second.
struct WinnerRecord {
  std::uint16_t best;    // least block cost; 0xFFFF: no search (the range leaves the image)
  std::uint16_t second;  // least cost more than one disparity away (0xFFFF: none), or, in
                         // the counted mode of the SIMD builds, the number of costs below
                         // the uniqueness threshold
  std::int32_t kbest;    // disparity index of the least cost
  std::uint32_t tsum;    // block texture sum
  std::uint32_t around;  // costs at disparity index kbest - 1 and + 1: c0 | c2 << 16
};
static_assert(sizeof(WinnerRecord) == 16, "records are read four to a vector");

// Per-band scratch memory, allocated by the caller (carve_band gives the sizes).
struct BandScratch {
  std::uint16_t* colsum;   // cols * dp: block-column sums of the pixel costs
  std::uint16_t* acc;      // dp: block sums of the current pixel
  void* rpad_in;           // cols + dp + kRowPad features: the padded right row entering
  void* rpad_out;          // the same for the leaving row
  // Census, the padded rows regrouped for the SIMD builds (see the kernels), cols + dp +
  // kRowPad elements of regrouped_bytes(lanes) each: the codes' nibbles as two rows of
  // uint16, then those of the left row as two more.
  void* quad_in;
  void* quad_out;
  std::uint16_t* rmin;     // cols + dp + kRowPad: least cost per right column
  std::uint16_t* rarg;     // cols + dp + kRowPad: the left column (mod 2^16) that gave it
  std::uint32_t* texcol;   // cols: block-column sums of the texture
  // The row's winner records (see WinnerRecord), cols + 16 of them.
  void* records;
  // SIMD builds: the block costs of the last 16 pixels, recent_size(lanes, dp) of them.
  std::uint16_t* recent;
  // SIMD builds, census, fixed first pass: the pixel costs of the last
  // cost_ring_rows(radius) image rows (row y in slot y mod that), so that a row leaving the
  // block is read back rather than matched again. One byte per cost (a census cost is at
  // most 16): column x of a slot at x * cost_ring_column_bytes(dp), its lanes as the pairs of
  // vectors that vpackuswb makes (see winners_avx2); cost_ring_size(...) bytes, null when
  // that is 0.
  std::uint8_t* ring;
};

// Bytes per element of the regrouped census rows of a build with this many lanes (the SIMD
// builds' 16; the baseline build has none).
inline constexpr std::size_t regrouped_bytes(int lanes) { return lanes == 16 ? 8 : 0; }

// Elements of BandScratch::recent: 16 rows of dp + 32 (SIMD builds only).
inline constexpr std::size_t recent_size(int lanes, int dp) {
  return lanes == 16 ? 16 * (static_cast<std::size_t>(dp) + 32) : 0;
}

// Rows y - r .. y + r: the row entering at y (y + r) takes the slot of the row leaving
// (y - r - 1), whose costs are read before they are overwritten.
inline constexpr std::ptrdiff_t cost_ring_rows(int radius) { return 2 * radius + 1; }

// The most a worker's cost ring may take, in bytes; beyond, the leaving row is matched again.
inline constexpr std::size_t kCostRingBudget = std::size_t{24} << 20;

// Bytes of one column's costs in a ring slot: dp rounded up to 32 (whole pairs of vectors).
inline constexpr std::ptrdiff_t cost_ring_column_bytes(int dp) { return (dp + 31) / 32 * 32; }

// Bytes of BandScratch::ring: a build with 16 lanes (AVX2, AVX-512), census features (4
// bytes) and dp <= 256 (its fixed first pass) keeps cost_ring_rows(radius) rows of cols
// columns, when they fit kCostRingBudget; 0 otherwise.
inline constexpr std::size_t cost_ring_size(int lanes, std::size_t feat_size, int radius,
                                            std::ptrdiff_t cols, int dp) {
  const std::size_t n = static_cast<std::size_t>(cost_ring_rows(radius)) *
                        static_cast<std::size_t>(cols) *
                        static_cast<std::size_t>(cost_ring_column_bytes(dp));
  return lanes == 16 && feat_size == 4 && dp <= 256 && n <= kCostRingBudget ? n : 0;
}

// Elements of slack after each padded row, so vector loops may overrun.
inline constexpr std::ptrdiff_t kRowPad = 64;

// bgr: the channels are B, G, R (OpenCV's COLOR_BGR2GRAY) rather than R, G, B.
using RgbToGreyFn = void (*)(const std::uint8_t* rgb, std::uint8_t* grey, std::ptrdiff_t cols,
                             bool bgr);
// rows: the 5 rows y-2 .. y+2 (clamped to the image), each `cols` long.
using CensusRow8Fn = void (*)(const std::uint8_t* const* rows, std::uint32_t* out,
                              std::ptrdiff_t cols);
using CensusRow16Fn = void (*)(const std::uint16_t* const* rows, std::uint32_t* out,
                               std::ptrdiff_t cols);
// rows: y-1 .. y+1 (clamped). prefiltered or texture may be null.
using SobelRow8Fn = void (*)(const std::uint8_t* const* rows, std::uint8_t* prefiltered,
                             std::uint8_t* texture, std::ptrdiff_t cols);
using SobelRow16Fn = void (*)(const std::uint16_t* const* rows, std::uint8_t* prefiltered,
                              std::uint8_t* texture, std::ptrdiff_t cols);
// The min-max stretch of one uint16 row (stereodepth/stretch.hpp's rule): dst[x] =
// ((clamp(src[x], lo, hi) - lo) * 65280 + (hi - lo) / 2) / (hi - lo), 0 <= lo < hi <= 65535.
using StretchRow16Fn = void (*)(const std::uint16_t* src, std::uint16_t* dst, std::ptrdiff_t cols,
                                int lo, int hi);
// The least and the largest of `lo`, `hi` and the row's values, into lo and hi.
using RangeRow16Fn = void (*)(const std::uint16_t* src, std::ptrdiff_t cols, std::uint16_t& lo,
                              std::uint16_t& hi);
// Matches rows y0 .. y1 - 1. fresh: start from scratch at y0; otherwise the scratch holds the
// column sums of row y0 - 1 (a band continued in pieces).
using MatchBandFn = void (*)(const MatchArgs& args, const BandScratch& scratch,
                             std::ptrdiff_t y0, std::ptrdiff_t y1, bool fresh);
// The speckle filter's links of one row, as bits of 64-bit words ((cols + 63) / 64 each; the
// bits past cols are 0): valid (d[i] is not NaN), left (d[i] and d[i - 1] are linked: both
// valid, |d[i] - d[i - 1]| <= range_f), up (d[i] and u[i] linked; all 0 when u is null).
using SpeckleLinksFn = void (*)(const float* d, const float* u, std::ptrdiff_t cols,
                                float range_f, std::uint64_t* valid, std::uint64_t* left,
                                std::uint64_t* up);

struct BlockMatchKernels {
  int lanes;  // dp is a multiple of this
  RgbToGreyFn rgb_to_grey;
  CensusRow8Fn census_row8;
  CensusRow16Fn census_row16;
  SobelRow8Fn sobel_row8;
  SobelRow16Fn sobel_row16;
  RangeRow16Fn range_row16;
  StretchRow16Fn stretch_row16;
  MatchBandFn match_band;
  SpeckleLinksFn speckle_links;
};

#define STEREODEPTH_DECLARE_BLOCK_MATCH_KERNELS(ns) \
  namespace ns {                                    \
  const BlockMatchKernels& block_match_kernels();   \
  }
STEREODEPTH_DECLARE_BLOCK_MATCH_KERNELS(baseline)
STEREODEPTH_DECLARE_BLOCK_MATCH_KERNELS(avx2)
STEREODEPTH_DECLARE_BLOCK_MATCH_KERNELS(avx512)
#undef STEREODEPTH_DECLARE_BLOCK_MATCH_KERNELS

}  // namespace stereodepth::detail
