// Block-matching kernels. Compiled once per instruction set (STEREODEPTH_ISA_NS); everything
// here stays inside that namespace (see dispatch.hpp). The baseline build runs the plain loops,
// the reference every SIMD variant is tested against; the AVX2 and AVX-512 builds replace the
// hot loops with intrinsics that compute the same integers.
//
// One row of a band: (1) the block-column sums colsum[x][q] gain the pixel costs of the row
// entering the block and lose those of the row leaving it; (2) a running sum along the row
// gives each pixel's block costs; its winner (least cost, lowest disparity on a tie), the
// uniqueness data and the costs beside the winner go to a per-pixel record, and the same
// costs update the right image's running winners (the other diagonal); (3) a second pass over
// the records applies the checks (left-right among them) and the sub-pixel step.
//
// The SIMD builds (AVX2, and AVX-512 with the same 16-lane code) keep a pixel's costs in
// registers (dp <= 256: one template per vector count), do step (1) for column x + r on the
// way (so the column sums are read back from L1), work in groups of 16 pixels (block costs to
// `recent`, then the right winners and the winners from there), match the border band in the
// same pass (border_band otherwise), read the census costs of the row leaving the block from a
// ring of the last rows' costs (BandScratch::ring), and do step (3) eight pixels at a time. In
// the defaults' case (census, byte column sums) the block costs are kept as cost << 4, the
// form of the winner searches' keys (see winners_avx2, kShifted).
// Every path computes the same integers, and the floating-point steps use the same IEEE
// operations in the same order as the numpy oracle.
#include "block_match_kernels.hpp"
#include "band_rule.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <type_traits>

#if defined(__AVX2__) || defined(__AVX512F__)
#if defined(__GNUC__) && !defined(__clang__)
// GCC 12's AVX-512 intrinsics start from _mm512_undefined_*(), which its flow analysis then
// reports as "may be used uninitialized" (GCC bug 105593): not a problem in this code.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <immintrin.h>
#endif

#ifndef STEREODEPTH_ISA_NS
#error "STEREODEPTH_ISA_NS must name the instruction set this file is compiled for"
#endif

// The AVX-512 build runs the AVX2 matcher: 16-lane vectors, with the AVX-512 encodings and
// registers the compiler picks. On the first AVX-512 machine measured (AMD EPYC, Zen 4) the
// earlier 32-lane form took 2.6-3x the time of the AVX2 one (bench/README.md, "On an AVX-512
// machine (the eleventh round)").
#if defined(__AVX2__)
#define STEREODEPTH_BM_AVX2 1
#endif

namespace stereodepth::detail::STEREODEPTH_ISA_NS {
namespace {

#if defined(STEREODEPTH_BM_AVX2)
constexpr int kLanes = 16;  // per ymm register
#else
constexpr int kLanes = 8;
#endif

using std::ptrdiff_t;
using std::uint16_t;
using std::uint32_t;
using std::uint8_t;

inline ptrdiff_t clamp_index(ptrdiff_t v, ptrdiff_t lo, ptrdiff_t hi) {
  return v < lo ? lo : (v > hi ? hi : v);
}

// ------------------------------------------------------------------------------------------
// Grey, census and Sobel rows.

// RangeRow16Fn (the compiler vectorizes the loop).
void range_row16(const uint16_t* __restrict src, ptrdiff_t cols, uint16_t& lo, uint16_t& hi) {
  uint16_t mn = lo, mx = hi;
  for (ptrdiff_t x = 0; x < cols; ++x) {
    mn = std::min(mn, src[x]);
    mx = std::max(mx, src[x]);
  }
  lo = mn;
  hi = mx;
}

// StretchRow16Fn, in lanes the compiler vectorizes (no division): the quotient q of
// num = n * 65280 + span / 2 by span (n = clamp(v) - lo) first in float, then corrected by the
// exact remainder. The float quotient is within 0.012 of the exact one: n * 65280 is exact in
// float (n * 255 < 2^24), and the sum, 1 / span and the product each round by at most 2^-24
// relative (3 * 2^-24 * 65280.5 < 0.012). So its truncation is floor(num / span) - 1, + 0 or
// + 1, and the remainder num - q * span (in wrapping 32-bit arithmetic; truly in
// [-span, 2 * span)) says which. Tests compare every value with numpy's division.
void stretch_row16(const uint16_t* __restrict src, uint16_t* __restrict dst, ptrdiff_t cols,
                   int lo, int hi) {
  // The top of the scale, 255 * 256: matching.py's UINT16_STRETCH_TOP.
  constexpr uint32_t kTop = 255u * 256u;
  const int32_t span = hi - lo, half = span / 2;
  const float inv = 1.0f / static_cast<float>(span);
  const float half_f = static_cast<float>(half);
  const auto uspan = static_cast<uint32_t>(span);
  for (ptrdiff_t x = 0; x < cols; ++x) {
    const int32_t n = std::min(std::max(static_cast<int32_t>(src[x]), lo), hi) - lo;
    const uint32_t num = static_cast<uint32_t>(n) * kTop + static_cast<uint32_t>(half);
    int32_t q = static_cast<int32_t>((static_cast<float>(n) * float{kTop} + half_f) * inv);
    const auto r = static_cast<int32_t>(num - static_cast<uint32_t>(q) * uspan);
    q += static_cast<int32_t>(r >= span) - static_cast<int32_t>(r < 0);
    dst[x] = static_cast<uint16_t>(q);
  }
}

// OpenCV's COLOR_RGB2GRAY (COLOR_BGR2GRAY with bgr) for 8-bit images, bit for bit (tests
// check all 2^24 colours): (9798 R + 19235 G + 3735 B + 16384) >> 15, with w0, w1, w2 the
// weights of the pixel's bytes 0, 1, 2.
void rgb_to_grey(const uint8_t* rgb, uint8_t* grey, ptrdiff_t cols, bool bgr) {
  const uint32_t w0 = bgr ? 3735u : 9798u, w1 = 19235u, w2 = bgr ? 9798u : 3735u;
  ptrdiff_t x = 0;
#if defined(STEREODEPTH_BM_AVX2)
  // 16 pixels at a time, in 32-bit lanes: vpshufb spreads each 128-bit half's four pixels
  // into (byte 0, byte 1) and (byte 2, 0) pairs of 16-bit lanes, and vpmaddwd sums them with
  // the weights
  // (exact: at most 255 * 32768 fits a lane). A vector holds pixels 0-3 and 8-11, the other
  // 4-7 and 12-15, so that packing them gives 0-15 in order. The last of the four 16-byte
  // loads ends at byte 3 * (x + 12) + 16 <= 3 * cols: x + 18 <= cols.
  const __m256i rg_of = _mm256_broadcastsi128_si256(
      _mm_setr_epi8(0, -1, 1, -1, 3, -1, 4, -1, 6, -1, 7, -1, 9, -1, 10, -1));
  const __m256i b_of = _mm256_broadcastsi128_si256(
      _mm_setr_epi8(2, -1, -1, -1, 5, -1, -1, -1, 8, -1, -1, -1, 11, -1, -1, -1));
  const __m256i w_rg = _mm256_set1_epi32(static_cast<int>(w0 | (w1 << 16)));
  const __m256i w_b = _mm256_set1_epi32(static_cast<int>(w2));
  const __m256i half = _mm256_set1_epi32(16384);
  auto four_and_four = [&](const uint8_t* p) {  // pixels 0-3 and 8-11 from p
    const __m256i v = _mm256_loadu2_m128i(reinterpret_cast<const __m128i*>(p + 24),
                                          reinterpret_cast<const __m128i*>(p));
    const __m256i sum = _mm256_add_epi32(_mm256_madd_epi16(_mm256_shuffle_epi8(v, rg_of), w_rg),
                                         _mm256_madd_epi16(_mm256_shuffle_epi8(v, b_of), w_b));
    return _mm256_srli_epi32(_mm256_add_epi32(sum, half), 15);
  };
  for (; x + 18 <= cols; x += 16) {
    const __m256i w =
        _mm256_packus_epi32(four_and_four(rgb + 3 * x), four_and_four(rgb + 3 * x + 12));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(grey + x),
                     _mm_packus_epi16(_mm256_castsi256_si128(w), _mm256_extracti128_si256(w, 1)));
  }
#endif
  for (; x < cols; ++x) {
    const uint32_t c0 = rgb[3 * x], c1 = rgb[3 * x + 1], c2 = rgb[3 * x + 2];
    grey[x] = static_cast<uint8_t>((c0 * w0 + c1 * w1 + c2 * w2 + 16384u) >> 15);
  }
}

// The census neighbours: the border of the 5x5 window (16 pixels), row-major.
constexpr bool on_ring(int dy, int dx) {  // dy = 0..4 (row y + dy - 2), dx = -2..2
  return dy == 0 || dy == 4 || dx == -2 || dx == 2;
}

// The census code at column x: one bit per ring neighbour, row-major, the first in bit 15,
// set where the neighbour (clamped to the image) is darker than the centre.
template <typename T>
uint32_t census_at(const T* const* rows, ptrdiff_t x, ptrdiff_t cols) {
  const T c = rows[2][x];
  uint32_t code = 0;
  for (int dy = 0; dy < 5; ++dy) {
    for (int dx = -2; dx <= 2; ++dx) {
      if (!on_ring(dy, dx)) continue;
      const T v = rows[dy][clamp_index(x + dx, 0, cols - 1)];
      code = (code << 1) | static_cast<uint32_t>(v < c);
    }
  }
  return code;
}


#if defined(STEREODEPTH_BM_AVX2)
// The census codes of the 32 interior 8-bit pixels from x: each neighbour's comparison sets
// its bit in one of two byte planes (bits 8-15, 0-7), interleaved into 16-bit codes and
// widened to 32 bits.
inline void census_block_avx2(const uint8_t* const* rows, ptrdiff_t x, uint32_t* out) {
  auto load = [](const uint8_t* p) {
    return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
  };
  const __m256i c = load(rows[2] + x);
  // Each plane gathers 8 neighbours, the first in its top bit: doubled before each one is
  // added, it ends as the sum of ge_k << (7 - k) over its neighbours (ge_k: -1 in the bytes
  // where the neighbour is >= the centre, else 0), which is (the bits of v < c) - 255, i.e.
  // those bits + 1, modulo 256; so - 1 at the end. Fully unrolled, with the rows'
  // pointers in registers (GCC 12 kept the loops over rows and columns, rebuilding each
  // bit's constant at run time: about five times the instructions).
  const uint8_t* const r0 = rows[0] + x;
  const uint8_t* const r1 = rows[1] + x;
  const uint8_t* const r2 = rows[2] + x;
  const uint8_t* const r3 = rows[3] + x;
  const uint8_t* const r4 = rows[4] + x;
  auto ge = [&](const uint8_t* p) {
    // v >= c (unsigned) where max(v, c) == v.
    const __m256i v = load(p);
    return _mm256_cmpeq_epi8(_mm256_max_epu8(v, c), v);
  };
  auto step = [](__m256i plane, __m256i g) {
    return _mm256_add_epi8(_mm256_add_epi8(plane, plane), g);
  };
  // Bits 15 .. 8: row 0 (5 pixels), then row 1's two ends and row 2's left end.
  __m256i hi8 = ge(r0 - 2);
  hi8 = step(hi8, ge(r0 - 1));
  hi8 = step(hi8, ge(r0));
  hi8 = step(hi8, ge(r0 + 1));
  hi8 = step(hi8, ge(r0 + 2));
  hi8 = step(hi8, ge(r1 - 2));
  hi8 = step(hi8, ge(r1 + 2));
  hi8 = step(hi8, ge(r2 - 2));
  // Bits 7 .. 0: row 2's right end, row 3's two ends, row 4 (5 pixels).
  __m256i lo8 = ge(r2 + 2);
  lo8 = step(lo8, ge(r3 - 2));
  lo8 = step(lo8, ge(r3 + 2));
  lo8 = step(lo8, ge(r4 - 2));
  lo8 = step(lo8, ge(r4 - 1));
  lo8 = step(lo8, ge(r4));
  lo8 = step(lo8, ge(r4 + 1));
  lo8 = step(lo8, ge(r4 + 2));
  const __m256i one = _mm256_set1_epi8(1);
  const __m256i plane[2] = {_mm256_sub_epi8(hi8, one), _mm256_sub_epi8(lo8, one)};
  // Pixels 0-7 and 16-23 (lo), 8-15 and 24-31 (hi) as 16-bit codes.
  const __m256i lo = _mm256_unpacklo_epi8(plane[1], plane[0]);
  const __m256i hi = _mm256_unpackhi_epi8(plane[1], plane[0]);
  auto put = [&](ptrdiff_t at, __m128i codes) {
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + x + at), _mm256_cvtepu16_epi32(codes));
  };
  put(0, _mm256_castsi256_si128(lo));
  put(8, _mm256_castsi256_si128(hi));
  put(16, _mm256_extracti128_si256(lo, 1));
  put(24, _mm256_extracti128_si256(hi, 1));
}
#endif

template <typename T>
void census_row(const T* const* rows, uint32_t* out, ptrdiff_t cols) {
  ptrdiff_t x = 0;
  for (; x < cols && x < 2; ++x) out[x] = census_at(rows, x, cols);
#if defined(STEREODEPTH_BM_AVX2)
  if constexpr (sizeof(T) == 1) {
    constexpr ptrdiff_t kBlock = 32;
    if (cols - 4 >= kBlock) {
      for (; x + kBlock <= cols - 2; x += kBlock) census_block_avx2(rows, x, out);
      // The tail: one more block ending at the last interior column (see below).
      if (x < cols - 2) {
        census_block_avx2(rows, cols - 2 - kBlock, out);
        x = cols - 2;
      }
    }
  }
#endif
  for (; x < cols - 2; ++x) {
    // Interior columns: no clamping (the compiler vectorises this loop).
    const T c = rows[2][x];
    uint32_t code = 0;
    for (int dy = 0; dy < 5; ++dy) {
      const T* p = rows[dy];
      for (int dx = -2; dx <= 2; ++dx) {
        if (!on_ring(dy, dx)) continue;
        code = (code << 1) | static_cast<uint32_t>(p[x + dx] < c);
      }
    }
    out[x] = code;
  }
  for (; x < cols; ++x) out[x] = census_at(rows, x, cols);
}

// The x-Sobel response of rows y-1..y+1 at column x (neighbour columns xm, xp), shifted right
// by 8 bits (toward -inf) for 16-bit images.
template <typename T>
inline int32_t sobel_at(const T* const* rows, ptrdiff_t xm, ptrdiff_t xp) {
  const int32_t s = (static_cast<int32_t>(rows[0][xp]) - static_cast<int32_t>(rows[0][xm])) +
                    2 * (static_cast<int32_t>(rows[1][xp]) - static_cast<int32_t>(rows[1][xm])) +
                    (static_cast<int32_t>(rows[2][xp]) - static_cast<int32_t>(rows[2][xm]));
  return sizeof(T) == 2 ? (s >> 8) : s;
}

