// Internal: the semi-global matching kernels, compiled once per instruction set.
//
// Layouts: costs C (uint8) and sums S (uint16) hold `nd` values per pixel, disparity index k
// (disparity min_d + k) rising. Path costs L (int16) hold `ls` values per pixel: a sentinel
// at 0, the nd values at 1 .. nd, a sentinel at nd + 1 (kSentinel, above every path cost, so
// the neighbours d - 1 and d + 1 of the ends never win), then padding.
#pragma once

#include <cstddef>
#include <cstdint>

namespace stereodepth::detail {

// Path costs stay <= 16 * block_size^2 + p2 <= 65535 / 4 < kSentinel; kSentinel + p1 and
// m + p2 stay below 2^15.
inline constexpr std::int16_t kSentinel = 16384;

struct PathParams {
  int nd;  // disparities
  int ls;  // int16 per pixel in path rows (>= nd + 3)
  int p1;
  const std::int16_t* p2;  // P2' for each signed intensity step -255 .. 255, at p2[step]
};

// The pixel costs (census Hamming distances) of one census row pair for the columns
// clamp(x0 - r) .. clamp(x1 - 1 + r): out[j * nd + k] for column clamp(x0 - r + j).
// rev: cols + nd scratch.
using RawRowFn = void (*)(const std::uint16_t* lrow, const std::uint16_t* rrow,
                          std::ptrdiff_t cols, std::ptrdiff_t x0, std::ptrdiff_t x1, int radius,
                          int nd, int min_d, std::uint16_t* rev, std::uint16_t* out);
// The box costs of columns x0 .. x1 - 1 of one image row from the raw rows of the 2r + 1
// census rows y - r .. y + r (clamped; RawRowFn's layout), candidates outside the right image
// at cmax. colsum: (x1 - x0 + 2r) * nd scratch. out: the row's cols * nd costs.
using BoxRowFn = void (*)(const std::uint16_t* const* raws, int radius, std::ptrdiff_t cols,
                          std::ptrdiff_t x0, std::ptrdiff_t x1, int nd, int min_d, int cmax,
                          std::uint16_t* colsum, std::uint8_t* out);
// The paths from the left and from the right along one row, added to s (s[x * nd + k] +=
// L_lr + L_rl). g: the row's grey levels (8-bit scale). tmp: 2 * ls int16 scratch.
using HorizontalRowFn = void (*)(const PathParams& p, const std::uint8_t* c,
                                 const std::uint8_t* g, std::ptrdiff_t cols, std::uint16_t* s,
                                 std::int16_t* tmp);
// One row of a vertical or diagonal path, columns x0 .. x1 - 1: cur[x] from prev[x - dx]
// (the previous row; null on the path's first row, and a path starts where x - dx leaves the
// image). Writes L into s (the row's sums) when `write`, adds it otherwise.
using PathRowFn = void (*)(const PathParams& p, const std::uint8_t* c, const std::uint8_t* g,
                           const std::uint8_t* gprev, const std::int16_t* prev,
                           std::int16_t* cur, std::ptrdiff_t cols, std::ptrdiff_t x0,
                           std::ptrdiff_t x1, int dx, std::uint16_t* s, bool write);

// path_row for nv (1 or 3) directions at once, dxs[v] for prev[v] and cur[v], their path costs
// summed into s (written when `write`, added otherwise); explicit SIMD, nd % 16 == 0 (null in
// the baseline build).
using PathRowsFn = void (*)(const PathParams& p, const std::uint8_t* c, const std::uint8_t* g,
                            const std::uint8_t* gprev, const std::int16_t* const* prev,
                            std::int16_t* const* cur, int nv, const int* dxs, std::ptrdiff_t cols,
                            std::ptrdiff_t x0, std::ptrdiff_t x1, std::uint16_t* s, bool write);

struct DecideArgs {
  std::ptrdiff_t cols;
  int nd, min_d;             // nd: the disparities that may win
  int stride;                // sums per pixel in a row of sums (>= nd; see run_disparities)
  int subpixel;              // SubpixelFit
  double uniqueness_factor;  // 0: off
  double lr_max_diff;        // negative: off
  bool clip_border;
};
// The winner, checks and sub-pixel step of one row of sums. rmin, rarg: cols elements of
// scratch each; winners: cols.
using DecideRowFn = void (*)(const DecideArgs& a, const std::uint16_t* s, float* disp,
                             float* conf, std::uint16_t* rmin, std::uint16_t* rarg,
                             std::uint32_t* winners);

// The 3x3 median of row `mid` (up/down: the rows above and below, null outside the image):
// each valid pixel becomes the lower median of the valid pixels of its window; NaN stays.
// flags: cols bytes of scratch.
using MedianRowFn = void (*)(const float* up, const float* mid, const float* down, float* out,
                             std::uint8_t* flags, std::ptrdiff_t cols);

// raw_row and box_row with 8-bit costs (explicit SIMD; null in the baseline build): the same
// values, half the bytes. box_row8 may compute one of the raw rows itself, raws[fresh] (fresh
// >= 0; that census row pair: lrow, rrow), column by column as it sums them. rev:
// rev8_bytes(cols, nd) bytes of scratch (2 * (cols + nd) + 64 would do for the plain layout);
// ring: 3 * nd bytes of scratch.
inline std::size_t rev8_bytes(std::ptrdiff_t cols, int nd) {
  // The transposed layout's right row: (cols + nd / n) vectors of n <= 32 bytes, twice, and
  // its runs (cols + nd, twice).
  return 66 * static_cast<std::size_t>(cols) + 4 * static_cast<std::size_t>(nd) + 128;
}
using RawRow8Fn = void (*)(const std::uint16_t* lrow, const std::uint16_t* rrow,
                           std::ptrdiff_t cols, std::ptrdiff_t x0, std::ptrdiff_t x1, int radius,
                           int nd, int min_d, std::uint8_t* rev, std::uint8_t* out);
using BoxRow8Fn = void (*)(std::uint8_t* const* raws, int fresh, const std::uint16_t* lrow,
                           const std::uint16_t* rrow, std::uint8_t* rev, int radius,
                           std::ptrdiff_t cols, std::ptrdiff_t x0, std::ptrdiff_t x1, int nd,
                           int min_d, int cmax, std::uint8_t* ring, std::uint8_t* out);

// One image row's paths along the row and its decision, fused (explicit SIMD; 16 disparities
// at a time with AVX2, 32 with AVX-512 when nd allows): pass 1 (x rising) the path from above
// (null lv: none; in place in lv, each pixel's nd values then a pad of sentinels, its least
// cost per pixel in lvmin; a path starts where gprev is null) and the path from the left,
// their sum plus `base` (null: none) into `partial`; pass 2 (x falling) the path from the
// right, the row's sums S, the winner, the second best and the right image's winners (a
// window over the diagonal moved one lane per pixel); then the checks and the sub-pixel step.
// Same results as path_row + horizontal_row + decide_row. c, partial and base hold nd values
// per pixel.

// The padding before the first pixel's path costs in lv and the most after each pixel's.
inline constexpr int kFusedPad = 32;

struct FusedRowArgs {
  PathParams p;
  DecideArgs d;
  const std::uint8_t* c;
  const std::uint8_t* g;
  const std::uint8_t* gprev;  // vertical: the row above (null: the path starts here)
  std::int16_t* lv;           // kFusedPad + cols * (nd + kFusedPad) + 64; null: no vertical path
  std::int16_t* lvmin;        // cols
  const std::uint16_t* base;  // null: none
  std::uint16_t* partial;     // cols * nd scratch
  std::uint16_t* small;       // 3 * (nd + kFusedPad) scratch (aligned to 64 bytes)
  std::uint32_t* result;      // 4 * cols scratch
  std::uint16_t* rfinal;      // cols scratch
  float* disp;
  float* conf;  // null: not wanted
};
using FusedRowFn = void (*)(const FusedRowArgs& a);

struct SemiGlobalKernels {
  RawRowFn raw_row;
  BoxRowFn box_row;
  HorizontalRowFn horizontal_row;
  PathRowFn path_row;
  DecideRowFn decide_row;
  MedianRowFn median_row;
  RawRow8Fn raw_row8;    // null in the baseline build
  BoxRow8Fn box_row8;    // null in the baseline build
  PathRowsFn path_rows;  // null in the baseline build
  FusedRowFn fused_row;  // null in the baseline build
  int fused_lanes;       // fused_row needs nd % fused_lanes == 0
  // The same three in the transposed layout (null in the baseline build; nd % fused_lanes
  // == 0): each pixel's nd values as nv vectors of n lanes (n = 32 when the AVX-512 build
  // runs nd % 32 == 0 and nd >= 128, else 16; nv = nd / n), lane j of vector v holding
  // disparity index j * nv + v, so that the neighbours d - 1 and d + 1 are whole vectors.
  // raw_row8_t and box_row8_t write their costs so; fused_row_t reads c (and base) so and
  // needs no padding in lv (nd values per pixel). Same results as raw_row8 + box_row8 +
  // fused_row.
  RawRow8Fn raw_row8_t;
  BoxRow8Fn box_row8_t;
  FusedRowFn fused_row_t;
};

#define STEREODEPTH_DECLARE_SEMI_GLOBAL_KERNELS(ns) \
  namespace ns {                                    \
  const SemiGlobalKernels& semi_global_kernels();   \
  }
STEREODEPTH_DECLARE_SEMI_GLOBAL_KERNELS(baseline)
STEREODEPTH_DECLARE_SEMI_GLOBAL_KERNELS(avx2)
STEREODEPTH_DECLARE_SEMI_GLOBAL_KERNELS(avx512)
#undef STEREODEPTH_DECLARE_SEMI_GLOBAL_KERNELS

}  // namespace stereodepth::detail
