// Per-row remap loops (the arithmetic is specified in stereodepth/remap.hpp). Compiled once
// per instruction set (STEREODEPTH_ISA_NS); everything here stays inside that namespace.
//
// The scalar loop is the reference. With AVX2, eight output pixels are computed at once
// wherever all their four neighbours are inside the image: scalar loads fetch the top and
// bottom neighbour pairs (4 bytes per pixel and row for grey, 8 for RGB), pmaddwd forms top
// and bot, and one 32-bit multiply blends them as top * 1024 + (bot - top) * fy, which equals
// the specification's sum exactly.
#include "remap_kernels.hpp"

#include <cmath>
#include <cstdint>
#include <cstring>

#if defined(__AVX2__)
#include <immintrin.h>
#endif

#ifndef STEREODEPTH_ISA_NS
#error "STEREODEPTH_ISA_NS must name the instruction set this file is compiled for"
#endif

namespace stereodepth::detail::STEREODEPTH_ISA_NS {
namespace {

constexpr int kOne = 1 << kRemapFractionBits;  // 1024
constexpr int kShift = 2 * kRemapFractionBits;  // 20

// Pixels [begin, end) of a row of T samples with CN interleaved channels, scalar.
template <typename T, int CN>
void remap_scalar(const RemapRowArgs& a, std::ptrdiff_t begin, std::ptrdiff_t end) {
  using Acc = std::int32_t;  // uint8 only: at most 255 * 2^20
  T* out = static_cast<T*>(a.dst);
  const std::ptrdiff_t rows = a.src_rows, cols = a.src_cols;
  for (std::ptrdiff_t j = begin; j < end; ++j) {
    const std::ptrdiff_t x = a.xy[2 * j], y = a.xy[2 * j + 1];
    const Acc fx = static_cast<Acc>(a.frac[j] & 0xffffu);
    const Acc fy = static_cast<Acc>(a.frac[j] >> 16);
    const bool x0 = x >= 0 && x < cols, x1 = x + 1 >= 0 && x + 1 < cols;
    const bool y0 = y >= 0 && y < rows, y1 = y + 1 >= 0 && y + 1 < rows;
    const T* r0 = reinterpret_cast<const T*>(a.src + (y0 ? y : 0) * a.src_stride);
    const T* r1 = reinterpret_cast<const T*>(a.src + (y1 ? y + 1 : 0) * a.src_stride);
    for (int c = 0; c < CN; ++c) {
      const Acc p00 = (y0 && x0) ? static_cast<Acc>(r0[x * CN + c]) : 0;
      const Acc p01 = (y0 && x1) ? static_cast<Acc>(r0[(x + 1) * CN + c]) : 0;
      const Acc p10 = (y1 && x0) ? static_cast<Acc>(r1[x * CN + c]) : 0;
      const Acc p11 = (y1 && x1) ? static_cast<Acc>(r1[(x + 1) * CN + c]) : 0;
      const Acc top = p00 * (kOne - fx) + p01 * fx;
      const Acc bot = p10 * (kOne - fx) + p11 * fx;
      out[j * CN + c] =
          static_cast<T>((top * (kOne - fy) + bot * fy + (Acc{1} << (kShift - 1))) >> kShift);
    }
  }
}

template <typename T, int CN>
void remap_row_scalar(const RemapRowArgs& a) {
  remap_scalar<T, CN>(a, 0, a.n);
}

// 16-bit grey from float positions, float64 arithmetic (remap.hpp).
void remap_u16(const RemapRowArgs& a, std::ptrdiff_t begin, std::ptrdiff_t end) {
  auto* out = static_cast<std::uint16_t*>(a.dst);
  const std::ptrdiff_t rows = a.src_rows, cols = a.src_cols;
  for (std::ptrdiff_t j = begin; j < end; ++j) {
    const double px = a.pos[2 * j], py = a.pos[2 * j + 1];
    const double fx0 = std::floor(px), fy0 = std::floor(py);
    const double fx = px - fx0, fy = py - fy0;
    const std::ptrdiff_t x = static_cast<std::ptrdiff_t>(fx0), y = static_cast<std::ptrdiff_t>(fy0);
    const bool x0 = x >= 0 && x < cols, x1 = x + 1 >= 0 && x + 1 < cols;
    const bool y0 = y >= 0 && y < rows, y1 = y + 1 >= 0 && y + 1 < rows;
    const auto* r0 = reinterpret_cast<const std::uint16_t*>(a.src + (y0 ? y : 0) * a.src_stride);
    const auto* r1 =
        reinterpret_cast<const std::uint16_t*>(a.src + (y1 ? y + 1 : 0) * a.src_stride);
    const double p00 = (y0 && x0) ? r0[x] : 0.0, p01 = (y0 && x1) ? r0[x + 1] : 0.0;
    const double p10 = (y1 && x0) ? r1[x] : 0.0, p11 = (y1 && x1) ? r1[x + 1] : 0.0;
    const double top = p00 * (1.0 - fx) + p01 * fx;
    const double bot = p10 * (1.0 - fx) + p11 * fx;
    double v = std::nearbyint(top * (1.0 - fy) + bot * fy);
    v = v < 65535.0 ? v : 65535.0;
    out[j] = static_cast<std::uint16_t>(v);
  }
}

#if !defined(__AVX2__)
void remap_row_u16(const RemapRowArgs& a) { remap_u16(a, 0, a.n); }
#endif

#if defined(__AVX2__)

// Loads of 4 or 8 bytes at base + ofs[k] + d for eight pixels (ofs: non-negative int32
// offsets), as _mm256_i32gather_epi32 and _mm256_i32gather_epi64 would fetch them. Scalar
// loads: on Zen 3 (the machine measured) they are about a third faster than the gathers. The
// offsets stay in four 64-bit scalars (an array of them is turned by GCC into vector code
// that stores and reloads them, slower than the gathers).
struct Addresses8 {
  const std::uint8_t* base;
  std::uint64_t q0, q1, q2, q3;  // offsets 2k (low half) and 2k + 1 (high half)
  Addresses8(const std::uint8_t* b, __m256i ofs) : base(b) {
    const __m128i lo = _mm256_castsi256_si128(ofs), hi = _mm256_extracti128_si256(ofs, 1);
    q0 = static_cast<std::uint64_t>(_mm_cvtsi128_si64(lo));
    q1 = static_cast<std::uint64_t>(_mm_extract_epi64(lo, 1));
    q2 = static_cast<std::uint64_t>(_mm_cvtsi128_si64(hi));
    q3 = static_cast<std::uint64_t>(_mm_extract_epi64(hi, 1));
  }
  static std::int32_t u32(const std::uint8_t* at) {
    std::int32_t v;
    std::memcpy(&v, at, sizeof v);
    return v;
  }
  static const std::uint8_t* even(const std::uint8_t* b, std::uint64_t q) {
    return b + static_cast<std::uint32_t>(q);
  }
  static const std::uint8_t* odd(const std::uint8_t* b, std::uint64_t q) { return b + (q >> 32); }
  // The 4 bytes at each offset + d.
  __m256i load32(std::ptrdiff_t d) const {
    const std::uint8_t* b = base + d;
    __m128i lo = _mm_cvtsi32_si128(u32(even(b, q0)));
    lo = _mm_insert_epi32(lo, u32(odd(b, q0)), 1);
    lo = _mm_insert_epi32(lo, u32(even(b, q1)), 2);
    lo = _mm_insert_epi32(lo, u32(odd(b, q1)), 3);
    __m128i hi = _mm_cvtsi32_si128(u32(even(b, q2)));
    hi = _mm_insert_epi32(hi, u32(odd(b, q2)), 1);
    hi = _mm_insert_epi32(hi, u32(even(b, q3)), 2);
    hi = _mm_insert_epi32(hi, u32(odd(b, q3)), 3);
    return _mm256_inserti128_si256(_mm256_castsi128_si256(lo), hi, 1);
  }
  // The 8 bytes at offsets 0, 1 | 4, 5 (second: 2, 3 | 6, 7) + d, two per 128-bit lane.
  __m256i load64x2(bool second, std::ptrdiff_t d) const {
    const std::uint8_t* b = base + d;
    const std::uint64_t qa = second ? q1 : q0, qb = second ? q3 : q2;
    const auto at = [](const std::uint8_t* p) { return reinterpret_cast<const double*>(p); };
    const __m128d lo = _mm_loadh_pd(_mm_castsi128_pd(_mm_loadu_si64(even(b, qa))), at(odd(b, qa)));
    const __m128d hi = _mm_loadh_pd(_mm_castsi128_pd(_mm_loadu_si64(even(b, qb))), at(odd(b, qb)));
    return _mm256_inserti128_si256(_mm256_castsi128_si256(_mm_castpd_si128(lo)),
                                   _mm_castpd_si128(hi), 1);
  }
};

// The source line of the bottom neighbours of a pixel at (x, y) in a row kRemapAhead rows
// below, for a prefetch (null outside the image): the rows a band reads move down the image
// with it, and the lines first touched there are otherwise cache misses. One prefetch per 8
// (4) pixels. The caller issues the prefetch: a helper holding only a prefetch is deduced
// free of side effects and its calls deleted (GCC 12).
inline const char* bottom_line(const RemapRowArgs& a, std::ptrdiff_t x, std::ptrdiff_t y,
                               std::ptrdiff_t bytes) {
  if (x >= 0 && x < a.src_cols && y + 1 >= 0 && y + 1 < a.src_rows) {
    return reinterpret_cast<const char*>(a.src + (y + 1) * a.src_stride + x * bytes);
  }
  return nullptr;
}

// Four 4-byte loads, as Addresses8 (_mm_i32gather_epi32).
struct Addresses4 {
  const std::uint8_t* base;
  std::uint64_t q0, q1;
  Addresses4(const std::uint8_t* b, __m128i ofs)
      : base(b),
        q0(static_cast<std::uint64_t>(_mm_cvtsi128_si64(ofs))),
        q1(static_cast<std::uint64_t>(_mm_extract_epi64(ofs, 1))) {}
  __m128i load32(std::ptrdiff_t d) const {
    const std::uint8_t* b = base + d;
    __m128i v = _mm_cvtsi32_si128(Addresses8::u32(Addresses8::even(b, q0)));
    v = _mm_insert_epi32(v, Addresses8::u32(Addresses8::odd(b, q0)), 1);
    v = _mm_insert_epi32(v, Addresses8::u32(Addresses8::even(b, q1)), 2);
    return _mm_insert_epi32(v, Addresses8::u32(Addresses8::odd(b, q1)), 3);
  }
};

// Eight grey uint8 results from the offsets `e` of the top-left neighbours and fractions `f`;
// `pick` moves the two neighbours in each 32-bit load into int16 pairs.
inline __m128i blend8(const std::uint8_t* src, std::ptrdiff_t stride, __m256i e, __m256i f,
                      __m256i pick) {
  const Addresses8 at(src, e);
  __m256i top = at.load32(0);
  __m256i bot = at.load32(stride);
  top = _mm256_shuffle_epi8(top, pick);
  bot = _mm256_shuffle_epi8(bot, pick);
  const __m256i fx = _mm256_and_si256(f, _mm256_set1_epi32(0xffff));
  const __m256i wx = _mm256_or_si256(_mm256_sub_epi32(_mm256_set1_epi32(kOne), fx),
                                     _mm256_slli_epi32(fx, 16));
  const __m256i t = _mm256_madd_epi16(top, wx);
  const __m256i b = _mm256_madd_epi16(bot, wx);
  const __m256i fy = _mm256_srli_epi32(f, 16);
  __m256i v = _mm256_add_epi32(_mm256_slli_epi32(t, kRemapFractionBits),
                               _mm256_mullo_epi32(_mm256_sub_epi32(b, t), fy));
  v = _mm256_srai_epi32(_mm256_add_epi32(v, _mm256_set1_epi32(1 << (kShift - 1))), kShift);
  const __m128i w = _mm_packus_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  return _mm_packus_epi16(w, w);
}

// Bytes 4i and 4i + 1 of every dword as an int16 pair.
inline __m256i pick_pattern() {
  return _mm256_setr_epi8(0, -128, 1, -128, 4, -128, 5, -128, 8, -128, 9, -128, 12, -128, 13,
                          -128, 0, -128, 1, -128, 4, -128, 5, -128, 8, -128, 9, -128, 12, -128,
                          13, -128);
}

// Eight RGB pixels from the offsets `ofs` of their top-left neighbours and fractions `f`: 8
// bytes from each top-left neighbour (both neighbours' R G B) in the top and bottom rows,
// regrouped by channel with one shuffle per two pixels and two unpacks, so that pmaddwd
// forms top and bot for 8 pixels of one channel at once with the fractions as loaded (no
// per-pixel broadcasts, no unused fourth channel); the rows are then blended as in blend8.
// Writes 24 bytes at `o`; with `room`, 8 more that later pixels overwrite.
inline void blend_rgb8(const std::uint8_t* src, std::ptrdiff_t stride, __m256i ofs, __m256i f,
                       std::uint8_t* o, bool room) {
  const Addresses8 at(src, ofs);
  // Per 128-bit lane, two pixels' 8 bytes [R G B R' G' B' . .] -> the (left, right) byte pairs
  // grouped by channel: R pairs of both pixels, G pairs, B pairs, 4 zeros.
  const __m256i group = _mm256_setr_epi8(0, 3, 8, 11, 1, 4, 9, 12, 2, 5, 10, 13, -128, -128, -128,
                                         -128, 0, 3, 8, 11, 1, 4, 9, 12, 2, 5, 10, 13, -128, -128,
                                         -128, -128);
  const __m256i zero = _mm256_setzero_si256();
  const __m256i fx = _mm256_and_si256(f, _mm256_set1_epi32(0xffff));
  const __m256i wx = _mm256_or_si256(_mm256_sub_epi32(_mm256_set1_epi32(kOne), fx),
                                     _mm256_slli_epi32(fx, 16));
  const __m256i fy = _mm256_srli_epi32(f, 16);
  // Row d's horizontal sums per channel, pixels 0-3 in the low lane and 4-7 in the high one.
  const auto rows = [&](std::ptrdiff_t d, __m256i& r, __m256i& g, __m256i& b) {
    const __m256i a = _mm256_shuffle_epi8(at.load64x2(false, d), group);  // pixels 0 1 | 4 5
    const __m256i c = _mm256_shuffle_epi8(at.load64x2(true, d), group);   // pixels 2 3 | 6 7
    const __m256i lo = _mm256_unpacklo_epi32(a, c);  // R01 R23 G01 G23
    const __m256i hi = _mm256_unpackhi_epi32(a, c);  // B01 B23 0 0
    r = _mm256_madd_epi16(_mm256_unpacklo_epi8(lo, zero), wx);
    g = _mm256_madd_epi16(_mm256_unpackhi_epi8(lo, zero), wx);
    b = _mm256_madd_epi16(_mm256_unpacklo_epi8(hi, zero), wx);
  };
  __m256i tr, tg, tb, br, bg, bb;
  rows(0, tr, tg, tb);
  rows(stride, br, bg, bb);
  const __m256i half = _mm256_set1_epi32(1 << (kShift - 1));
  const auto blend = [&](__m256i t, __m256i b) {
    const __m256i v = _mm256_add_epi32(_mm256_slli_epi32(t, kRemapFractionBits),
                                       _mm256_mullo_epi32(_mm256_sub_epi32(b, t), fy));
    return _mm256_srai_epi32(_mm256_add_epi32(v, half), kShift);
  };
  const __m256i vr = blend(tr, br), vg = blend(tg, bg), vb = blend(tb, bb);
  // Per lane: R0-3 G0-3 B0-3 B0-3 as bytes, then interleaved, then the lanes joined.
  const __m256i bytes = _mm256_packus_epi16(_mm256_packus_epi32(vr, vg),
                                            _mm256_packus_epi32(vb, vb));
  const __m256i rgb = _mm256_shuffle_epi8(
      bytes, _mm256_setr_epi8(0, 4, 8, 1, 5, 9, 2, 6, 10, 3, 7, 11, -1, -1, -1, -1, 0, 4, 8, 1, 5,
                              9, 2, 6, 10, 3, 7, 11, -1, -1, -1, -1));
  const __m256i packed =
      _mm256_permutevar8x32_epi32(rgb, _mm256_setr_epi32(0, 1, 2, 4, 5, 6, 3, 7));
  if (room) {
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(o), packed);
  } else {
    _mm_storeu_si128(reinterpret_cast<__m128i*>(o), _mm256_castsi256_si128(packed));
    _mm_storel_epi64(reinterpret_cast<__m128i*>(o + 16), _mm256_extracti128_si256(packed, 1));
  }
}

// 16-bit grey, four pixels at a time in float64: the scalar loop's operations in its order
// (no contraction), so the results are the same bits; one 32-bit load per pixel and row
// fetches both neighbours.
void remap_row_u16_avx2(const RemapRowArgs& a) {
  const std::ptrdiff_t stride = a.src_stride;
  const std::ptrdiff_t extent = (a.src_rows - 1) * stride + a.src_cols * 2;
  std::ptrdiff_t j = 0;
  if (extent < (std::ptrdiff_t{1} << 30) && a.src_rows >= 2 && a.src_cols >= 2) {
    auto* out = static_cast<std::uint16_t*>(a.dst);
    const __m128i xmax = _mm_set1_epi32(static_cast<std::int32_t>(a.src_cols - 2));
    const __m128i ymax = _mm_set1_epi32(static_cast<std::int32_t>(a.src_rows - 2));
    const __m128i vstride = _mm_set1_epi32(static_cast<std::int32_t>(stride));
    const __m128i elim = _mm_set1_epi32(static_cast<std::int32_t>(extent - stride - 4));
    const __m128i lo16 = _mm_set1_epi32(0xffff);
    const __m256i deinterleave = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
    const __m256d one = _mm256_set1_pd(1.0), top_value = _mm256_set1_pd(65535.0);
    for (; j + 4 <= a.n; j += 4) {
      // Clamped to [-2, side + 1]: the conversions cannot overflow.
      if (const char* line = bottom_line(a, static_cast<std::ptrdiff_t>(a.pos_ahead[2 * j]),
                                         static_cast<std::ptrdiff_t>(a.pos_ahead[2 * j + 1]), 2)) {
        _mm_prefetch(line, _MM_HINT_T0);
      }
      const __m256 xy = _mm256_permutevar8x32_ps(_mm256_loadu_ps(a.pos + 2 * j), deinterleave);
      const __m256d px = _mm256_cvtps_pd(_mm256_castps256_ps128(xy));
      const __m256d py = _mm256_cvtps_pd(_mm256_extractf128_ps(xy, 1));
      const __m256d x0 = _mm256_floor_pd(px), y0 = _mm256_floor_pd(py);
      const __m256d fx = _mm256_sub_pd(px, x0), fy = _mm256_sub_pd(py, y0);
      const __m128i ix = _mm256_cvtpd_epi32(x0), iy = _mm256_cvtpd_epi32(y0);
      const __m128i ofs = _mm_add_epi32(_mm_mullo_epi32(iy, vstride), _mm_add_epi32(ix, ix));
      const __m128i bad = _mm_or_si128(
          _mm_or_si128(_mm_cmpgt_epi32(ix, xmax), _mm_cmpgt_epi32(iy, ymax)),
          _mm_or_si128(_mm_or_si128(_mm_cmplt_epi32(ix, _mm_setzero_si128()),
                                    _mm_cmplt_epi32(iy, _mm_setzero_si128())),
                       _mm_cmpgt_epi32(ofs, elim)));
      if (!_mm_testz_si128(bad, bad)) {
        remap_u16(a, j, j + 4);
        continue;
      }
      const Addresses4 at(a.src, ofs);
      const __m128i t = at.load32(0);
      const __m128i b = at.load32(stride);
      const __m256d p00 = _mm256_cvtepi32_pd(_mm_and_si128(t, lo16));
      const __m256d p01 = _mm256_cvtepi32_pd(_mm_srli_epi32(t, 16));
      const __m256d p10 = _mm256_cvtepi32_pd(_mm_and_si128(b, lo16));
      const __m256d p11 = _mm256_cvtepi32_pd(_mm_srli_epi32(b, 16));
      const __m256d wx = _mm256_sub_pd(one, fx);
      const __m256d vt = _mm256_add_pd(_mm256_mul_pd(p00, wx), _mm256_mul_pd(p01, fx));
      const __m256d vb = _mm256_add_pd(_mm256_mul_pd(p10, wx), _mm256_mul_pd(p11, fx));
      __m256d v = _mm256_add_pd(_mm256_mul_pd(vt, _mm256_sub_pd(one, fy)), _mm256_mul_pd(vb, fy));
      v = _mm256_min_pd(_mm256_round_pd(v, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC),
                        top_value);
      const __m128i v32 = _mm256_cvtpd_epi32(v);
      _mm_storel_epi64(reinterpret_cast<__m128i*>(out + j), _mm_packus_epi32(v32, v32));
    }
  }
  remap_u16(a, j, a.n);
}

// CN = 1 (grey) or 3 (RGB) uint8 channels.
template <int CN>
void remap_row_u8_avx2(const RemapRowArgs& a) {
  const std::ptrdiff_t stride = a.src_stride;
  std::ptrdiff_t j = 0;
  // Whole-vector path needs every offset in int32 and the stride in int16.
  const std::ptrdiff_t extent = (a.src_rows - 1) * stride + a.src_cols * CN;
  if (stride <= 32767 && extent < (std::ptrdiff_t{1} << 30) && a.src_rows >= 2 &&
      a.src_cols >= 2) {
    const __m256i mul = _mm256_set1_epi32((static_cast<std::int32_t>(stride) << 16) | CN);
    // Inside: 0 <= x <= cols - 2 and 0 <= y <= rows - 2, tested on the int16 pairs.
    const __m256i lim = _mm256_set1_epi32(
        (static_cast<std::int32_t>(a.src_rows - 2) << 16) |
        static_cast<std::int32_t>(static_cast<std::uint16_t>(a.src_cols - 2)));
    // The loads of the bottom row (4 bytes for grey, 8 for RGB) must stay inside the image.
    const __m256i elim =
        _mm256_set1_epi32(static_cast<std::int32_t>(extent - stride - (CN == 1 ? 4 : 8)));
    const __m256i pick = pick_pattern();
    const __m256i zero = _mm256_setzero_si256();
    std::uint8_t* out = static_cast<std::uint8_t*>(a.dst);
    for (; j + 8 <= a.n; j += 8) {
      if (const char* line = bottom_line(a, a.xy_ahead[2 * j], a.xy_ahead[2 * j + 1], CN)) {
        _mm_prefetch(line, _MM_HINT_T0);
      }
      const __m256i xy = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(a.xy + 2 * j));
      const __m256i f = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(a.frac + j));
      const __m256i ofs = _mm256_madd_epi16(xy, mul);
      const __m256i bad = _mm256_or_si256(
          _mm256_or_si256(_mm256_cmpgt_epi16(xy, lim), _mm256_cmpgt_epi16(zero, xy)),
          _mm256_cmpgt_epi32(ofs, elim));
      if (!_mm256_testz_si256(bad, bad)) {
        remap_scalar<std::uint8_t, CN>(a, j, j + 8);
        continue;
      }
      if constexpr (CN == 1) {
        _mm_storel_epi64(reinterpret_cast<__m128i*>(out + j), blend8(a.src, stride, ofs, f, pick));
      } else {
        blend_rgb8(a.src, stride, ofs, f, out + 3 * j, j + 11 <= a.n);
      }
    }
  }
  remap_scalar<std::uint8_t, CN>(a, j, a.n);
}

#endif

}  // namespace

const RemapKernels& remap_kernels() {
#if defined(__AVX2__)
  static const RemapKernels kernels = {{
      &remap_row_u8_avx2<1>,
      &remap_row_u16_avx2,
      &remap_row_u8_avx2<3>,
  }};
#else
  static const RemapKernels kernels = {{
      &remap_row_scalar<std::uint8_t, 1>,
      &remap_row_u16,
      &remap_row_scalar<std::uint8_t, 3>,
  }};
#endif
  return kernels;
}

}  // namespace stereodepth::detail::STEREODEPTH_ISA_NS