// prefiltered = clip(s, -31, 31) + 31 (SAD), texture = min(|s|, 31); either may be null.
template <typename T>
void sobel_row(const T* const* rows, uint8_t* pre, uint8_t* tex, ptrdiff_t cols) {
  constexpr int32_t cap = kPrefilterCap;
  auto put = [&](ptrdiff_t x, int32_t s) {
    const int32_t c = s < -cap ? -cap : (s > cap ? cap : s);
    if (pre) pre[x] = static_cast<uint8_t>(c + cap);
    if (tex) tex[x] = static_cast<uint8_t>(c < 0 ? -c : c);
  };
  for (ptrdiff_t x = 0; x < cols; ++x) {
    put(x, sobel_at(rows, clamp_index(x - 1, 0, cols - 1), clamp_index(x + 1, 0, cols - 1)));
  }
}

// ------------------------------------------------------------------------------------------
// Pixel costs into the block-column sums.

struct CensusCost {
  using Feature = uint32_t;
  static inline uint32_t cost(uint32_t a, uint32_t b) {
    return static_cast<uint32_t>(__builtin_popcount(a ^ b));
  }
};

struct SadCost {
  using Feature = uint8_t;
  static inline uint32_t cost(uint8_t a, uint8_t b) {
    return static_cast<uint32_t>(a > b ? a - b : b - a);
  }
};

#if defined(STEREODEPTH_BM_AVX2)
// The set bits of 0 .. 15 in each 128-bit half: a vpshufb table for nibbles.
inline __m256i nibble_popcounts() {
  return _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3,
                          1, 2, 2, 3, 2, 3, 3, 4);
}

// Set bits of each 32-bit lane (nibble lookup, then byte sums).
inline __m256i popcnt_epi32(__m256i v) {
  const __m256i lut = nibble_popcounts();
  const __m256i low = _mm256_set1_epi8(0x0f);
  const __m256i lo = _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low));
  const __m256i hi = _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16(v, 4), low));
  const __m256i bytes = _mm256_add_epi8(lo, hi);
  const __m256i pairs = _mm256_maddubs_epi16(bytes, _mm256_set1_epi8(1));
  return _mm256_madd_epi16(pairs, _mm256_set1_epi16(1));
}

// 16 lanes of 32-bit values (two vectors, in order) to 16-bit lanes, in order.
inline __m256i narrow_epi32(__m256i a, __m256i b) {
  return _mm256_permute4x64_epi64(_mm256_packs_epi32(a, b), 0xD8);
}

inline __m256i census_cost16(__m256i l, const uint32_t* r) {
  return narrow_epi32(
      popcnt_epi32(_mm256_xor_si256(l, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(r)))),
      popcnt_epi32(
          _mm256_xor_si256(l, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(r + 8)))));
}

inline __m256i sad_cost16(__m256i l, const uint8_t* r) {
  const __m256i rv = _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(r)));
  return _mm256_abs_epi16(_mm256_sub_epi16(l, rv));
}
#endif


// colsum[x][q] += cost(left[x], rpad[x + q]) for every lane (the padding lanes too: their sums
// are never read as costs). AVX2 census: when costs is not null, the costs also go there (the
// row's slot of BandScratch::ring, bytes, see winners_avx2).
template <typename Cost>
void add_cost_row(const typename Cost::Feature* left, const typename Cost::Feature* rpad,
                  uint16_t* colsum, ptrdiff_t cols, int dp, uint8_t* costs, bool byte_cols) {
  constexpr bool kCensus = sizeof(typename Cost::Feature) == 4;
#if !defined(STEREODEPTH_BM_AVX2)
  (void)costs;
  (void)byte_cols;
#else
  if constexpr (kCensus) {
   if (byte_cols) {
    // Census with byte column sums (see RowCtx::byte_cols): the costs, packed in pairs of
    // vectors, go to the ring slot and are added to the sums in the same layout.
    auto* sums = reinterpret_cast<uint8_t*>(colsum);
    for (ptrdiff_t x = 0; x < cols; ++x) {
      const __m256i lv = _mm256_set1_epi32(static_cast<int>(left[x]));
      const auto* r = rpad + x;
      for (int q = 0; q < dp; q += 32) {
        const __m256i c0 = census_cost16(lv, r + q);
        const __m256i c1 = q + 16 < dp ? census_cost16(lv, r + q + 16) : _mm256_setzero_si256();
        const __m256i c8 = _mm256_packus_epi16(c0, c1);
        const ptrdiff_t at = x * cost_ring_column_bytes(dp) + q;
        _mm256_store_si256(reinterpret_cast<__m256i*>(costs + at), c8);
        auto* sp = reinterpret_cast<__m256i*>(sums + at);
        _mm256_store_si256(sp, _mm256_add_epi8(_mm256_load_si256(sp), c8));
      }
    }
    return;
   }
  }
#endif
  for (ptrdiff_t x = 0; x < cols; ++x) {
    uint16_t* s = colsum + x * dp;
    const auto l = left[x];
    const auto* r = rpad + x;
#if defined(STEREODEPTH_BM_AVX2)
    const __m256i lv = kCensus ? _mm256_set1_epi32(static_cast<int>(l))
                               : _mm256_set1_epi16(static_cast<short>(l));
    auto cost = [&](int q) {
      __m256i c;
      if constexpr (kCensus) {
        c = census_cost16(lv, r + q);
      } else {
        c = sad_cost16(lv, r + q);
      }
      auto* sp = reinterpret_cast<__m256i*>(s + q);
      _mm256_storeu_si256(sp, _mm256_add_epi16(_mm256_loadu_si256(sp), c));
      return c;
    };
    for (int q = 0; q < dp; q += 32) {
      const __m256i c0 = cost(q);
      const __m256i c1 = q + 16 < dp ? cost(q + 16) : _mm256_setzero_si256();
      if (costs) {
        _mm256_store_si256(
            reinterpret_cast<__m256i*>(costs + x * cost_ring_column_bytes(dp) + q),
            _mm256_packus_epi16(c0, c1));
      }
    }
#else
    (void)kCensus;
    for (int q = 0; q < dp; ++q) s[q] = static_cast<uint16_t>(s[q] + Cost::cost(l, r[q]));
#endif
  }
}

// colsum[x][q] += cost(entering) - cost(leaving), modulo 2^16 (exact: the sums stay < 2^16).
template <typename Cost>
void update_cost_rows(const typename Cost::Feature* left_in, const typename Cost::Feature* rpad_in,
                      const typename Cost::Feature* left_out,
                      const typename Cost::Feature* rpad_out, uint16_t* colsum, ptrdiff_t cols,
                      int dp) {
  constexpr bool kCensus = sizeof(typename Cost::Feature) == 4;
  for (ptrdiff_t x = 0; x < cols; ++x) {
    uint16_t* s = colsum + x * dp;
    const auto li = left_in[x];
    const auto lo = left_out[x];
    const auto* ri = rpad_in + x;
    const auto* ro = rpad_out + x;
#if defined(STEREODEPTH_BM_AVX2)
    const __m256i liv = kCensus ? _mm256_set1_epi32(static_cast<int>(li))
                                : _mm256_set1_epi16(static_cast<short>(li));
    const __m256i lov = kCensus ? _mm256_set1_epi32(static_cast<int>(lo))
                                : _mm256_set1_epi16(static_cast<short>(lo));
    for (int q = 0; q < dp; q += 16) {
      __m256i c;
      if constexpr (kCensus) {
        c = _mm256_sub_epi16(census_cost16(liv, ri + q), census_cost16(lov, ro + q));
      } else {
        c = _mm256_sub_epi16(sad_cost16(liv, ri + q), sad_cost16(lov, ro + q));
      }
      auto* sp = reinterpret_cast<__m256i*>(s + q);
      _mm256_storeu_si256(sp, _mm256_add_epi16(_mm256_loadu_si256(sp), c));
    }
#else
    (void)kCensus;
    for (int q = 0; q < dp; ++q) {
      s[q] = static_cast<uint16_t>(s[q] + Cost::cost(li, ri[q]) - Cost::cost(lo, ro[q]));
    }
#endif
  }
}

// ------------------------------------------------------------------------------------------
// One row, in two passes. The first runs along the row with the block sums of one pixel at a
// time: it keeps the right image's running winners and writes each pixel's winner record
// (integers only). The second turns the records into the checks, the sub-pixel step and the
// outputs, many pixels at a time.

struct RowCtx {
  const uint16_t* colsum;
  const uint32_t* texcol;  // null when the texture check is off
  ptrdiff_t cols, xlo, xhi;  // columns xlo..xhi have their whole search range in the image
  int dp, nd, qpad, radius, min_d;
  SubpixelFit subpixel;
  bool lr_on, need_second;
  bool clip_border;  // match the border columns (see border_band)
  // Fixed-size SIMD first pass without confidence: `second` holds, instead of the
  // second-best cost, how many lanes cost less than the uniqueness threshold
  // unique_min[best]; the second pass subtracts the winner and its two neighbours (see
  // decide_avx2).
  bool count_low;
  bool first_pass_only;  // diagnostics: skip the second pass (see MatchArgs)
  double texture_sum_min, uniqueness_factor, lr_max_diff;
  uint16_t* acc;   // dp lanes of scratch (generic pass)
  uint16_t* rmin;  // generic pass
  // Right winners: rarg[i] is the left column (mod 2^16) whose block won right column
  // i + jmin; its disparity index is (rarg[i] - i + dp - 1) mod 2^16.
  uint16_t* rarg;
  uint16_t* recent;   // AVX2: the block costs of the last 16 pixels (see winners_avx2)
  WinnerRecord* rec;  // the row's winner records
  const uint32_t* unique_min;  // null when off
  // unique_min's thresholds t as min(t << 4, cap), in both halves (see winners_avx2,
  // kShifted, and MatchArgs::unique_min_shifted); null when off.
  const uint32_t* unique_min_shifted;
  // The column-sum update of this row, when the first pass does it on the way (fused): the
  // left feature rows and padded right rows entering and leaving the block; null otherwise.
  const void* in_left;
  const void* in_rpad;
  const void* out_left;
  const void* out_rpad;
  const void* in_quad;  // census: the padded rows regrouped (see quads_of, nibbles_of)
  const void* out_quad;
  ptrdiff_t nibble_stride;  // AVX2: elements from the low nibbles to the high ones
  // AVX2 census: the ring slots (see BandScratch::ring) of the rows entering and leaving.
  uint8_t* ring_in;
  const uint8_t* ring_out;
  // AVX2 census with a ring and block costs of a column below 256 (block size <= 15): the
  // column sums are bytes, laid out as the ring's slots (see winners_avx2), for every row of
  // the band.
  bool byte_cols;
  // The records' `around` holds the neighbours' costs as cost << 4 (0xFFFF for none): the
  // fixed first pass with byte column sums (winners_avx2, kShifted) leaves them so and
  // decide_avx2 shifts them back, eight pixels at a time.
  bool around_shifted;
  float* drow;
  float* crow;  // null when no confidence is wanted
};

constexpr uint32_t kNone = 0xFFFFu;  // no search (best) / no second-best (second)

// The record of a pixel with no search: its block leaves the right image.
inline void record_none(const RowCtx& c, ptrdiff_t x) {
  c.rec[x] = WinnerRecord{static_cast<uint16_t>(kNone), static_cast<uint16_t>(kNone), 0, 0, 0};
}

struct Winner {
  uint32_t best;  // least cost
  int q;          // its lane: the highest lane among equal costs (the lowest disparity)
};

#if defined(STEREODEPTH_BM_AVX2)

inline __m256i lane_iota16() {
  return _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
}

// All-ones on the padding lanes (q < qpad < 16, in the first vector).
inline __m256i pad_vector(int qpad) {
  return _mm256_cmpgt_epi16(_mm256_set1_epi16(static_cast<short>(qpad)), lane_iota16());
}

inline uint32_t hmin_epu16(__m256i v) {
  const __m128i b = _mm_min_epu16(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  return static_cast<uint32_t>(_mm_cvtsi128_si32(_mm_minpos_epu16(b))) & 0xFFFFu;
}

inline Winner find_winner(const uint16_t* acc, int qpad, int dp) {
  const __m256i padv = pad_vector(qpad);
  auto load = [&](int q) {
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(acc + q));
    return q == 0 ? _mm256_or_si256(v, padv) : v;
  };
  __m256i mn = load(0);
  for (int q = 16; q < dp; q += 16) mn = _mm256_min_epu16(mn, load(q));
  const uint32_t best = hmin_epu16(mn);
  const __m256i bv = _mm256_set1_epi16(static_cast<short>(best));
  int qb = -1;
  for (int q = 0; q < dp; q += 16) {
    const unsigned m = static_cast<unsigned>(_mm256_movemask_epi8(_mm256_cmpeq_epi16(load(q), bv)));
    if (m) qb = q + (31 - __builtin_clz(m)) / 2;
  }
  return {best, qb};
}

inline uint32_t second_cost(const uint16_t* acc, int qpad, int dp, int qb) {
  const __m256i padv = pad_vector(qpad);
  const __m256i iota = lane_iota16();
  const __m256i two = _mm256_set1_epi16(2);
  __m256i mn = _mm256_set1_epi16(-1);
  for (int q = 0; q < dp; q += 16) {
    // Lanes with (lane - (qb - 1 - q)) <= 2, unsigned, are qb - 1 .. qb + 1.
    const __m256i rel =
        _mm256_sub_epi16(iota, _mm256_set1_epi16(static_cast<short>(qb - 1 - q)));
    __m256i ex = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, two), rel);
    if (q == 0) ex = _mm256_or_si256(ex, padv);
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(acc + q));
    mn = _mm256_min_epu16(mn, _mm256_or_si256(v, ex));
  }
  return hmin_epu16(mn);
}

inline void right_update(const uint16_t* acc, uint16_t* rmin, uint16_t* rarg, ptrdiff_t x,
                         int qpad, int dp) {
  const __m256i padv = pad_vector(qpad);
  const __m256i xv = _mm256_set1_epi16(static_cast<short>(x));
  for (int q = 0; q < dp; q += 16) {
    __m256i a = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(acc + q));
    if (q == 0) a = _mm256_or_si256(a, padv);
    auto* pm = reinterpret_cast<__m256i*>(rmin + x + q);
    auto* pa = reinterpret_cast<__m256i*>(rarg + x + q);
    const __m256i rm = _mm256_loadu_si256(pm);
    const __m256i mn = _mm256_min_epu16(a, rm);
    // a < rm: min(a, rm) == a and a != rm.
    const __m256i lt = _mm256_andnot_si256(_mm256_cmpeq_epi16(a, rm), _mm256_cmpeq_epi16(mn, a));
    _mm256_storeu_si256(pm, mn);
    _mm256_storeu_si256(pa, _mm256_blendv_epi8(_mm256_loadu_si256(pa), xv, lt));
  }
}

#else

inline Winner find_winner(const uint16_t* acc, int qpad, int dp) {
  Winner w{0x10000u, -1};
  for (int q = dp - 1; q >= qpad; --q) {
    if (acc[q] < w.best) {
      w.best = acc[q];
      w.q = q;
    }
  }
  return w;
}

// The least cost more than one lane away from lane qb; kNone when there is none.
inline uint32_t second_cost(const uint16_t* acc, int qpad, int dp, int qb) {
  uint32_t s = kNone;
  for (int q = qpad; q < dp; ++q) {
    if ((q < qb - 1 || q > qb + 1) && acc[q] < s) s = acc[q];
  }
  return s;
}

// The right image's running winners: column i = x + q (right column i + jmin) keeps its least
// cost and the left column x that gave it. Candidates arrive in increasing disparity, so a
// strict < keeps the lowest.
inline void right_update(const uint16_t* acc, uint16_t* rmin, uint16_t* rarg, ptrdiff_t x,
                         int qpad, int dp) {
  for (int q = qpad; q < dp; ++q) {
    if (acc[q] < rmin[x + q]) {
      rmin[x + q] = acc[q];
      rarg[x + q] = static_cast<uint16_t>(x);
    }
  }
}

#endif

// First pass, with the costs in memory (any dp).
void winners_generic(const RowCtx& c) {
  const ptrdiff_t cols = c.cols;
  const int dp = c.dp, r = c.radius;
  uint16_t* acc = c.acc;
  if (c.lr_on) {
    for (ptrdiff_t i = 0; i < cols + dp + 32; ++i) c.rmin[i] = 0xFFFF;
  }
  std::memset(acc, 0, sizeof(uint16_t) * static_cast<size_t>(dp));
  uint32_t tsum = 0;
  for (ptrdiff_t dx = -r; dx <= r; ++dx) {
    const ptrdiff_t xx = clamp_index(dx, 0, cols - 1);
    const uint16_t* col = c.colsum + xx * dp;
    for (int q = 0; q < dp; ++q) acc[q] = static_cast<uint16_t>(acc[q] + col[q]);
    if (c.texcol) tsum += c.texcol[xx];
  }
  for (ptrdiff_t x = 0; x < cols; ++x) {
    if (x > 0) {
      const ptrdiff_t xp = clamp_index(x + r, 0, cols - 1);
      const ptrdiff_t xm = clamp_index(x - r - 1, 0, cols - 1);
      const uint16_t* plus = c.colsum + xp * dp;
      const uint16_t* minus = c.colsum + xm * dp;
      for (int q = 0; q < dp; ++q) acc[q] = static_cast<uint16_t>(acc[q] + plus[q] - minus[q]);
      if (c.texcol) tsum += c.texcol[xp] - c.texcol[xm];
    }
    if (c.lr_on) right_update(acc, c.rmin, c.rarg, x, c.qpad, dp);
    if (x < c.xlo || x > c.xhi) {
      record_none(c, x);
      continue;
    }
    const Winner w = find_winner(acc, c.qpad, dp);
    WinnerRecord& rec = c.rec[x];
    rec.best = static_cast<uint16_t>(w.best);
    rec.kbest = dp - 1 - w.q;
    rec.second = static_cast<uint16_t>(c.need_second ? second_cost(acc, c.qpad, dp, w.q) : kNone);
    rec.tsum = tsum;
    rec.around = 0;
    if (c.subpixel != SubpixelFit::kNone) {
      const uint32_t c0 = w.q + 1 < dp ? acc[w.q + 1] : 0u;  // disparity index kb - 1
      const uint32_t c2 = w.q >= 1 ? acc[w.q - 1] : 0u;      // disparity index kb + 1
      rec.around = c0 | (c2 << 16);
    }
  }
}

#if defined(STEREODEPTH_BM_AVX2)

constexpr int kMaxChunks = 16;  // dp <= 256

// The n census codes of a row (16 bits each) split into nibbles for the lookup in
// update_col: out[i] = code & 0x0F0F and out[stride + i] = (code >> 4) & 0x0F0F, one load per
// 16 lanes (padded right rows), one broadcast per column (left rows).
void nibbles_of(const uint32_t* codes, uint16_t* out, ptrdiff_t n, ptrdiff_t stride) {
#if defined(__AVX512BITALG__)
  // With AVX512_BITALG update_col counts whole codes (vpopcntw): the codes as they are.
  (void)stride;
  for (ptrdiff_t i = 0; i < n; ++i) out[i] = static_cast<uint16_t>(codes[i]);
#else
  for (ptrdiff_t i = 0; i < n; ++i) {
    out[i] = static_cast<uint16_t>(codes[i] & 0x0F0Fu);
    out[stride + i] = static_cast<uint16_t>((codes[i] >> 4) & 0x0F0Fu);
  }
#endif
}

// The right winners, updated 16 pixels at a time from the costs that winners_avx2 keeps:
// row t of `recent` holds pixel x0 + t's dp costs at elements 16 .. 16 + dp - 1 (0xFFFF on
// either side). Right column i = x0 + 16k + j (aligned block k = 0 .. NC of the columns these
// pixels reach) receives lane i - x of pixel x, for x rising, i.e. disparity rising: a strict
// < keeps the lowest. Doing this per block rather than per pixel keeps the block's winners in
// two registers, and the loads never wait on a store that overlaps them only in part (which
// the per-pixel update does: a store-forwarding stall for every vector).
template <int NC>
void right_group(const uint16_t* recent, uint16_t* rmin, uint16_t* rarg, ptrdiff_t x0, int n) {
  constexpr ptrdiff_t kRow = 16 * NC + 32;
  const __m256i one = _mm256_set1_epi16(1);
  for (int k = 0; k <= NC; ++k) {
    auto* pm = reinterpret_cast<__m256i*>(rmin + x0 + 16 * k);
    auto* pa = reinterpret_cast<__m256i*>(rarg + x0 + 16 * k);
    __m256i best = _mm256_load_si256(pm);
    __m256i arg = _mm256_load_si256(pa);
    __m256i xv = _mm256_set1_epi16(static_cast<short>(x0));
    const uint16_t* p = recent + 16 + 16 * k;  // row t: lanes 16k - t ..
    for (int t = 0; t < n; ++t, p += kRow - 1) {
      const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
      const __m256i m = _mm256_min_epu16(v, best);
      arg = _mm256_blendv_epi8(xv, arg, _mm256_cmpeq_epi16(m, best));  // x where v < best
      best = m;
      xv = _mm256_add_epi16(xv, one);
    }
    _mm256_store_si256(pm, best);
    _mm256_store_si256(pa, arg);
  }
}

// right_group when every block cost is below 4095: each cost and its pixel's place in the
// group (4 bits) as one 16-bit key, cost << 4 | t, so that one unsigned minimum per pixel
// keeps the least cost and, among equal costs, the first pixel (the lowest disparity), as the
// strict < does. The 0xFFFF of `recent` either side of the lanes gives keys of at least
// 0xFFF0, above every real one; a column that only such keys reach gets cost 4095, which the
// first real cost replaces (its columns are never read before one arrives). kShifted: `recent`
// holds cost << 4 with the left winner's key bits 15 - i in the low four bits (see
// winners_avx2), its 0xFFFF lanes the same. Block k's lane j of pixel t is lane 16k + j - t
// of the pixel's costs, in vector i = k - [j < t], so v = cost << 4 | (15 - k + [j < t]);
// v + (t - [j < t]), added with unsigned saturation (0xFFFF stays 0xFFFF), is
// cost << 4 + 15 - k + t: per block the same order as cost << 4 | t, which subtracting
// 15 - k gives back.
template <int NC, bool kShifted>
void right_group_keyed(const uint16_t* recent, uint16_t* rmin, uint16_t* rarg, ptrdiff_t x0,
                       int n) {
  constexpr ptrdiff_t kRow = 16 * NC + 32;
  const __m256i ones = _mm256_set1_epi16(-1);
  const __m256i low4 = _mm256_set1_epi16(15);
  const __m256i xv = _mm256_set1_epi16(static_cast<short>(x0));
  __m256i keys[NC + 1];
  for (int k = 0; k <= NC; ++k) keys[k] = ones;
  __m256i tv = _mm256_setzero_si256();
  const __m256i iota = lane_iota16();
  for (int t = 0; t < n; ++t) {
    const uint16_t* p = recent + t * kRow + 16 - t;  // block k: lanes 16k - t ..
    __m256i add = tv;
    if constexpr (kShifted) add = _mm256_add_epi16(tv, _mm256_cmpgt_epi16(tv, iota));
    for (int k = 0; k <= NC; ++k) {
      const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p + 16 * k));
      if constexpr (kShifted) {
        // t - [j < t] in lane j.
        keys[k] = _mm256_min_epu16(keys[k], _mm256_adds_epu16(v, add));
      } else {
        keys[k] = _mm256_min_epu16(keys[k], _mm256_or_si256(_mm256_slli_epi16(v, 4), tv));
      }
    }
    tv = _mm256_add_epi16(tv, _mm256_set1_epi16(1));
  }
  if constexpr (kShifted) {
    // (Block NC = 16 adds 1 instead, with saturation: 0xFFFF, no cost, stays.)
    for (int k = 0; k <= NC; ++k) {
      keys[k] = k <= 15 ? _mm256_sub_epi16(keys[k], _mm256_set1_epi16(static_cast<short>(15 - k)))
                        : _mm256_adds_epu16(keys[k], _mm256_set1_epi16(1));
    }
  }
  for (int k = 0; k <= NC; ++k) {
    const __m256i key = keys[k];
    auto* pm = reinterpret_cast<__m256i*>(rmin + x0 + 16 * k);
    auto* pa = reinterpret_cast<__m256i*>(rarg + x0 + 16 * k);
    const __m256i best = _mm256_load_si256(pm);
    const __m256i cost = _mm256_srli_epi16(key, 4);
    const __m256i m = _mm256_min_epu16(cost, best);
    // cost < best: the minimum is not best (earlier groups keep their winners on a tie).
    const __m256i keep = _mm256_cmpeq_epi16(m, best);
    _mm256_store_si256(pm, m);
    _mm256_store_si256(
        pa, _mm256_blendv_epi8(_mm256_add_epi16(xv, _mm256_and_si256(key, low4)),
                               _mm256_load_si256(pa), keep));
  }
}

// First pass with the NC vectors of 16 costs in registers:
// the column-sum update fused in, a branch-free winner, and the right winners updated per
// group of 16 pixels (right_group) from the costs stored in `recent`, which also gives the
// winner's neighbours.
template <int NC, typename Cost, bool kRing, bool kBytes>
void winners_avx2(const RowCtx& c) {
  using F = typename Cost::Feature;
  // Everything the loop reads from c, in locals: the compiler then need not reload it after
  // each store (and dp is a constant).
  constexpr int dp = 16 * NC;
  constexpr ptrdiff_t kRow = dp + 32;  // a row of `recent`: 16 lanes of 0xFFFF either side
  const ptrdiff_t cols = c.cols, xlo = c.xlo, xhi = c.xhi;
  const int r = c.radius;
  const uint32_t* const texcol = c.texcol;
  const uint32_t* const unique_min = c.unique_min;
  WinnerRecord* const records = c.rec;
  uint16_t* const rmin = c.rmin;
  uint16_t* const rarg = c.rarg;
  uint16_t* const recent = c.recent;
  const bool lr_on = c.lr_on, count_low = c.count_low, need_second = c.need_second;
  const __m256i ones = _mm256_set1_epi16(-1);
  const __m256i padv = pad_vector(c.qpad);
  uint16_t* S = const_cast<uint16_t*>(c.colsum);

  // The fused column-sum update: column j gains the entering row's costs and loses the
  // leaving row's just before the running sum reads it (so it is read back from L1). Census:
  // the codes have 16 bits, so one 16-bit lane holds a whole code. The right rows come split
  // into nibbles (nibbles_of), so XOR with the left code's nibbles gives the vpshufb indices
  // directly; the byte counts of the entering row minus those of the leaving row (-8 .. 8),
  // summed in pairs by vpmaddubsw, give c_in - c_out. With AVX512_BITALG (the AVX-512 build)
  // the rows hold the whole codes and vpopcntw counts each XOR: one load, XOR and count per
  // 16 costs instead of two loads, two XORs, two lookups, an add and a vpmaddubsw (0.85-0.92x
  // the time of a whole call, Intel Emerald Rapids, one thread).
  const F* in_l = static_cast<const F*>(c.in_left);
  const F* in_r = static_cast<const F*>(c.in_rpad);
  const F* out_l = static_cast<const F*>(c.out_left);
  const F* out_r = static_cast<const F*>(c.out_rpad);
  const uint16_t* in16 = static_cast<const uint16_t*>(c.in_quad);
  const uint16_t* out16 = static_cast<const uint16_t*>(c.out_quad);
  const ptrdiff_t nib = c.nibble_stride;  // from the low nibbles to the high ones
  // Census: the left codes' nibbles of column j, entering (and leaving, without the ring),
  // broadcast.
  struct CensusLeft {
    __m256i in0, in1, out0, out1;
  };
  // (The left rows' nibbles follow the right rows' in the same buffers, as two more rows.)
  const uint16_t* const lin16 = in16 ? in16 + 2 * nib : nullptr;
  const uint16_t* const lout16 = out16 ? out16 + 2 * nib : nullptr;
  auto census_left = [&](ptrdiff_t j) {
    CensusLeft l;
    l.in0 = _mm256_set1_epi16(static_cast<short>(lin16[j]));
    if constexpr (!kRing) l.out0 = _mm256_set1_epi16(static_cast<short>(lout16[j]));
#if !defined(__AVX512BITALG__)  // (whole codes in in0 and out0 there)
    l.in1 = _mm256_set1_epi16(static_cast<short>(lin16[nib + j]));
    if constexpr (!kRing) l.out1 = _mm256_set1_epi16(static_cast<short>(lout16[nib + j]));
#endif
    return l;
  };
  // Census: vector i of column j updated, stored and returned (so the running sum need not
  // load it back: a store forwarded to a load adds its latency to the sum's chain). With the
  // ring, the entering row's costs are matched and kept there, the leaving row's read back;
  // without, both rows are matched (the byte counts of one minus the other's, -8 .. 8, summed
  // in pairs by vpmaddubsw).
  // The ring holds one byte per cost: the costs of vectors i and i + 1 (i even; zeros past
  // the last vector) as _mm256_packus_epi16 leaves them, which _mm256_unpacklo_epi8 and
  // _mm256_unpackhi_epi8 with zeros undo; half the bytes of 16-bit costs to store and to
  // read back (the ring exceeds L2, so they travel through L3), for one pack per pair and
  // two unpacks. Hence a pair of vectors per call.
  uint8_t* const ring_in = c.ring_in;
  const uint8_t* const ring_out = c.ring_out;
  constexpr ptrdiff_t kRingColumn = cost_ring_column_bytes(dp);
  struct Pair {
    __m256i v[2];
  };
#if defined(__AVX512BITALG__)
  // The set bits of each 16-bit lane of (l ^ r), r the whole codes at p (vpopcntw): the
  // costs themselves.
  auto count16 = [](__m256i l, const uint16_t* p) {
    return _mm256_popcnt_epi16(
        _mm256_xor_si256(l, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p))));
  };
#endif
  auto census_update = [&](const CensusLeft& l, ptrdiff_t j, int i) {
#if !defined(__AVX512BITALG__)
    const __m256i lut = nibble_popcounts();
    // Set bits of each byte of (l ^ r): the counts of its two nibbles.
    auto count = [&](__m256i l0, __m256i l1, const uint16_t* p) {
      const __m256i r0 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
      const __m256i r1 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p + nib));
      return _mm256_add_epi8(_mm256_shuffle_epi8(lut, _mm256_xor_si256(l0, r0)),
                             _mm256_shuffle_epi8(lut, _mm256_xor_si256(l1, r1)));
    };
#endif
    auto* s = reinterpret_cast<__m256i*>(S + j * dp) + i;
    const bool two = i + 1 < NC;
    __m256i d[2];
    if constexpr (kRing) {
#if defined(__AVX512BITALG__)
      const __m256i cin0 = count16(l.in0, in16 + j + 16 * i);
      const __m256i cin1 = two ? count16(l.in0, in16 + j + 16 * (i + 1)) : _mm256_setzero_si256();
#else
      const __m256i ones8 = _mm256_set1_epi8(1);
      const __m256i cin0 = _mm256_maddubs_epi16(ones8, count(l.in0, l.in1, in16 + j + 16 * i));
      const __m256i cin1 =
          two ? _mm256_maddubs_epi16(ones8, count(l.in0, l.in1, in16 + j + 16 * (i + 1)))
              : _mm256_setzero_si256();
#endif
      // Loaded before the store: the two rows share a slot (see cost_ring_rows).
      const __m256i out = _mm256_load_si256(
          reinterpret_cast<const __m256i*>(ring_out + j * kRingColumn + 16 * i));
      _mm256_store_si256(reinterpret_cast<__m256i*>(ring_in + j * kRingColumn + 16 * i),
                         _mm256_packus_epi16(cin0, cin1));
      d[0] = _mm256_sub_epi16(cin0, _mm256_unpacklo_epi8(out, _mm256_setzero_si256()));
      d[1] = _mm256_sub_epi16(cin1, _mm256_unpackhi_epi8(out, _mm256_setzero_si256()));
    } else {
      for (int h = 0; h < 1 + static_cast<int>(two); ++h) {
#if defined(__AVX512BITALG__)
        d[h] = _mm256_sub_epi16(count16(l.in0, in16 + j + 16 * (i + h)),
                                count16(l.out0, out16 + j + 16 * (i + h)));
#else
        const __m256i pin = count(l.in0, l.in1, in16 + j + 16 * (i + h));
        const __m256i pout = count(l.out0, l.out1, out16 + j + 16 * (i + h));
        d[h] = _mm256_maddubs_epi16(_mm256_set1_epi8(1), _mm256_sub_epi8(pin, pout));
#endif
      }
    }
    Pair p;
    p.v[0] = _mm256_add_epi16(_mm256_load_si256(s), d[0]);
    _mm256_store_si256(s, p.v[0]);
    if (two) {
      p.v[1] = _mm256_add_epi16(_mm256_load_si256(s + 1), d[1]);
      _mm256_store_si256(s + 1, p.v[1]);
    }
    return p;
  };
  // The same with byte column sums (kBytes, see RowCtx::byte_cols): entering minus leaving
  // costs as bytes (-16 .. 16, exact modulo 256 as the sums stay below 256), added to the
  // sums in the ring's layout; returns the column's new sums (bytes, that layout). Half the
  // bytes of 16-bit sums to load and store per column.
  auto census_update_bytes = [&](const CensusLeft& l, ptrdiff_t j, int i) {
#if defined(__AVX512BITALG__)
    const __m256i cin0 = count16(l.in0, in16 + j + 16 * i);
    const __m256i cin1 =
        i + 1 < NC ? count16(l.in0, in16 + j + 16 * (i + 1)) : _mm256_setzero_si256();
#else
    const __m256i lut = nibble_popcounts();
    auto count = [&](const uint16_t* p) {
      const __m256i r0 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
      const __m256i r1 = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p + nib));
      return _mm256_maddubs_epi16(
          _mm256_set1_epi8(1),
          _mm256_add_epi8(_mm256_shuffle_epi8(lut, _mm256_xor_si256(l.in0, r0)),
                          _mm256_shuffle_epi8(lut, _mm256_xor_si256(l.in1, r1))));
    };
    const __m256i cin0 = count(in16 + j + 16 * i);
    const __m256i cin1 = i + 1 < NC ? count(in16 + j + 16 * (i + 1)) : _mm256_setzero_si256();
#endif
    const __m256i c8 = _mm256_packus_epi16(cin0, cin1);
    const ptrdiff_t at = j * kRingColumn + 16 * i;
    // Loaded before the store: the two rows share a slot (see cost_ring_rows).
    const __m256i out = _mm256_load_si256(reinterpret_cast<const __m256i*>(ring_out + at));
    _mm256_store_si256(reinterpret_cast<__m256i*>(ring_in + at), c8);
    auto* s = reinterpret_cast<__m256i*>(reinterpret_cast<uint8_t*>(S) + at);
    const __m256i v = _mm256_add_epi8(_mm256_load_si256(s), _mm256_sub_epi8(c8, out));
    _mm256_store_si256(s, v);
    return v;
  };
  auto update_col = [&](ptrdiff_t j) {
    auto* s = reinterpret_cast<__m256i*>(S + j * dp);
    if constexpr (sizeof(F) == 4) {
      const CensusLeft l = census_left(j);
      for (int i = 0; i < NC; i += 2) {
        if constexpr (kBytes) {
          census_update_bytes(l, j, i);
        } else {
          census_update(l, j, i);
        }
      }
    } else {
      // SAD, 32 lanes of bytes at a time: |l - r| = max - min, and the entering row's cost
      // minus the leaving row's (-62 .. 62) fits a signed byte, widened for the sums. (With
      // NC odd the last load reads 16 lanes past dp, into the padded row's slack.)
      const __m256i li = _mm256_set1_epi8(static_cast<char>(in_l[j]));
      const __m256i lo = _mm256_set1_epi8(static_cast<char>(out_l[j]));
      auto cost = [](__m256i l, const uint8_t* p) {
        const __m256i r = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p));
        return _mm256_sub_epi8(_mm256_max_epu8(l, r), _mm256_min_epu8(l, r));
      };
      auto add = [&](int i, __m128i d) {
        _mm256_store_si256(s + i, _mm256_add_epi16(_mm256_load_si256(s + i),
                                                   _mm256_cvtepi8_epi16(d)));
      };
      for (int i = 0; i < NC; i += 2) {
        const __m256i d =
            _mm256_sub_epi8(cost(li, in_r + j + 16 * i), cost(lo, out_r + j + 16 * i));
        add(i, _mm256_castsi256_si128(d));
        if (i + 1 < NC) add(i + 1, _mm256_extracti128_si256(d, 1));
      }
    }
  };
  const bool fused = in_l != nullptr;
  if (fused) {
    for (ptrdiff_t j = 0; j <= r && j < cols; ++j) update_col(j);
  }

  __m256i A[NC];
  // Vector i of column j's sums, widened from bytes with kBytes.
  auto column = [&](ptrdiff_t j, int i) {
    if constexpr (kBytes) {
      const __m256i v = _mm256_load_si256(reinterpret_cast<const __m256i*>(
          reinterpret_cast<const uint8_t*>(S) + j * kRingColumn + 16 * (i & ~1)));
      return (i & 1) ? _mm256_unpackhi_epi8(v, _mm256_setzero_si256())
                     : _mm256_unpacklo_epi8(v, _mm256_setzero_si256());
    } else {
      return _mm256_load_si256(reinterpret_cast<const __m256i*>(S + j * dp) + i);
    }
  };
  for (int i = 0; i < NC; ++i) A[i] = _mm256_setzero_si256();
  uint32_t tsum = 0;
  for (ptrdiff_t dx = -r; dx <= r; ++dx) {
    const ptrdiff_t xx = clamp_index(dx, 0, cols - 1);
    for (int i = 0; i < NC; ++i) A[i] = _mm256_add_epi16(A[i], column(xx, i));
    if (texcol) tsum += texcol[xx];
  }
  // kBytes: the running block sums are kept as cost << 4 (below 2^16: every block cost is
  // below 4095 there, see RowCtx::byte_cols), the form group_winners and right_group_keyed
  // make their keys from, so `recent` holds them so too.
  constexpr bool kShifted = kBytes;
  // kShifted: the running sums also carry, in their four low bits, the key bits of their
  // vector, 15 - i (see key_low): the updates add multiples of 16, which keep them, so the
  // winner search reads its keys from `recent` as they are, one vpor less per vector and
  // pixel (right_group_keyed turns them into its own at no extra cost). Every other reader of
  // `recent` takes a cost as v >> 4, or compares v with multiples of 16.
  if constexpr (kShifted) {
    for (int i = 0; i < NC; ++i) {
      A[i] = _mm256_or_si256(_mm256_slli_epi16(A[i], 4),
                             _mm256_set1_epi16(static_cast<short>(15 - i)));
    }
  }
  A[0] = _mm256_or_si256(A[0], padv);  // padding lanes: 0xFFFF, never a winner
  // kShifted: A[i] (and A[i + 1]) += (sums of column xp - those of column xm) << 4, from the
  // byte sums of the two columns (vector pair i in the ring's layout): vpmaddubsw of their
  // interleaved bytes with 16, -16 (exact: |16 * (a - b)| <= 16 * 255 fits the int16 lanes).
  const __m256i diff16 = _mm256_set1_epi16(static_cast<short>(0xF010));
  auto column_bytes = [&](ptrdiff_t j, int i) {
    return _mm256_load_si256(reinterpret_cast<const __m256i*>(
        reinterpret_cast<const uint8_t*>(S) + j * kRingColumn + 16 * i));
  };
  // A block cost in `recent` as the records' `second` holds it (0xFFFF, no cost, stays kNone;
  // `around` keeps the form of `recent`, see RowCtx::around_shifted).
  auto cost_of = [](uint32_t v) -> uint32_t {
    if constexpr (kShifted) {
      return v >= 0xFFF0u ? kNone : v >> 4;
    } else {
      return v;
    }
  };
  // The least cost passing the uniqueness check, per winning cost, in `recent`'s form.
  const uint32_t* const unique_thr = kShifted ? c.unique_min_shifted : unique_min;
  auto add_diff = [&](int i, __m256i vp, __m256i vm) {
    A[i] = _mm256_add_epi16(A[i], _mm256_maddubs_epi16(_mm256_unpacklo_epi8(vp, vm), diff16));
    if (i + 1 < NC) {
      A[i + 1] =
          _mm256_add_epi16(A[i + 1], _mm256_maddubs_epi16(_mm256_unpackhi_epi8(vp, vm), diff16));
    }
  };

  // The winner's neighbours serve the sub-pixel step and the counted uniqueness check.
  const bool around = c.subpixel != SubpixelFit::kNone || count_low;
  for (ptrdiff_t t = 0; t < 16; ++t) {
    for (int j = 0; j < 16; ++j) {
      recent[t * kRow + j] = 0xFFFF;
      recent[t * kRow + 16 + dp + j] = 0xFFFF;
    }
  }
  if (lr_on) {
    for (ptrdiff_t i = 0; i < cols + dp + 32; ++i) rmin[i] = 0xFFFF;
  }
  const __m256i iota = lane_iota16();
  const __m256i two = _mm256_set1_epi16(2);
  uint32_t tsums[16];  // the block texture sums of the group's pixels
  // Whether every block cost is below 4095 (see right_group_keyed).
  const bool keyed =
      (2 * r + 1) * (2 * r + 1) * (sizeof(F) == 4 ? kCensusCostMax : kSadCostMax) <= 4094;

  // The winners of the group of pixels x0 .. x1 (at most 16) from their costs in `recent`.
  // Apart from the running sums, one pixel's work does not depend on another's, but its
  // chain (least cost, its lane, the uniqueness count) is long: in a loop of its own, over
  // costs already in L1, the chains of many pixels overlap, where interleaved with the
  // column-sum update the processor's window held about two pixels and waited on each.
  // The border band (clip_border): a pixel outside xlo..xhi is matched over the disparity
  // indices klo..khi whose right pixel lies inside the image (border_band's rule), here as
  // lanes qlo..qhi; the others read as 0xFFFF (above every block cost), so the winner, the
  // uniqueness data and the neighbours below come out as border_band's. Returns false when
  // no lane is inside (the pixel stays NaN).
  const ptrdiff_t min_d = c.min_d, nd = c.nd;
  const bool clip_border = c.clip_border;
  auto border_lanes = [&](ptrdiff_t x, int& qlo, int& qhi) {
    const ptrdiff_t klo = clamp_index(x - min_d - cols + 1, 0, nd);
    const ptrdiff_t khi = clamp_index(x - min_d, -1, nd - 1);
    qlo = static_cast<int>(dp - 1 - khi);
    qhi = static_cast<int>(dp - 1 - klo);
    return klo <= khi;
  };
  // All ones on the lanes of vector i outside qlo..qhi.
  auto outside = [&](int qlo, int qhi, int i) {
    const __m256i lane = _mm256_add_epi16(iota, _mm256_set1_epi16(static_cast<short>(16 * i)));
    return _mm256_or_si256(_mm256_cmpgt_epi16(_mm256_set1_epi16(static_cast<short>(qlo)), lane),
                           _mm256_cmpgt_epi16(lane, _mm256_set1_epi16(static_cast<short>(qhi))));
  };
  // Whether every value `recent` holds for a real cost, and every threshold of unique_thr,
  // is below 0x7FFF, so that signed 16-bit compares order them (block sizes up to 11 with
  // byte column sums: 121 * 16 << 4 = 30976; BlockMatcher caps the thresholds at 0x7FFF
  // then, which changes no unsigned comparison with a cost).
  const int qpad = c.qpad;
  const bool low_signed =
      kShifted && (2 * r + 1) * (2 * r + 1) * kCensusCostMax * 16 < 0x7FFF;
  __m256i key_low[NC];  // 15 - i in every lane (see group_winners)
  for (int i = 0; i < NC; ++i) {
    key_low[i] = _mm256_set1_epi16(static_cast<short>(15 - i));
    // Kept as values: GCC would otherwise rebuild each constant in the loop (three
    // instructions) rather than read it. (With kShifted the loops do not use them.)
    if constexpr (!kShifted) __asm__("" : "+x"(key_low[i]));
  }
  // kFast (std::true_type): the defaults' case, keyed, with the uniqueness count and the
  // winner's neighbours, decided once per group rather than tested per pixel.
  // kInner (std::true_type): every pixel of the group has its whole search range in the
  // image (xlo <= x0, x1 <= xhi), so none takes the border band's masks. Tested per pixel,
  // GCC computed those masks (lane compares against qlo and qhi, about 20 instructions) for
  // every pixel and ORed them in, branch-free.
  // kBand (inner = std::integral_constant<int, 2>): every pixel of the group lies in the left
  // border band or inside, has a lane inside, and is matched over lanes qlo .. dp - 1 (klo is
  // 0: only disparities beyond x - min_d leave the image), with kLowSigned. The two-pixel loop
  // takes these too, its masks one compare per vector (on Jadeplant, a quarter of the pixels
  // are in the band; the loop one pixel at a time took about a tenth of the first pass).
  auto group_winners = [&](ptrdiff_t x0, ptrdiff_t x1, auto fast, auto inner, auto low_signed) {
    constexpr bool kFast = decltype(fast)::value;
    constexpr bool kInner = static_cast<int>(decltype(inner)::value) == 1;
    constexpr bool kBand = static_cast<int>(decltype(inner)::value) == 2;
    constexpr bool kLowSigned = decltype(low_signed)::value;
    const bool keyed_ = kFast || kShifted || keyed;
    const bool count_low_ = kFast || count_low;
    const bool around_ = kFast || around;
    // Without keys, in two loops: the least costs first (a short chain), then the rest, which
    // starts from the least cost in memory; each loop's chain is then short enough for the
    // processor to overlap several pixels.
    alignas(32) uint16_t bests[16];
    for (ptrdiff_t x = x0; x <= x1 && !keyed_; ++x) {
      const uint16_t* const row = recent + (x - x0) * kRow + 16;
      auto load = [&](int i) {
        return _mm256_load_si256(reinterpret_cast<const __m256i*>(row) + i);
      };
      int qlo = 0, qhi = -1;
      const bool border = !kInner && (x < xlo || x > xhi);
      if (border && !(clip_border && border_lanes(x, qlo, qhi))) continue;  // no search
      // The least cost, in four chains of minima (a quarter of one chain's latency).
      __m256i mins[4] = {ones, ones, ones, ones};
      if (border) {
        for (int i = 0; i < NC; ++i) {
          mins[0] = _mm256_min_epu16(mins[0], _mm256_or_si256(load(i), outside(qlo, qhi, i)));
        }
      } else {
        for (int i = 0; i < NC; ++i) mins[i & 3] = _mm256_min_epu16(mins[i & 3], load(i));
      }
      const __m256i m = _mm256_min_epu16(_mm256_min_epu16(mins[0], mins[1]),
                                         _mm256_min_epu16(mins[2], mins[3]));
      bests[x - x0] = static_cast<uint16_t>(_mm_cvtsi128_si32(_mm_minpos_epu16(
          _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1)))));
    }
    ptrdiff_t xstart = x0;
    if constexpr (kFast && (kInner || kBand)) {
      static_assert(!kBand || kLowSigned, "the band's masked lanes are counted out as signed");
      // Two pixels at a time, each step for both before the next, so that the second
      // pixel's work sits beside the first's long chain (minima, vphminposuw, the key in a
      // general register, the threshold's load, the count).
      constexpr int kP = 2;
      for (; xstart + kP - 1 <= x1; xstart += kP) {
        const uint16_t* rows_[kP];
        __m256i k[kP];
        __m128i m[kP];
        uint32_t key[kP], best[kP], eq[kP], second[kP];
        int qb[kP];
        for (int p = 0; p < kP; ++p) rows_[p] = recent + (xstart + p - x0) * kRow + 16;
        // The first lane searched (border_lanes' qlo; qpad inside), and in the band, the
        // lanes below it as 0xFFFF.
        int qlo[kP];
        __m256i qlo_v[kP];
        for (int p = 0; p < kP; ++p) {
          qlo[p] = kBand ? std::max(static_cast<int>(dp - 1 - (xstart + p - min_d)), qpad) : qpad;
          qlo_v[p] = _mm256_set1_epi16(static_cast<short>(qlo[p]));
        }
        auto lv = [&](int p, int i) {
          const __m256i v = _mm256_load_si256(reinterpret_cast<const __m256i*>(rows_[p]) + i);
          if constexpr (kBand) {
            const __m256i lane =
                _mm256_add_epi16(iota, _mm256_set1_epi16(static_cast<short>(16 * i)));
            return _mm256_or_si256(v, _mm256_cmpgt_epi16(qlo_v[p], lane));
          } else {
            return v;
          }
        };
        for (int p = 0; p < kP; ++p) {
          auto key_of = [&](int i) {
            return kShifted ? lv(p, i)
                            : _mm256_or_si256(_mm256_slli_epi16(lv(p, i), 4), key_low[i]);
          };
          __m256i kmin[2] = {key_of(0), NC > 1 ? key_of(1) : ones};
          for (int i = 2; i < NC; ++i) kmin[i & 1] = _mm256_min_epu16(kmin[i & 1], key_of(i));
          k[p] = _mm256_min_epu16(kmin[0], kmin[1]);
        }
        for (int p = 0; p < kP; ++p) {
          m[p] = _mm_minpos_epu16(
              _mm_min_epu16(_mm256_castsi256_si128(k[p]), _mm256_extracti128_si256(k[p], 1)));
        }
        for (int p = 0; p < kP; ++p) {
          key[p] = static_cast<uint32_t>(_mm_cvtsi128_si32(m[p])) & 0xFFFFu;
          eq[p] = static_cast<uint32_t>(
              _mm256_movemask_epi8(_mm256_cmpeq_epi16(k[p], _mm256_broadcastw_epi16(m[p]))));
        }
        for (int p = 0; p < kP; ++p) {
          best[p] = key[p] >> 4;
          // (31 ^ clz is 31 - clz, the highest set bit: one bsr.)
          qb[p] = static_cast<int>(16 * (15 - (key[p] & 15u)) +
                                   ((31 ^ __builtin_clz(eq[p])) >> 1));
        }
        if constexpr (kLowSigned) {
          static_assert(kP == 2, "the count below sums two pixels' lanes at once");
          // Every block cost << 4 and every threshold is below 0x7FFF here (see low_signed):
          // one signed compare per vector gives -1 on the lanes below the threshold, summed
          // per lane (-NC .. 0); the two pixels' sums packed to bytes, made positive and
          // added up by vpsadbw (eight bytes per 64-bit lane: pixel 0's lanes 0-7, pixel
          // 1's, pixel 0's 8-15, pixel 1's). The padding lanes (0xFFFF, -1 as signed) are
          // among those counted, and are taken back out (in the band, every lane below qlo).
          __m256i sum[kP];
          for (int p = 0; p < kP; ++p) {
            const __m256i thr = _mm256_set1_epi32(static_cast<int>(unique_thr[best[p]]));
            auto below = [&](int i) { return _mm256_cmpgt_epi16(thr, lv(p, i)); };
            __m256i part[2] = {below(0), NC > 1 ? below(1) : _mm256_setzero_si256()};
            for (int i = 2; i < NC; ++i) part[i & 1] = _mm256_add_epi16(part[i & 1], below(i));
            sum[p] = _mm256_add_epi16(part[0], part[1]);
          }
          const __m256i per8 = _mm256_sad_epu8(
              _mm256_abs_epi8(_mm256_packs_epi16(sum[0], sum[1])), _mm256_setzero_si256());
          const __m128i both =
              _mm_add_epi32(_mm256_castsi256_si128(per8), _mm256_extracti128_si256(per8, 1));
          second[0] = static_cast<uint32_t>(_mm_cvtsi128_si32(both) - qlo[0]);
          second[1] = static_cast<uint32_t>(_mm_extract_epi32(both, 2) - qlo[1]);
        } else {
          for (int p = 0; p < kP; ++p) {
            const __m256i thr = _mm256_set1_epi32(static_cast<int>(unique_thr[best[p]]));
            auto at_least = [&](int i) {
              return _mm256_cmpeq_epi16(_mm256_min_epu16(lv(p, i), thr), thr);
            };
            uint32_t high = 0;
            for (int i = 0; i < NC; i += 2) {
              const __m256i mk =
                  _mm256_packs_epi16(at_least(i), i + 1 < NC ? at_least(i + 1) : ones);
              high += static_cast<uint32_t>(__builtin_popcount(
                  static_cast<uint32_t>(_mm256_movemask_epi8(mk))));
            }
            second[p] = static_cast<uint32_t>(16 * (NC + (NC & 1))) - high;
          }
        }
        for (int p = 0; p < kP; ++p) {
          const ptrdiff_t x = xstart + p;
          WinnerRecord* rec = records + x;
          rec->best = static_cast<uint16_t>(best[p]);
          rec->second = static_cast<uint16_t>(second[p]);
          rec->kbest = dp - 1 - qb[p];
          if (texcol) rec->tsum = tsums[x - x0];  // (read only with the texture check)
          // (In the band the lane below the winner may be outside the lanes searched: none.)
          const uint32_t c2 = !kBand || qb[p] - 1 >= qlo[p] ? rows_[p][qb[p] - 1] : kNone;
          rec->around = static_cast<uint32_t>(rows_[p][qb[p] + 1]) | (c2 << 16);
        }
      }
    }
    for (ptrdiff_t x = xstart; x <= x1; ++x) {
      const uint16_t* const row = recent + (x - x0) * kRow + 16;
      __m256i V[NC];
      for (int i = 0; i < NC; ++i) {
        V[i] = _mm256_load_si256(reinterpret_cast<const __m256i*>(row) + i);
      }
      int qlo = 0, qhi = dp - 1;  // the lanes searched
      const bool border = !kInner && (x < xlo || x > xhi);
      if (border) {
        if (!clip_border || !border_lanes(x, qlo, qhi)) {
          record_none(c, x);
          continue;
        }
        for (int i = 0; i < NC; ++i) V[i] = _mm256_or_si256(V[i], outside(qlo, qhi, i));
      }
      uint32_t best = 0;
      int qb = 0;
      if (keyed_) {
        // The winner with its cost in one pass: keys cost << 4 | (15 - i) for vector i (every
        // cost is below 4095, and the 0xFFFF lanes give keys of at least 0xFFF0, above every
        // real one), so that the least key per lane is the least cost and, among equal costs,
        // the last vector (the highest lane); across the 16 lanes, the least key's highest
        // lane. (One loop with the rest: its chain is short enough to overlap pixels.)
        auto key_of = [&](int i) {
          return kShifted ? V[i] : _mm256_or_si256(_mm256_slli_epi16(V[i], 4), key_low[i]);
        };
        __m256i kmin[2] = {key_of(0), NC > 1 ? key_of(1) : ones};
        for (int i = 2; i < NC; ++i) kmin[i & 1] = _mm256_min_epu16(kmin[i & 1], key_of(i));
        const __m256i k = _mm256_min_epu16(kmin[0], kmin[1]);
        const uint32_t key =
            static_cast<uint32_t>(_mm_cvtsi128_si32(_mm_minpos_epu16(_mm_min_epu16(
                _mm256_castsi256_si128(k), _mm256_extracti128_si256(k, 1))))) &
            0xFFFFu;
        const auto eq = static_cast<uint32_t>(_mm256_movemask_epi8(
            _mm256_cmpeq_epi16(k, _mm256_set1_epi16(static_cast<short>(key)))));
        best = key >> 4;
        qb = static_cast<int>(16 * (15 - (key & 15u)) + (31 - __builtin_clz(eq)) / 2);
      } else {
        best = bests[x - x0];
        const __m256i bv = _mm256_set1_epi16(static_cast<short>(bests[x - x0]));
        // The winner: the highest lane holding the least cost (the lowest disparity on a
        // tie), branch-free (which vector holds the winner changes from pixel to pixel, and a
        // mispredicted branch costs more than this whole selection), four vectors (64 lanes)
        // at a time: the comparison masks of two vectors packed to bytes (vpacksswb
        // interleaves their 128-bit halves, vpermq puts them back in order) give one bit per
        // lane.
        for (int g = 0; g < NC; g += 4) {
          auto eq = [&](int k) {
            return k < NC ? _mm256_cmpeq_epi16(V[k], bv) : _mm256_setzero_si256();
          };
          auto bits = [&](int k) {
            const __m256i m = _mm256_permute4x64_epi64(_mm256_packs_epi16(eq(k), eq(k + 1)), 0xD8);
            return static_cast<std::uint64_t>(static_cast<uint32_t>(_mm256_movemask_epi8(m)));
          };
          std::uint64_t w = bits(g);
          if (g + 2 < NC) w |= bits(g + 2) << 32;
          const int top = 16 * g + 63 - __builtin_clzll(w | 1u);
          const int found = -static_cast<int>(w != 0);  // all ones when this group holds the least
          qb ^= (qb ^ top) & found;
        }
      }
      uint32_t second = kNone;
      if (count_low_) {
        // How many lanes cost less than the uniqueness threshold (this does not wait for the
        // winner's lane): the lanes >= it are those with min(a, thr) == thr; two vectors'
        // masks packed to bytes give one bit per lane.
        const __m256i thr = _mm256_set1_epi32(static_cast<int>(unique_thr[best]));
        auto at_least = [&](int k) {
          return _mm256_cmpeq_epi16(_mm256_min_epu16(V[k], thr), thr);
        };
        uint32_t high = 0;
        for (int i = 0; i < NC; i += 2) {
          const __m256i m = _mm256_packs_epi16(at_least(i), i + 1 < NC ? at_least(i + 1) : ones);
          high += static_cast<uint32_t>(__builtin_popcount(
              static_cast<uint32_t>(_mm256_movemask_epi8(m))));
        }
        second = static_cast<uint32_t>(16 * (NC + (NC & 1))) - high;
      } else if (need_second) {
        // The exact second-best cost, for the confidence: lanes qb - 1 .. qb + 1 are those
        // with (lane - (qb - 1)) <= 2, unsigned.
        __m256i m2 = ones;
        for (int i = 0; i < NC; ++i) {
          const __m256i rel =
              _mm256_sub_epi16(iota, _mm256_set1_epi16(static_cast<short>(qb - 1 - 16 * i)));
          const __m256i ex = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, two), rel);
          m2 = _mm256_min_epu16(m2, _mm256_or_si256(V[i], ex));
        }
        second = cost_of(hmin_epu16(m2));
      }
      WinnerRecord* rec = records + x;
      rec->best = static_cast<uint16_t>(best);
      rec->second = static_cast<uint16_t>(second);
      rec->kbest = dp - 1 - qb;
      rec->tsum = tsums[x - x0];
      // c0 | c2 << 16: lanes qb + 1 and qb - 1 (disparity index kb - 1 and kb + 1). Beyond
      // the lanes `recent` holds 0xFFFF where the other passes store 0: the second pass reads
      // neither (it needs 1 <= kb <= nd - 2).
      // In the border band a neighbour outside the lanes searched reads as 0xFFFF, which
      // the second pass takes as "no sub-pixel step" (border_band's rule).
      // Inside the border (qlo = 0, qhi = dp - 1) the tests are not needed: lanes -1 and dp
      // of `recent` hold 0xFFFF, i.e. kNone, and a padding lane beside the winner holds its
      // block sum ORed with 0xFFFF.
      uint32_t around_costs = 0;
      if (around_) {
        if (border) {
          const uint32_t c0 = qb + 1 <= qhi ? row[qb + 1] : kNone;
          const uint32_t c2 = qb - 1 >= qlo ? row[qb - 1] : kNone;
          around_costs = c0 | (c2 << 16);
        } else {
          around_costs =
              static_cast<uint32_t>(row[qb + 1]) | (static_cast<uint32_t>(row[qb - 1]) << 16);
        }
      }
      rec->around = around_costs;
    }
  };

  // Along the row, 16 pixels at a time: the block sums of each pixel go to `recent`, then
  // the right winners and the winners of those pixels are found. A group whose columns all
  // have their block inside the row (no clamping) and whose column sums are updated here
  // takes the short path.
  for (ptrdiff_t x0 = 0; x0 < cols; x0 += 16) {
    const ptrdiff_t x1 = std::min<ptrdiff_t>(x0 + 16, cols);
    uint16_t* row = recent + 16;
    constexpr bool kSplitRow = sizeof(F) == 4 && kBytes && NC >= 8;
    if (kSplitRow && fused && x0 > r && x1 + r <= cols) {
     if constexpr (kSplitRow) {
      // Many vectors (ndisp >= 128): the group's pixels in two passes over the lanes, each
      // with its half of the running sums, which then fit the 16 registers with the
      // constants (in one pass GCC kept several in memory, a store and a load per pixel).
      // The passes touch different lanes of the same columns: the same sums as one pass.
      constexpr int kSplit = (NC / 2 + 1) / 2 * 2;  // an even number of vectors first
      auto pass = [&](auto ib_, auto ie_) {
        constexpr int ib = decltype(ib_)::value, ie = decltype(ie_)::value;
        uint16_t* rowp = recent + 16;
        for (ptrdiff_t x = x0; x < x1; ++x, rowp += kRow) {
          const ptrdiff_t xp = x + r, xm = x - r - 1;
          const CensusLeft l = census_left(xp);
          for (int i = ib; i < ie; i += 2) {
            add_diff(i, census_update_bytes(l, xp, i), column_bytes(xm, i));
          }
          if constexpr (ib == 0) A[0] = _mm256_or_si256(A[0], padv);
          for (int i = ib; i < ie; ++i) {
            _mm256_store_si256(reinterpret_cast<__m256i*>(rowp) + i, A[i]);
          }
          if constexpr (ib == 0) {
            if (texcol) tsum += texcol[xp] - texcol[xm];
            tsums[x - x0] = tsum;
          }
        }
      };
      pass(std::integral_constant<int, 0>{}, std::integral_constant<int, kSplit>{});
      pass(std::integral_constant<int, kSplit>{}, std::integral_constant<int, NC>{});
     }
    } else if (fused && x0 > r && x1 + r <= cols) {
      for (ptrdiff_t x = x0; x < x1; ++x, row += kRow) {
        const ptrdiff_t xp = x + r, xm = x - r - 1;
        if constexpr (sizeof(F) == 4) {
          const CensusLeft l = census_left(xp);
          for (int i = 0; i < NC; i += 2) {
            if constexpr (kBytes) {
              add_diff(i, census_update_bytes(l, xp, i), column_bytes(xm, i));
            } else {
              const Pair p = census_update(l, xp, i);
              A[i] = _mm256_sub_epi16(_mm256_add_epi16(A[i], p.v[0]), column(xm, i));
              if (i + 1 < NC) {
                A[i + 1] = _mm256_sub_epi16(_mm256_add_epi16(A[i + 1], p.v[1]), column(xm, i + 1));
              }
            }
          }
        } else {
          update_col(xp);
          for (int i = 0; i < NC; ++i) {
            A[i] = _mm256_sub_epi16(_mm256_add_epi16(A[i], column(xp, i)), column(xm, i));
          }
        }
        A[0] = _mm256_or_si256(A[0], padv);  // (padv is 0 when there is no padding)
        if (texcol) tsum += texcol[xp] - texcol[xm];
        for (int i = 0; i < NC; ++i) _mm256_store_si256(reinterpret_cast<__m256i*>(row) + i, A[i]);
        tsums[x - x0] = tsum;
      }
    } else {
      for (ptrdiff_t x = x0; x < x1; ++x, row += kRow) {
        if (x > 0) {
          const ptrdiff_t xp = clamp_index(x + r, 0, cols - 1);
          const ptrdiff_t xm = clamp_index(x - r - 1, 0, cols - 1);
          if constexpr (sizeof(F) == 4) {
            if (fused && x + r < cols) {
              const CensusLeft l = census_left(x + r);
              for (int i = 0; i < NC; i += 2) {
                if constexpr (kBytes) {
                  add_diff(i, census_update_bytes(l, x + r, i), column_bytes(xm, i));
                } else {
                  const Pair p = census_update(l, x + r, i);
                  A[i] = _mm256_sub_epi16(_mm256_add_epi16(A[i], p.v[0]), column(xm, i));
                  if (i + 1 < NC) {
                    A[i + 1] =
                        _mm256_sub_epi16(_mm256_add_epi16(A[i + 1], p.v[1]), column(xm, i + 1));
                  }
                }
              }
            } else if constexpr (kBytes) {
              for (int i = 0; i < NC; i += 2) add_diff(i, column_bytes(xp, i), column_bytes(xm, i));
            } else {
              for (int i = 0; i < NC; ++i) {
                A[i] = _mm256_sub_epi16(_mm256_add_epi16(A[i], column(xp, i)), column(xm, i));
              }
            }
          } else {
            if (fused && x + r < cols) update_col(x + r);
            for (int i = 0; i < NC; ++i) {
              A[i] = _mm256_sub_epi16(_mm256_add_epi16(A[i], column(xp, i)), column(xm, i));
            }
          }
          A[0] = _mm256_or_si256(A[0], padv);
          if (texcol) tsum += texcol[xp] - texcol[xm];
        }
        for (int i = 0; i < NC; ++i) _mm256_store_si256(reinterpret_cast<__m256i*>(row) + i, A[i]);
        tsums[x - x0] = tsum;
      }
    }
    const int n = static_cast<int>(x1 - x0);
    if (lr_on) {
      if (kShifted || keyed) {
        right_group_keyed<NC, kShifted>(recent, rmin, rarg, x0, n);
      } else {
        right_group<NC>(recent, rmin, rarg, x0, n);
      }
    }
    if (keyed && count_low && around) {
      if (x0 >= xlo && x1 - 1 <= xhi) {
        if (low_signed) {
          group_winners(x0, x1 - 1, std::true_type{}, std::true_type{}, std::true_type{});
        } else {
          group_winners(x0, x1 - 1, std::true_type{}, std::true_type{}, std::false_type{});
        }
      } else if (low_signed && clip_border && x0 >= min_d && x1 - 1 <= xhi) {
        group_winners(x0, x1 - 1, std::true_type{}, std::integral_constant<int, 2>{},
                      std::true_type{});
      } else {
        group_winners(x0, x1 - 1, std::true_type{}, std::false_type{}, std::false_type{});
      }
    } else {
      group_winners(x0, x1 - 1, std::false_type{}, std::false_type{}, std::false_type{});
    }
  }
}

// Whether the fixed first pass takes its byte-column-sum form (winners_avx2 with kBytes),
// which leaves the records' `around` as cost << 4 (RowCtx::around_shifted).
template <typename Cost>
bool byte_sum_pass(const RowCtx& c) {
  return sizeof(typename Cost::Feature) == 4 && c.byte_cols;
}

// The first pass for dp = kLanes * NC when NC <= kMaxChunks; false otherwise.
template <int NC, typename Cost>
bool winners_fixed(const RowCtx& c) {
  if constexpr (NC > kMaxChunks) {
    (void)c;
    return false;
  } else {
    if (c.dp == kLanes * NC) {
      if constexpr (sizeof(typename Cost::Feature) == 4) {
        if (byte_sum_pass<Cost>(c)) {
          winners_avx2<NC, Cost, true, true>(c);
        } else if (c.ring_in != nullptr) {
          winners_avx2<NC, Cost, true, false>(c);
        } else {
          winners_avx2<NC, Cost, false, false>(c);
        }
      } else {
        winners_avx2<NC, Cost, false, false>(c);
      }
      return true;
    }
    return winners_fixed<NC + 1, Cost>(c);
  }
}

#endif


// Second pass, one pixel at a time: the checks, the sub-pixel step and the outputs. (The
// SIMD builds use decide_avx2, which gives the same results.)
[[maybe_unused]] void decide_generic(const RowCtx& c) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (ptrdiff_t x = 0; x < c.cols; ++x) {
    const WinnerRecord& rec = c.rec[x];
    const uint32_t b = rec.best;
    const uint32_t s2 = rec.second;
    const int kb = rec.kbest;
    const bool has2 = s2 != kNone;
    bool ok = b != kNone;
    if (ok && c.texcol) ok = !(static_cast<double>(rec.tsum) < c.texture_sum_min);
    if (ok && c.uniqueness_factor > 0 && has2) {
      ok = static_cast<double>(s2) * 100.0 > static_cast<double>(b) * c.uniqueness_factor;
    }
    if (ok && c.lr_on) {
      const ptrdiff_t i = x + (c.dp - 1 - kb);
      const int kr = static_cast<uint16_t>(c.rarg[i] - i + c.dp - 1);
      const int diff = kb > kr ? kb - kr : kr - kb;
      ok = static_cast<double>(diff) <= c.lr_max_diff;
    }
    if (!ok) {
      c.drow[x] = nan;
      if (c.crow) c.crow[x] = 0.0f;
      continue;
    }
    float d = static_cast<float>(c.min_d + kb);
    if (c.subpixel != SubpixelFit::kNone && kb >= 1 && kb <= c.nd - 2) {
      const int32_t c0 = static_cast<int32_t>(rec.around & 0xFFFFu);
      const int32_t c1 = static_cast<int32_t>(b);
      const int32_t c2 = static_cast<int32_t>(rec.around >> 16);
      const float num = static_cast<float>(c0 - c2);
      float den;
      if (c.subpixel == SubpixelFit::kParabola) {
        den = static_cast<float>(2 * (c0 + c2 - 2 * c1));
      } else {
        den = static_cast<float>(2 * (c0 - c1 > c2 - c1 ? c0 - c1 : c2 - c1));
      }
      if (den > 0.0f) d = d + num / den;
    }
    c.drow[x] = d;
    if (c.crow) {
      c.crow[x] = !has2 ? 1.0f
                  : s2 > 0 ? static_cast<float>(s2 - b) / static_cast<float>(s2)
                           : 0.0f;
    }
  }
}

#if defined(STEREODEPTH_BM_AVX2)

// 8 int32 lanes as two vectors of 4 doubles (exact).
inline __m256d low_pd(__m256i v) { return _mm256_cvtepi32_pd(_mm256_castsi256_si128(v)); }
inline __m256d high_pd(__m256i v) { return _mm256_cvtepi32_pd(_mm256_extracti128_si256(v, 1)); }

// Two vectors of 4 double-comparison masks as one of 8 int32 masks, in order.
inline __m256i masks_of(__m256d lo, __m256d hi) {
  const __m256i even = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
  auto half = [&](__m256d m) {
    return _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(m), even));
  };
  return _mm256_inserti128_si256(_mm256_castsi128_si256(half(lo)), half(hi), 1);
}

// Second pass, 8 pixels at a time; the same IEEE operations as decide_generic. Lane masks are
// all ones (true) or zero; every integer here is below 2^31, so signed compares serve.
void decide_avx2(const RowCtx& c) {
  const ptrdiff_t cols = c.cols;
  const int dp = c.dp;
  const bool sub = c.subpixel != SubpixelFit::kNone;
  const bool parabola = c.subpixel == SubpixelFit::kParabola;
  const __m256i none = _mm256_set1_epi32(static_cast<int>(kNone));
  const __m256i low16 = _mm256_set1_epi32(0xFFFF);
  const __m256i iota = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i zero = _mm256_setzero_si256();
  const __m256i all = _mm256_set1_epi32(-1);
  const __m256 nan = _mm256_set1_ps(std::numeric_limits<float>::quiet_NaN());
  // kb >= 1 and kb <= nd - 2: the winner has both neighbours.
  auto interior = [&](__m256i kb) {
    return _mm256_andnot_si256(_mm256_cmpgt_epi32(kb, _mm256_set1_epi32(c.nd - 2)),
                               _mm256_cmpgt_epi32(kb, zero));
  };
  // The sub-pixel step of the disparities d (winner kb, its cost b, its neighbours' c0 and c2)
  // in the lanes of ok that have both neighbours and a positive denominator. The other lanes'
  // quotients (perhaps of a zero) are dropped. A neighbour of 0xFFFF lies outside the
  // disparities searched (the border band, see winners_avx2): no step.
  auto subpixel_step = [&](__m256 d, __m256i kb, __m256i b, __m256i c0, __m256i c2,
                           __m256i ok) {
    const __m256 num = _mm256_cvtepi32_ps(_mm256_sub_epi32(c0, c2));
    __m256i den_i;
    if (parabola) {
      den_i = _mm256_sub_epi32(_mm256_add_epi32(c0, c2), _mm256_add_epi32(b, b));
    } else {
      den_i = _mm256_max_epi32(_mm256_sub_epi32(c0, b), _mm256_sub_epi32(c2, b));
    }
    const __m256 den = _mm256_cvtepi32_ps(_mm256_add_epi32(den_i, den_i));
    const __m256i both = _mm256_andnot_si256(
        _mm256_or_si256(_mm256_cmpeq_epi32(c0, none), _mm256_cmpeq_epi32(c2, none)),
        _mm256_and_si256(ok, interior(kb)));
    const __m256 use = _mm256_and_ps(_mm256_castsi256_ps(both),
                                     _mm256_cmp_ps(den, _mm256_setzero_ps(), _CMP_GT_OQ));
    return _mm256_blendv_ps(d, _mm256_add_ps(d, _mm256_div_ps(num, den)), use);
  };
  // An integer disparity difference d passes the left-right check when d <= lr_max_diff,
  // that is d <= floor(lr_max_diff).
  const int lr_int = c.lr_max_diff >= 65536.0 ? 65536 : static_cast<int>(std::floor(c.lr_max_diff));
  // The winners' neighbours' costs, c0 | c2 << 16, from the records' `around` (kNone stays
  // kNone): as they are, or from cost << 4 when the first pass kept that form
  // (RowCtx::around_shifted).
  const bool around_shifted = c.around_shifted;
  const __m256i none_from = _mm256_set1_epi16(static_cast<short>(0xFFF0));
  auto neighbours = [&](__m256i v) {
    if (!around_shifted) return v;
    const __m256i none16 = _mm256_cmpeq_epi16(_mm256_max_epu16(v, none_from), v);
    return _mm256_or_si256(_mm256_srli_epi16(v, 4), none16);
  };
  // The transpose below leaves the pixels in the order 0, 2, 4, 6, 1, 3, 5, 7.
  const __m256i unshuffle = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
  ptrdiff_t xstart = 0;
  if (c.count_low && c.lr_on && c.texcol == nullptr && c.crow == nullptr && sub) {
    // The defaults' case, 16 pixels at a time: each step for both groups of 8 before the
    // next, so that the two groups' gathers (the threshold, the right winner) overlap rather
    // than each group waiting on its own. The same arithmetic as the loop below.
    constexpr int kU = 2;
    const __m256i nd2 = _mm256_set1_epi32(c.nd - 2);
    const __m256i lr_v = _mm256_set1_epi32(lr_int);
    const __m256i dp1 = _mm256_set1_epi32(dp - 1);
    const __m256i mind = _mm256_set1_epi32(c.min_d);
    for (; xstart + 8 * kU <= cols; xstart += 8 * kU) {
      __m256i f0[kU], kb[kU], nb[kU], ok[kU], thr[kU], g[kU], iv[kU];
      for (int u = 0; u < kU; ++u) {
        const __m256i* rv = reinterpret_cast<const __m256i*>(c.rec + xstart + 8 * u);
        const __m256i r0 = _mm256_loadu_si256(rv), r1 = _mm256_loadu_si256(rv + 1);
        const __m256i r2 = _mm256_loadu_si256(rv + 2), r3 = _mm256_loadu_si256(rv + 3);
        const __m256i t0 = _mm256_unpacklo_epi32(r0, r1), t1 = _mm256_unpackhi_epi32(r0, r1);
        const __m256i t2 = _mm256_unpacklo_epi32(r2, r3), t3 = _mm256_unpackhi_epi32(r2, r3);
        f0[u] = _mm256_permutevar8x32_epi32(_mm256_unpacklo_epi64(t0, t2), unshuffle);
        kb[u] = _mm256_permutevar8x32_epi32(_mm256_unpackhi_epi64(t0, t2), unshuffle);
        nb[u] = neighbours(_mm256_permutevar8x32_epi32(_mm256_unpackhi_epi64(t1, t3), unshuffle));
        ok[u] = _mm256_xor_si256(_mm256_cmpeq_epi32(_mm256_and_si256(f0[u], low16), none), all);
      }
      for (int u = 0; u < kU; ++u) {
        thr[u] = _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(c.unique_min),
                                             _mm256_and_si256(f0[u], low16), ok[u], 4);
      }
      for (int u = 0; u < kU; ++u) {
        const __m256i t = _mm256_and_si256(thr[u], low16);
        const __m256i c0 = _mm256_and_si256(nb[u], low16);
        const __m256i c2 = _mm256_srli_epi32(nb[u], 16);
        const __m256i low0 =
            _mm256_and_si256(_mm256_cmpgt_epi32(kb[u], zero), _mm256_cmpgt_epi32(t, c0));
        const __m256i low2 =
            _mm256_andnot_si256(_mm256_cmpgt_epi32(kb[u], nd2), _mm256_cmpgt_epi32(t, c2));
        const __m256i near = _mm256_sub_epi32(_mm256_sub_epi32(_mm256_set1_epi32(1), low0), low2);
        ok[u] = _mm256_and_si256(ok[u], _mm256_cmpeq_epi32(_mm256_srli_epi32(f0[u], 16), near));
        const __m256i xs =
            _mm256_add_epi32(_mm256_set1_epi32(static_cast<int>(xstart + 8 * u)), iota);
        iv[u] = _mm256_sub_epi32(_mm256_add_epi32(xs, dp1), kb[u]);
      }
      for (int u = 0; u < kU; ++u) {
        const int* rarg = reinterpret_cast<const int*>(c.rarg);
        g[u] = _mm256_mask_i32gather_epi32(zero, rarg, iv[u], ok[u], 2);
      }
      for (int u = 0; u < kU; ++u) {
        const __m256i kr =
            _mm256_and_si256(_mm256_add_epi32(_mm256_sub_epi32(g[u], iv[u]), dp1), low16);
        const __m256i diff = _mm256_abs_epi32(_mm256_sub_epi32(kb[u], kr));
        ok[u] = _mm256_andnot_si256(_mm256_cmpgt_epi32(diff, lr_v), ok[u]);
        const __m256i b = _mm256_and_si256(f0[u], low16);
        const __m256i c0 = _mm256_and_si256(nb[u], low16);
        const __m256i c2 = _mm256_srli_epi32(nb[u], 16);
        const __m256 d = subpixel_step(_mm256_cvtepi32_ps(_mm256_add_epi32(kb[u], mind)), kb[u],
                                       b, c0, c2, ok[u]);
        _mm256_storeu_ps(c.drow + xstart + 8 * u,
                         _mm256_blendv_ps(nan, d, _mm256_castsi256_ps(ok[u])));
      }
    }
  }
  for (ptrdiff_t x = xstart; x < cols; x += 8) {
    const int n = static_cast<int>(cols - x < 8 ? cols - x : 8);
    const __m256i lanes = _mm256_cmpgt_epi32(_mm256_set1_epi32(n), iota);
    // 8 records, two per vector: a 4 x 4 transpose in each 128-bit half gives the fields of
    // pixels 0, 2, 4, 6 (low half) and 1, 3, 5, 7 (high half).
    const __m256i* rv = reinterpret_cast<const __m256i*>(c.rec + x);
    const __m256i r0 = _mm256_loadu_si256(rv), r1 = _mm256_loadu_si256(rv + 1);
    const __m256i r2 = _mm256_loadu_si256(rv + 2), r3 = _mm256_loadu_si256(rv + 3);
    const __m256i t0 = _mm256_unpacklo_epi32(r0, r1), t1 = _mm256_unpackhi_epi32(r0, r1);
    const __m256i t2 = _mm256_unpacklo_epi32(r2, r3), t3 = _mm256_unpackhi_epi32(r2, r3);
    auto order = [&](__m256i v) { return _mm256_permutevar8x32_epi32(v, unshuffle); };
    const __m256i f0 = order(_mm256_unpacklo_epi64(t0, t2));  // best | second << 16
    const __m256i kb = order(_mm256_unpackhi_epi64(t0, t2));
    const __m256i b = _mm256_and_si256(f0, low16);
    const __m256i s2 = _mm256_srli_epi32(f0, 16);
    const __m256i has2 = _mm256_xor_si256(_mm256_cmpeq_epi32(s2, none), all);
    __m256i ok = _mm256_andnot_si256(_mm256_cmpeq_epi32(b, none), lanes);
    if (c.texcol) {
      const __m256i t = order(_mm256_unpacklo_epi64(t1, t3));
      const __m256d tmin = _mm256_set1_pd(c.texture_sum_min);
      ok = _mm256_and_si256(ok, masks_of(_mm256_cmp_pd(low_pd(t), tmin, _CMP_NLT_UQ),
                                         _mm256_cmp_pd(high_pd(t), tmin, _CMP_NLT_UQ)));
    }
    const __m256i nb = neighbours(order(_mm256_unpackhi_epi64(t1, t3)));  // c0 | c2 << 16
    const __m256i c0 = _mm256_and_si256(nb, low16);
    const __m256i c2 = _mm256_srli_epi32(nb, 16);
    if (c.count_low) {
      // Unique when the lanes below the threshold are only the winner and those of its two
      // neighbours (disparity index kb - 1 and kb + 1, where they exist) below it.
      const __m256i thr = _mm256_and_si256(
          _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(c.unique_min), b, ok, 4),
          low16);
      const __m256i low0 =
          _mm256_and_si256(_mm256_cmpgt_epi32(kb, zero), _mm256_cmpgt_epi32(thr, c0));
      const __m256i low2 = _mm256_andnot_si256(
          _mm256_cmpgt_epi32(kb, _mm256_set1_epi32(c.nd - 2)), _mm256_cmpgt_epi32(thr, c2));
      // 1 + low0 + low2, the masks counting -1 each.
      const __m256i near = _mm256_sub_epi32(_mm256_sub_epi32(_mm256_set1_epi32(1), low0), low2);
      ok = _mm256_and_si256(ok, _mm256_cmpeq_epi32(s2, near));
    } else if (c.uniqueness_factor > 0) {
      const __m256d hundred = _mm256_set1_pd(100.0);
      const __m256d f = _mm256_set1_pd(c.uniqueness_factor);
      const __m256i unique =
          masks_of(_mm256_cmp_pd(_mm256_mul_pd(low_pd(s2), hundred), _mm256_mul_pd(low_pd(b), f),
                                 _CMP_GT_OQ),
                   _mm256_cmp_pd(_mm256_mul_pd(high_pd(s2), hundred),
                                 _mm256_mul_pd(high_pd(b), f), _CMP_GT_OQ));
      ok = _mm256_and_si256(ok, _mm256_or_si256(_mm256_xor_si256(has2, all), unique));
    }
    if (c.lr_on) {
      // i = x + dp - 1 - kb; the right winner's index is (rarg[i] - i + dp - 1) mod 2^16.
      const __m256i xs = _mm256_add_epi32(_mm256_set1_epi32(static_cast<int>(x)), iota);
      const __m256i i = _mm256_sub_epi32(_mm256_add_epi32(xs, _mm256_set1_epi32(dp - 1)), kb);
      const __m256i g =
          _mm256_mask_i32gather_epi32(zero, reinterpret_cast<const int*>(c.rarg), i, ok, 2);
      const __m256i kr = _mm256_and_si256(
          _mm256_add_epi32(_mm256_sub_epi32(g, i), _mm256_set1_epi32(dp - 1)), low16);
      const __m256i diff = _mm256_abs_epi32(_mm256_sub_epi32(kb, kr));
      ok = _mm256_andnot_si256(_mm256_cmpgt_epi32(diff, _mm256_set1_epi32(lr_int)), ok);
    }
    __m256 d = _mm256_cvtepi32_ps(_mm256_add_epi32(kb, _mm256_set1_epi32(c.min_d)));
    if (sub) d = subpixel_step(d, kb, b, c0, c2, ok);
    const __m256 okf = _mm256_castsi256_ps(ok);
    // A masked store only for the row's tail: vmaskmovps is microcoded on AMD processors.
    auto store = [&](float* p, __m256 v) {
      if (n == 8) {
        _mm256_storeu_ps(p, v);
      } else {
        _mm256_maskstore_ps(p, lanes, v);
      }
    };
    store(c.drow + x, _mm256_blendv_ps(nan, d, okf));
    if (c.crow) {
      const __m256 ratio = _mm256_div_ps(_mm256_cvtepi32_ps(_mm256_sub_epi32(s2, b)),
                                         _mm256_cvtepi32_ps(s2));
      const __m256 pos = _mm256_castsi256_ps(_mm256_cmpgt_epi32(s2, zero));
      const __m256 conf = _mm256_blendv_ps(_mm256_set1_ps(1.0f), _mm256_and_ps(ratio, pos),
                                           _mm256_castsi256_ps(has2));
      store(c.crow + x, _mm256_and_ps(conf, okf));
    }
  }
}

#endif

// The border band (clip_border): the columns outside xlo..xhi, whose search range leaves the
// right image and which the passes above leave NaN, matched over the disparities whose right
// pixel lies inside the image (the others never win), by decide_generic's rules; the winner
// moves by the sub-pixel step only when both neighbours are inside too. Runs after the first
// pass, when the column sums and the right winners of the row are complete.
// The least of n >= 1 16-bit lanes (a reduction the compiler vectorises).
inline uint32_t least_lane(const uint16_t* lanes, ptrdiff_t n) {
  uint16_t m = 0xFFFFu;
  for (ptrdiff_t i = 0; i < n; ++i) m = lanes[i] < m ? lanes[i] : m;
  return m;
}

void border_band(const RowCtx& c) {
  const ptrdiff_t cols = c.cols;
  const int dp = c.dp, r = c.radius, nd = c.nd;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  uint16_t* acc = c.acc;
  uint32_t tsum = 0;
  bool started = false;
  for (ptrdiff_t x = 0; x < cols; ++x) {
    if (x >= c.xlo && x <= c.xhi) {
      started = false;
      x = c.xhi;  // jump to the right band
      continue;
    }
    const ptrdiff_t klo = clamp_index(x - c.min_d - cols + 1, 0, nd);
    const ptrdiff_t khi = clamp_index(x - c.min_d, -1, nd - 1);
    if (klo > khi) {
      started = false;
      continue;  // no candidate inside the image: stays NaN
    }
    if (!started) {
      std::memset(acc, 0, sizeof(uint16_t) * static_cast<size_t>(dp));
      tsum = 0;
      for (ptrdiff_t dx = -r; dx <= r; ++dx) {
        const ptrdiff_t xx = clamp_index(x + dx, 0, cols - 1);
        const uint16_t* col = c.colsum + xx * dp;
        for (int q = 0; q < dp; ++q) acc[q] = static_cast<uint16_t>(acc[q] + col[q]);
        if (c.texcol) tsum += c.texcol[xx];
      }
      started = true;
    } else {
      const ptrdiff_t xp = clamp_index(x + r, 0, cols - 1);
      const ptrdiff_t xm = clamp_index(x - r - 1, 0, cols - 1);
      const uint16_t* plus = c.colsum + xp * dp;
      const uint16_t* minus = c.colsum + xm * dp;
      for (int q = 0; q < dp; ++q) acc[q] = static_cast<uint16_t>(acc[q] + plus[q] - minus[q]);
      if (c.texcol) tsum += c.texcol[xp] - c.texcol[xm];
    }
    // Disparity index k is lane dp - 1 - k, so k = khi .. klo lie in ascending memory. The
    // winner is the least cost (a min reduction) at its lowest k; the second best the least
    // cost more than one disparity away, over the two lane ranges either side of the winner.
    const uint32_t b = least_lane(acc + (dp - 1 - khi), khi - klo + 1);
    ptrdiff_t kb = klo;
    while (acc[dp - 1 - kb] != b) ++kb;
    const ptrdiff_t lo_end = std::min(kb - 2, khi);  // k in klo .. kb - 2
    const ptrdiff_t hi_begin = std::max(kb + 2, klo);  // k in kb + 2 .. khi
    uint32_t s2 = kNone;
    if (lo_end >= klo) s2 = std::min(s2, least_lane(acc + (dp - 1 - lo_end), lo_end - klo + 1));
    if (khi >= hi_begin) {
      s2 = std::min(s2, least_lane(acc + (dp - 1 - khi), khi - hi_begin + 1));
    }
    const bool has2 = s2 != kNone;
    bool ok = true;
    if (c.texcol) ok = !(static_cast<double>(tsum) < c.texture_sum_min);
    if (ok && c.uniqueness_factor > 0 && has2) {
      ok = static_cast<double>(s2) * 100.0 > static_cast<double>(b) * c.uniqueness_factor;
    }
    if (ok && c.lr_on) {
      const ptrdiff_t i = x + (dp - 1 - kb);
      const int kr = static_cast<uint16_t>(c.rarg[i] - i + dp - 1);
      const ptrdiff_t diff = kb > kr ? kb - kr : kr - kb;
      ok = static_cast<double>(diff) <= c.lr_max_diff;
    }
    if (!ok) {
      c.drow[x] = nan;
      if (c.crow) c.crow[x] = 0.0f;
      continue;
    }
    float d = static_cast<float>(c.min_d + kb);
    if (c.subpixel != SubpixelFit::kNone && kb - 1 >= klo && kb + 1 <= khi) {
      const int32_t c0 = acc[dp - kb];      // index kb - 1
      const int32_t c1 = static_cast<int32_t>(b);
      const int32_t c2 = acc[dp - 2 - kb];  // index kb + 1
      const float num = static_cast<float>(c0 - c2);
      float den;
      if (c.subpixel == SubpixelFit::kParabola) {
        den = static_cast<float>(2 * (c0 + c2 - 2 * c1));
      } else {
        den = static_cast<float>(2 * (c0 - c1 > c2 - c1 ? c0 - c1 : c2 - c1));
      }
      if (den > 0.0f) d = d + num / den;
    }
    c.drow[x] = d;
    if (c.crow) {
      c.crow[x] = !has2 ? 1.0f
                  : s2 > 0 ? static_cast<float>(s2 - b) / static_cast<float>(s2)
                           : 0.0f;
    }
  }
}

// Whether this build's first pass updates the column sums itself for this dp.
inline bool fuses_update(int dp) {
#if defined(STEREODEPTH_BM_AVX2)
  return dp <= kLanes * kMaxChunks;
#else
  (void)dp;
  return false;
#endif
}

template <typename Cost>
void row_pass(const RowCtx& c) {
#if defined(STEREODEPTH_BM_AVX2)
  if (c.dp <= kLanes * kMaxChunks) {
    RowCtx counted = c;
    counted.count_low = c.unique_min != nullptr && c.crow == nullptr;
    counted.around_shifted = byte_sum_pass<Cost>(c);
    winners_fixed<1, Cost>(counted);
    // The fixed pass matches the border band itself (group_winners): no border_band here.
    if (!c.first_pass_only) decide_avx2(counted);
  } else {
    winners_generic(c);
    if (!c.first_pass_only) decide_avx2(c);
    if (c.clip_border) border_band(c);
  }
#else
  winners_generic(c);
  if (!c.first_pass_only) decide_generic(c);
  if (c.clip_border) border_band(c);
#endif
  if (c.clip_border && !c.first_pass_only) drop_unrivalled(c.drow, c.crow, c.cols, c.min_d, c.nd);
}

// ------------------------------------------------------------------------------------------
// One band of rows.

// pad[i] = row[clamp(i + jmin, 0, cols - 1)] for i in [0, n).
template <typename F>
void pad_right_row(const F* row, F* pad, ptrdiff_t cols, ptrdiff_t n, ptrdiff_t jmin) {
  const ptrdiff_t lo = clamp_index(-jmin, 0, n);         // first i with i + jmin >= 0
  const ptrdiff_t hi = clamp_index(cols - jmin, lo, n);  // first i with i + jmin >= cols
  for (ptrdiff_t i = 0; i < lo; ++i) pad[i] = row[0];
  if (hi > lo) std::memcpy(pad + lo, row + (lo + jmin), sizeof(F) * static_cast<size_t>(hi - lo));
  for (ptrdiff_t i = hi; i < n; ++i) pad[i] = row[cols - 1];
}

template <typename Cost>
void match_band_impl(const MatchArgs& a, const BandScratch& s, ptrdiff_t y0, ptrdiff_t y1,
                     bool fresh) {
  using F = typename Cost::Feature;
  const ptrdiff_t cols = a.cols, rows = a.rows;
  const int dp = a.dp, r = a.radius;
  // Right column of lane q at left column x: x + q + jmin.
  const ptrdiff_t jmin = -static_cast<ptrdiff_t>(a.min_d) - dp + 1;
  const ptrdiff_t npad = cols + dp + kRowPad;
  const F* lfeat = static_cast<const F*>(a.left_feat);
  const F* rfeat = static_cast<const F*>(a.right_feat);
  auto lrow = [&](ptrdiff_t y) {
    return lfeat + (clamp_index(y, 0, rows - 1) - a.feat_row0) * a.feat_stride;
  };
  auto rrow = [&](ptrdiff_t y) {
    return rfeat + (clamp_index(y, 0, rows - 1) - a.feat_row0) * a.feat_stride;
  };
  auto trow = [&](ptrdiff_t y) {
    return a.texture + (clamp_index(y, 0, rows - 1) - a.feat_row0) * a.texture_stride;
  };
  F* rpad_in = static_cast<F*>(s.rpad_in);
  F* rpad_out = static_cast<F*>(s.rpad_out);
  const bool tex_on = a.texture != nullptr && a.texture_sum_min > 0;

  RowCtx c{};
  c.colsum = s.colsum;
  c.texcol = tex_on ? s.texcol : nullptr;
  c.cols = cols;
  c.xlo = static_cast<ptrdiff_t>(a.min_d) + a.num_d - 1;
  c.xhi = cols - 1 + a.min_d;
  c.dp = dp;
  c.nd = a.num_d;
  c.qpad = dp - a.num_d;
  c.radius = r;
  c.min_d = a.min_d;
  c.subpixel = a.subpixel;
  c.lr_on = a.lr_max_diff >= 0;
  c.need_second = a.uniqueness_factor > 0 || a.conf != nullptr;
  c.clip_border = a.clip_border;
  c.texture_sum_min = a.texture_sum_min;
  c.uniqueness_factor = a.uniqueness_factor;
  c.lr_max_diff = a.lr_max_diff;
  c.acc = s.acc;
  c.rmin = s.rmin;
  c.rarg = s.rarg;
  c.recent = s.recent;
  c.rec = static_cast<WinnerRecord*>(s.records);
  c.unique_min = a.unique_min;
  c.unique_min_shifted = a.unique_min_shifted;
  c.first_pass_only = a.first_pass_only;

  const bool fused = fuses_update(dp);
#if defined(STEREODEPTH_BM_AVX2)
  c.byte_cols = sizeof(F) == 4 && s.ring != nullptr && fused && (2 * r + 1) * kCensusCostMax <= 255;
#endif
  // The ring slot of image row y (clamped), or null without a ring.
  auto ring_slot = [&](ptrdiff_t y) -> uint8_t* {
    if (!s.ring) return nullptr;
    const ptrdiff_t slot = clamp_index(y, 0, rows - 1) % cost_ring_rows(r);
    return s.ring + slot * cols * cost_ring_column_bytes(dp);
  };
  for (ptrdiff_t y = y0; y < y1; ++y) {
    if (fresh && y == y0) {
      std::memset(s.colsum, 0, sizeof(uint16_t) * static_cast<size_t>(cols) * dp);
      if (tex_on) std::memset(s.texcol, 0, sizeof(uint32_t) * static_cast<size_t>(cols));
      for (ptrdiff_t dy = -r; dy <= r; ++dy) {
        pad_right_row(rrow(y + dy), rpad_in, cols, npad, jmin);
        add_cost_row<Cost>(lrow(y + dy), rpad_in, s.colsum, cols, dp, ring_slot(y + dy),
                           c.byte_cols);
        if (tex_on) {
          const uint8_t* t = trow(y + dy);
          for (ptrdiff_t x = 0; x < cols; ++x) s.texcol[x] += t[x];
        }
      }
    } else {
      const ptrdiff_t yin = clamp_index(y + r, 0, rows - 1);
      const ptrdiff_t yout = clamp_index(y - r - 1, 0, rows - 1);
      if (yin != yout) {
        pad_right_row(rrow(yin), rpad_in, cols, npad, jmin);
        // The leaving row's right features, where they are matched again (not with the
        // AVX2 build's ring of census costs).
        bool out_matched = true;
#if defined(STEREODEPTH_BM_AVX2)
        out_matched = !(fused && sizeof(F) == 4 && s.ring);
#endif
        if (out_matched) pad_right_row(rrow(yout), rpad_out, cols, npad, jmin);
        if (fused) {
          c.in_left = lrow(yin);
          c.in_rpad = rpad_in;
          c.out_left = lrow(yout);
          c.out_rpad = rpad_out;
#if defined(STEREODEPTH_BM_AVX2)
          if constexpr (sizeof(F) == 4) {
            // With the ring the leaving row's costs are read back: only the entering row is
            // matched.
            auto* qi = static_cast<uint16_t*>(s.quad_in);
            nibbles_of(rpad_in, qi, npad, npad);
            nibbles_of(lrow(yin), qi + 2 * npad, cols, npad);
            if (!s.ring) {
              auto* qo = static_cast<uint16_t*>(s.quad_out);
              nibbles_of(rpad_out, qo, npad, npad);
              nibbles_of(lrow(yout), qo + 2 * npad, cols, npad);
              c.out_quad = s.quad_out;
            }
            c.nibble_stride = npad;
            c.in_quad = s.quad_in;
            c.ring_in = ring_slot(yin);
            c.ring_out = ring_slot(yout);
          }
#endif
        } else {
          update_cost_rows<Cost>(lrow(yin), rpad_in, lrow(yout), rpad_out, s.colsum, cols, dp);
        }
        if (tex_on) {
          const uint8_t* ti = trow(yin);
          const uint8_t* to = trow(yout);
          for (ptrdiff_t x = 0; x < cols; ++x) s.texcol[x] += static_cast<uint32_t>(ti[x]) - to[x];
        }
      }
    }

    c.drow = a.disp + y * a.disp_stride;
    c.crow = a.conf ? a.conf + y * a.conf_stride : nullptr;
    row_pass<Cost>(c);
    c.in_left = c.in_rpad = c.out_left = c.out_rpad = nullptr;
  }
}

// ------------------------------------------------------------------------------------------
// The speckle filter's links of one row (see SpeckleLinksFn).

void speckle_links(const float* d, const float* u, ptrdiff_t cols, float rf, std::uint64_t* valid,
                   std::uint64_t* left, std::uint64_t* up) {
  const ptrdiff_t words = (cols + 63) / 64;
  std::memset(valid, 0, sizeof(std::uint64_t) * static_cast<size_t>(words));
  std::memset(left, 0, sizeof(std::uint64_t) * static_cast<size_t>(words));
  std::memset(up, 0, sizeof(std::uint64_t) * static_cast<size_t>(words));
  ptrdiff_t i = 0;
#if defined(STEREODEPTH_BM_AVX2)
  // 32 columns at a time, four movemasks of 8 per 32-bit half word (|a - b| is a - b with
  // the sign bit cleared, as fabs; a NaN compares false); column 0 has no left neighbour.
  auto* v32 = reinterpret_cast<uint32_t*>(valid);
  auto* l32 = reinterpret_cast<uint32_t*>(left);
  auto* u32 = reinterpret_cast<uint32_t*>(up);
  const __m256 r = _mm256_set1_ps(rf);
  const __m256 magnitude = _mm256_castsi256_ps(_mm256_set1_epi32(0x7FFFFFFF));
  auto near = [&](__m256 a, __m256 b) {
    return static_cast<uint32_t>(_mm256_movemask_ps(
        _mm256_cmp_ps(_mm256_and_ps(_mm256_sub_ps(a, b), magnitude), r, _CMP_LE_OQ)));
  };
  if (cols > 32) {
    for (; i + 32 <= cols; i += 32) {
      uint32_t vb = 0, lb = 0, ub = 0;
      for (int k = 0; k < 4; ++k) {
        const ptrdiff_t j = i + 8 * k;
        const __m256 dj = _mm256_loadu_ps(d + j);
        vb |= static_cast<uint32_t>(_mm256_movemask_ps(_mm256_cmp_ps(dj, dj, _CMP_ORD_Q)))
              << (8 * k);
        if (j > 0) lb |= near(dj, _mm256_loadu_ps(d + j - 1)) << (8 * k);
        if (u) ub |= near(dj, _mm256_loadu_ps(u + j)) << (8 * k);
      }
      v32[i / 32] = vb;
      l32[i / 32] = lb;
      u32[i / 32] = ub;
    }
    // The first 8 columns' left links (column 0 has none).
    for (ptrdiff_t j = 1; j < 8; ++j) {
      if (std::fabs(d[j] - d[j - 1]) <= rf) left[0] |= std::uint64_t{1} << j;
    }
  }
#endif
  for (; i < cols; ++i) {
    const std::uint64_t bit = std::uint64_t{1} << (i & 63);
    if (d[i] == d[i]) valid[i >> 6] |= bit;
    if (i > 0 && std::fabs(d[i] - d[i - 1]) <= rf) left[i >> 6] |= bit;
    if (u && std::fabs(d[i] - u[i]) <= rf) up[i >> 6] |= bit;
  }
}

void match_band(const MatchArgs& a, const BandScratch& s, ptrdiff_t y0, ptrdiff_t y1, bool fresh) {
  if (a.cost == MatchCost::kCensus) {
    match_band_impl<CensusCost>(a, s, y0, y1, fresh);
  } else {
    match_band_impl<SadCost>(a, s, y0, y1, fresh);
  }
}

}  // namespace

const BlockMatchKernels& block_match_kernels() {
  static const BlockMatchKernels kernels = {
      kLanes,
      &rgb_to_grey,
      &census_row<uint8_t>,
      &census_row<uint16_t>,
      &sobel_row<uint8_t>,
      &sobel_row<uint16_t>,
      &range_row16,
      &stretch_row16,
      &match_band,
      &speckle_links,
  };
  return kernels;
}

}  // namespace stereodepth::detail::STEREODEPTH_ISA_NS
