// Semi-global matching kernels. Compiled once per instruction set (STEREODEPTH_ISA_NS);
// everything here stays inside that namespace (see dispatch.hpp). The loops run over the
// disparities of one pixel with 16-bit lanes and no dependence between lanes, written so the
// compiler vectorises them for each build (SSE2, AVX2, AVX-512BW); every build computes the
// same integers, and the floating-point steps use the same IEEE operations, in the same order,
// as the numpy oracle.
#if defined(__GNUC__) && !defined(__clang__)
// GCC 12's AVX-512 headers trip -Wmaybe-uninitialized on their own _mm512_undefined_*()
// placeholders when inlined (GCC bug 105593); set before any include so that it covers them.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

#include "semi_global_kernels.hpp"
#include "band_rule.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>

#include "stereodepth/block_match.hpp"

#if defined(__AVX2__)
#include <immintrin.h>
#endif

#ifndef STEREODEPTH_ISA_NS
#error "STEREODEPTH_ISA_NS must name the instruction set this file is compiled for"
#endif

namespace stereodepth::detail::STEREODEPTH_ISA_NS {
namespace {

using std::int16_t;
using std::ptrdiff_t;
using std::uint16_t;
using std::uint32_t;
using std::uint8_t;

inline ptrdiff_t clamp_index(ptrdiff_t v, ptrdiff_t lo, ptrdiff_t hi) {
  return v < lo ? lo : (v > hi ? hi : v);
}

inline int16_t min16(int16_t a, int16_t b) { return a < b ? a : b; }

// Paths 4 and 8 keep the sums of every pixel and disparity (2 bytes each: 21 MB for Cones at
// ndisp 64), written on the way down, read and written on the way up and read by the fused
// rows, each time a whole image after the last: beyond the caches. perf put a fifth of those
// passes' samples on the sums' loads and stores, which the hardware prefetchers (stopping at
// page boundaries) did not hide. So each pixel asks for the cache lines of the sums
// kPrefetchBytes ahead of its own. In one process on Zen 4, paths=8 took 0.87-0.98 of the
// time with one thread on the shared scenes from ndisp 32 on (Cones 0.89, Adirondack 0.88,
// KITTI 0.90), 0.89-0.98 with two (AVX2: 0.91-1.00), and 1.00-1.05 on Tsukuba, whose 3.5 MB
// of sums stay in the caches; 4 KB ahead and prefetcht1 measured no better (bench/README,
// twenty-fifth round).
constexpr ptrdiff_t kPrefetchBytes = 2048;

// The cache lines that start in the bytes [p + kPrefetchBytes, p + kPrefetchBytes + bytes),
// asked for ahead of use (kWrite: to be written; prefetchw): called for consecutive blocks,
// each line once.
template <bool kWrite>
inline void prefetch_ahead(const void* p, ptrdiff_t bytes) {
  const std::uintptr_t lo =
      reinterpret_cast<std::uintptr_t>(p) + static_cast<std::uintptr_t>(kPrefetchBytes);
  const std::uintptr_t hi = lo + static_cast<std::uintptr_t>(bytes);
  for (std::uintptr_t at = (lo + 63) & ~std::uintptr_t{63}; at < hi; at += 64) {
    __builtin_prefetch(reinterpret_cast<const void*>(at), kWrite ? 1 : 0, 3);
  }
}

// Set bits of a 16-bit census difference, in 16-bit lanes (vectorises without popcnt).
inline uint16_t popcount16(uint16_t v) {
  v = static_cast<uint16_t>(v - ((v >> 1) & 0x5555u));
  v = static_cast<uint16_t>((v & 0x3333u) + ((v >> 2) & 0x3333u));
  v = static_cast<uint16_t>((v + (v >> 4)) & 0x0F0Fu);
  return static_cast<uint16_t>((v + (v >> 8)) & 0x001Fu);
}

// ------------------------------------------------------------------------------------------
// Costs.

void raw_row(const uint16_t* lrow, const uint16_t* rrow, ptrdiff_t cols, ptrdiff_t x0,
             ptrdiff_t x1, int radius, int nd, int min_d, uint16_t* rev, uint16_t* out) {
  // rev[u] = right[clamp(cols - 1 - min_d - u)]: the right pixel of column x and index k is
  // rev[cols - 1 - x + k], rising with k.
  const ptrdiff_t rl = cols + nd;
  for (ptrdiff_t u = 0; u < rl; ++u) rev[u] = rrow[clamp_index(cols - 1 - min_d - u, 0, cols - 1)];
  const ptrdiff_t n = x1 - x0 + 2 * radius;
#if defined(__AVX2__)
  // Set bits of 16 lanes at a time: a nibble lookup (vpshufb), then the two bytes' sum.
  const __m256i table = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1,
                                         2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
  const __m256i low4 = _mm256_set1_epi8(0x0F);
  const __m256i low8 = _mm256_set1_epi16(0x00FF);
  const int nv = nd / 16;
#endif
  for (ptrdiff_t j = 0; j < n; ++j) {
    const ptrdiff_t x = clamp_index(x0 - radius + j, 0, cols - 1);
    uint16_t* __restrict o = out + j * nd;
    const uint16_t l = lrow[x];
    const uint16_t* __restrict rv = rev + (cols - 1 - x);
    int k = 0;
#if defined(__AVX2__)
    const __m256i lv = _mm256_set1_epi16(static_cast<short>(l));
    for (int i = 0; i < nv; ++i, k += 16) {
      const __m256i d = _mm256_xor_si256(
          lv, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(rv + k)));
      const __m256i c = _mm256_add_epi8(
          _mm256_shuffle_epi8(table, _mm256_and_si256(d, low4)),
          _mm256_shuffle_epi8(table, _mm256_and_si256(_mm256_srli_epi16(d, 4), low4)));
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(o + k),
                          _mm256_add_epi16(_mm256_and_si256(c, low8), _mm256_srli_epi16(c, 8)));
    }
#endif
    for (; k < nd; ++k) o[k] = popcount16(static_cast<uint16_t>(l ^ rv[k]));
  }
}

void box_row(const uint16_t* const* raws, int radius, ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1,
             int nd, int min_d, int cmax, uint16_t* colsum, uint8_t* out) {
  const ptrdiff_t n = (x1 - x0 + 2 * radius) * nd;
  if (radius == 0) {
    colsum = const_cast<uint16_t*>(raws[0]);
  } else {
    const uint16_t* __restrict a = raws[0];
    const uint16_t* __restrict b = raws[1];
    const uint16_t* __restrict c = raws[2];
    for (ptrdiff_t i = 0; i < n; ++i) colsum[i] = static_cast<uint16_t>(a[i] + b[i] + c[i]);
  }
  for (ptrdiff_t x = x0; x < x1; ++x) {
    uint8_t* __restrict o = out + x * nd;
    const ptrdiff_t j = x - x0 + radius;
    if (radius == 0) {
      const uint16_t* __restrict a = colsum + j * nd;
      for (int k = 0; k < nd; ++k) o[k] = static_cast<uint8_t>(a[k]);
    } else {
      // Columns x - 1 and x + 1 clamped to the image: the raw rows repeat the edge columns.
      const uint16_t* __restrict a = colsum + (j - 1) * nd;
      const uint16_t* __restrict b = colsum + j * nd;
      const uint16_t* __restrict c = colsum + (j + 1) * nd;
      for (int k = 0; k < nd; ++k) o[k] = static_cast<uint8_t>(a[k] + b[k] + c[k]);
    }
    // Candidates whose right pixel x - min_d - k leaves the image cost the most.
    const ptrdiff_t khi = x - min_d;             // right pixel >= 0
    const ptrdiff_t klo = x - min_d - cols + 1;  // right pixel <= cols - 1
    for (ptrdiff_t k = clamp_index(khi + 1, 0, nd); k < nd; ++k) o[k] = static_cast<uint8_t>(cmax);
    for (ptrdiff_t k = 0, e = clamp_index(klo, 0, nd); k < e; ++k) {
      o[k] = static_cast<uint8_t>(cmax);
    }
  }
}

// ------------------------------------------------------------------------------------------
// Paths.

// P2' for the grey levels gp and gq (0 .. 255) of two neighbours on a path: an indexed load
// by the signed step (PathParams::p2), with no branch on its sign.
inline int p2_for(const PathParams& p, int gp, int gq) { return p.p2[gp - gq]; }

enum class SumMode { kWrite, kAdd };

// A path's first pixel: L = C. Returns min L.
template <SumMode kMode>
inline int16_t path_start(const uint8_t* __restrict c, int16_t* __restrict out, int nd,
                          uint16_t* __restrict s) {
  int16_t mn = std::numeric_limits<int16_t>::max();
  for (int d = 0; d < nd; ++d) {
    const int16_t v = static_cast<int16_t>(c[d]);
    out[d + 1] = v;
    mn = min16(mn, v);
    if constexpr (kMode == SumMode::kWrite) {
      s[d] = static_cast<uint16_t>(v);
    } else {
      s[d] = static_cast<uint16_t>(s[d] + static_cast<uint16_t>(v));
    }
  }
  return mn;
}

// L(p, d) = C(p, d) + min(L(q, d), L(q, d -+ 1) + P1, m + P2') - m, from prev (L(q, .), with
// sentinels); returns min L(p, .).
template <SumMode kMode>
inline int16_t path_step(const int16_t* __restrict prev, const uint8_t* __restrict c,
                         int16_t* __restrict out, int nd, int p1, int p2, int m,
                         uint16_t* __restrict s) {
  const int16_t vp1 = static_cast<int16_t>(p1);
  const int16_t mp2 = static_cast<int16_t>(m + p2);
  const int16_t vm = static_cast<int16_t>(m);
  int16_t mn = std::numeric_limits<int16_t>::max();
  for (int d = 0; d < nd; ++d) {
    const int16_t a = prev[d + 1];
    const int16_t be = static_cast<int16_t>(min16(prev[d], prev[d + 2]) + vp1);
    const int16_t v = min16(min16(a, mp2), be);
    const int16_t o = static_cast<int16_t>(static_cast<int16_t>(c[d]) + (v - vm));
    out[d + 1] = o;
    mn = min16(mn, o);
    if constexpr (kMode == SumMode::kWrite) {
      s[d] = static_cast<uint16_t>(o);
    } else {
      s[d] = static_cast<uint16_t>(s[d] + static_cast<uint16_t>(o));
    }
  }
  return mn;
}

void horizontal_row(const PathParams& p, const uint8_t* c, const uint8_t* g, ptrdiff_t cols,
                    uint16_t* s, int16_t* tmp) {
  const int nd = p.nd, ls = p.ls;
  int16_t* a = tmp;
  int16_t* b = tmp + ls;
  a[0] = a[nd + 1] = b[0] = b[nd + 1] = kSentinel;
  // From the left.
  int m = path_start<SumMode::kAdd>(c, a, nd, s);
  for (ptrdiff_t x = 1; x < cols; ++x) {
    const int p2 = p2_for(p, g[x], g[x - 1]);
    m = path_step<SumMode::kAdd>(a, c + x * nd, b, nd, p.p1, p2, m, s + x * nd);
    std::swap(a, b);
  }
  // From the right.
  const ptrdiff_t last = cols - 1;
  m = path_start<SumMode::kAdd>(c + last * nd, a, nd, s + last * nd);
  for (ptrdiff_t x = last - 1; x >= 0; --x) {
    const int p2 = p2_for(p, g[x], g[x + 1]);
    m = path_step<SumMode::kAdd>(a, c + x * nd, b, nd, p.p1, p2, m, s + x * nd);
    std::swap(a, b);
  }
}

template <SumMode kMode>
void path_row_impl(const PathParams& p, const uint8_t* c, const uint8_t* g, const uint8_t* gprev,
                   const int16_t* prev, int16_t* cur, ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1,
                   int dx, uint16_t* s) {
  const int nd = p.nd, ls = p.ls;
  for (ptrdiff_t x = x0; x < x1; ++x) {
    const ptrdiff_t xq = x - dx;
    int16_t* out = cur + x * ls;
    int16_t mn;
    if (prev == nullptr || xq < 0 || xq >= cols) {
      mn = path_start<kMode>(c + x * nd, out, nd, s + x * nd);
    } else {
      const int16_t* q = prev + xq * ls;
      const int p2 = p2_for(p, g[x], gprev[xq]);
      mn = path_step<kMode>(q, c + x * nd, out, nd, p.p1, p2, q[nd + 2], s + x * nd);
    }
    out[nd + 2] = mn;  // the pixel's least path cost, for the next row
  }
}

void path_row(const PathParams& p, const uint8_t* c, const uint8_t* g, const uint8_t* gprev,
              const int16_t* prev, int16_t* cur, ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1,
              int dx, uint16_t* s, bool write) {
  if (write) {
    path_row_impl<SumMode::kWrite>(p, c, g, gprev, prev, cur, cols, x0, x1, dx, s);
  } else {
    path_row_impl<SumMode::kAdd>(p, c, g, gprev, prev, cur, cols, x0, x1, dx, s);
  }
}

// ------------------------------------------------------------------------------------------
// Winner, checks, sub-pixel step.

constexpr uint32_t kNone = 0x10000u;  // "no second-best"; above every sum (sums <= 65532)

// The least sum over indices lo .. hi, its lowest index, and the least sum more than one
// index away from it (kNone when there is none).
inline void winner_of(const uint16_t* __restrict sx, ptrdiff_t lo, ptrdiff_t hi, uint32_t& best,
                      ptrdiff_t& kb, uint32_t& second) {
  // The least of sum << 16 | k: the least sum and its lowest index at once.
  uint32_t key = 0xFFFFFFFFu;
  for (ptrdiff_t k = lo; k <= hi; ++k) {
    const uint32_t v = (static_cast<uint32_t>(sx[k]) << 16) | static_cast<uint32_t>(k);
    key = v < key ? v : key;
  }
  best = key >> 16;
  kb = static_cast<ptrdiff_t>(key & 0xFFFFu);
  second = kNone;
  const int kb32 = static_cast<int>(kb), hi32 = static_cast<int>(hi);
  for (int k = static_cast<int>(lo); k <= hi32; ++k) {
    const unsigned dk = static_cast<unsigned>(k - kb32 + 1);  // > 2: more than one away
    const uint32_t sk = sx[k];
    const uint32_t v = dk > 2u ? sk : kNone;
    second = v < second ? v : second;
  }
}

#if defined(__AVX2__)
inline uint32_t hmin_epu16(__m256i v) {
  const __m128i m = _mm_min_epu16(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
  return static_cast<uint32_t>(_mm_cvtsi128_si32(_mm_minpos_epu16(m)) & 0xFFFF);
}

// winner_of over the whole range 0 .. nd - 1, 16 lanes at a time (the same results).
inline void winner_full(const uint16_t* __restrict sx, int nd, uint32_t& best, ptrdiff_t& kb,
                        uint32_t& second) {
  const int nv = nd / 16;
  if (nv == 0) {
    winner_of(sx, 0, nd - 1, best, kb, second);
    return;
  }
  auto load = [&](int i) {
    return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(sx + 16 * i));
  };
  __m256i m = load(0);
  for (int i = 1; i < nv; ++i) m = _mm256_min_epu16(m, load(i));
  uint32_t b = hmin_epu16(m);
  for (int k = 16 * nv; k < nd; ++k) b = sx[k] < b ? sx[k] : b;
  const __m256i bv = _mm256_set1_epi16(static_cast<short>(b));
  int k0 = -1;
  for (int i = 0; i < nv; ++i) {
    const unsigned mask =
        static_cast<unsigned>(_mm256_movemask_epi8(_mm256_cmpeq_epi16(load(i), bv)));
    if (mask) {
      k0 = 16 * i + __builtin_ctz(mask) / 2;
      break;
    }
  }
  if (k0 < 0) {
    k0 = 16 * nv;
    while (sx[k0] != b) ++k0;
  }
  // The least sum with the lanes k0 - 1 .. k0 + 1 set to 0xFFFF (above every sum).
  const __m256i iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m256i two = _mm256_set1_epi16(2);
  __m256i s2 = _mm256_set1_epi16(-1);
  for (int i = 0; i < nv; ++i) {
    const __m256i first = _mm256_set1_epi16(static_cast<short>(k0 - 1 - 16 * i));
    const __m256i rel = _mm256_sub_epi16(iota, first);
    const __m256i ex = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, two), rel);
    s2 = _mm256_min_epu16(s2, _mm256_or_si256(load(i), ex));
  }
  uint32_t sec = hmin_epu16(s2);
  for (int k = 16 * nv; k < nd; ++k) {
    if ((k < k0 - 1 || k > k0 + 1) && sx[k] < sec) sec = sx[k];
  }
  best = b;
  kb = k0;
  second = sec == 0xFFFFu ? kNone : sec;
}

// The least sum more than one index away from k0 over 0 .. nd - 1 (nd a multiple of 16).
inline uint32_t second_full(const uint16_t* __restrict sx, int nd, int k0) {
  const __m256i iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m256i two = _mm256_set1_epi16(2);
  __m256i s2 = _mm256_set1_epi16(-1);
  for (int i = 0; i < nd / 16; ++i) {
    const __m256i first = _mm256_set1_epi16(static_cast<short>(k0 - 1 - 16 * i));
    const __m256i rel = _mm256_sub_epi16(iota, first);
    const __m256i ex = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, two), rel);
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(sx + 16 * i));
    s2 = _mm256_min_epu16(s2, _mm256_or_si256(v, ex));
  }
  const uint32_t sec = hmin_epu16(s2);
  return sec == 0xFFFFu ? kNone : sec;
}

// For a pixel with the whole range (nd a multiple of 16): the right winners' update of
// decide_row and the pixel's own least sum and its lowest index, in one sweep. Returns
// best << 16 | kb.
inline uint32_t right_update_and_winner(const uint16_t* __restrict sx, int nd,
                                        uint16_t* __restrict rm, uint16_t* __restrict ra) {
  const __m256i iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  __m256i mv = _mm256_set1_epi16(-1);  // per lane: the least sum so far and its first index
  __m256i iv = _mm256_setzero_si256();
  for (int i = 0; i < nd / 16; ++i) {
    const __m256i k = _mm256_add_epi16(iota, _mm256_set1_epi16(static_cast<short>(16 * i)));
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(sx + 16 * i));
    __m256i* rp = reinterpret_cast<__m256i*>(rm + 16 * i);
    __m256i* ap = reinterpret_cast<__m256i*>(ra + 16 * i);
    const __m256i r = _mm256_loadu_si256(rp);
    const __m256i m = _mm256_min_epu16(r, v);
    const __m256i keep = _mm256_cmpeq_epi16(m, r);  // r <= v: no strict improvement
    _mm256_storeu_si256(rp, m);
    _mm256_storeu_si256(ap, _mm256_blendv_epi8(k, _mm256_loadu_si256(ap), keep));
    const __m256i mm = _mm256_min_epu16(mv, v);
    iv = _mm256_blendv_epi8(k, iv, _mm256_cmpeq_epi16(mm, mv));
    mv = mm;
  }
  const uint32_t best = hmin_epu16(mv);
  // The lowest index among the lanes holding the least sum.
  const __m256i at = _mm256_or_si256(
      iv, _mm256_xor_si256(_mm256_cmpeq_epi16(mv, _mm256_set1_epi16(static_cast<short>(best))),
                           _mm256_set1_epi16(-1)));
  const uint32_t kb = hmin_epu16(at);
  return (best << 16) | kb;
}
#endif

void decide_row(const DecideArgs& a, const uint16_t* s, float* disp, float* conf, uint16_t* rmin,
                uint16_t* rarg, uint32_t* winners) {
  const ptrdiff_t cols = a.cols;
  const int nd = a.nd;
  const ptrdiff_t dmin = a.min_d;
  const bool lr_on = a.lr_max_diff >= 0;
  auto range = [&](ptrdiff_t x, ptrdiff_t& klo, ptrdiff_t& khi) {
    klo = clamp_index(x - dmin - cols + 1, 0, nd);
    khi = clamp_index(x - dmin, -1, nd - 1);
  };
  // winners[x]: best << 16 | kb when the right winners' sweep found it, else 0xFFFFFFFF.
  for (ptrdiff_t x = 0; x < cols; ++x) winners[x] = 0xFFFFFFFFu;
  if (lr_on) {
    // The right image's winners: right column xr = x - dmin - k at j = cols - 1 - xr, rising
    // with k; x rises, so k does for each j, and a strict < keeps the lowest. Each column
    // starts at the least cost (0xFFFF) with its first candidate, so a column whose sums are
    // all 0xFFFF keeps that one, as the oracle's argmin does.
    for (ptrdiff_t j = 0; j < cols; ++j) {
      const ptrdiff_t xr = cols - 1 - j;
      rmin[j] = 0xFFFFu;
      rarg[j] = static_cast<uint16_t>(clamp_index(-dmin - xr, 0, nd - 1));
    }
    for (ptrdiff_t x = 0; x < cols; ++x) {
      ptrdiff_t klo, khi;
      range(x, klo, khi);
      const uint16_t* __restrict sx = s + x * a.stride;
      uint16_t* __restrict rm = rmin + (cols - 1 - x + dmin + klo);
      uint16_t* __restrict ra = rarg + (cols - 1 - x + dmin + klo);
      const ptrdiff_t n = khi - klo + 1;
      if (n <= 0) continue;
#if defined(__AVX2__)
      if (n == nd && nd % 16 == 0) {
        winners[x] = right_update_and_winner(sx, nd, rm, ra);
        continue;
      }
#endif
      for (ptrdiff_t i = 0; i < n; ++i) {
        const uint16_t v = sx[klo + i], r = rm[i];
        const bool lt = v < r;
        rm[i] = lt ? v : r;
        ra[i] = lt ? static_cast<uint16_t>(klo + i) : ra[i];
      }
    }
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (ptrdiff_t x = 0; x < cols; ++x) {
    ptrdiff_t klo, khi;
    range(x, klo, khi);
    const uint16_t* __restrict sx = s + x * a.stride;
    bool ok = klo <= khi;
    if (!a.clip_border) ok = ok && x - dmin - nd + 1 >= 0 && x - dmin <= cols - 1;
    if (!ok) {
      disp[x] = nan;
      if (conf) conf[x] = 0.0f;
      continue;
    }
    uint32_t best, second;
    ptrdiff_t kb;
#if defined(__AVX2__)
    if (winners[x] != 0xFFFFFFFFu) {
      best = winners[x] >> 16;
      kb = static_cast<ptrdiff_t>(winners[x] & 0xFFFFu);
      second = second_full(sx, nd, static_cast<int>(kb));
    } else if (klo == 0 && khi == nd - 1) {
      winner_full(sx, nd, best, kb, second);
    } else {
      winner_of(sx, klo, khi, best, kb, second);
    }
#else
    winner_of(sx, klo, khi, best, kb, second);
#endif
    const bool has2 = second != kNone;
    if (a.uniqueness_factor > 0 && has2) {
      ok = static_cast<double>(second) * 100.0 > static_cast<double>(best) * a.uniqueness_factor;
    }
    if (ok && lr_on) {
      const ptrdiff_t j = cols - 1 - (x - dmin - kb);
      const ptrdiff_t kr = rarg[j];
      const ptrdiff_t diff = kb > kr ? kb - kr : kr - kb;
      ok = static_cast<double>(diff) <= a.lr_max_diff;
    }
    if (!ok) {
      disp[x] = nan;
      if (conf) conf[x] = 0.0f;
      continue;
    }
    float d = static_cast<float>(dmin + kb);
    if (a.subpixel != static_cast<int>(SubpixelFit::kNone) && kb - 1 >= klo && kb + 1 <= khi) {
      const int32_t c0 = sx[kb - 1];
      const int32_t c1 = static_cast<int32_t>(best);
      const int32_t c2 = sx[kb + 1];
      const float num = static_cast<float>(c0 - c2);
      float den;
      if (a.subpixel == static_cast<int>(SubpixelFit::kParabola)) {
        den = static_cast<float>(2 * (c0 + c2 - 2 * c1));
      } else {
        den = static_cast<float>(2 * (c0 - c1 > c2 - c1 ? c0 - c1 : c2 - c1));
      }
      if (den > 0.0f) d = d + num / den;
    }
    disp[x] = d;
    if (conf) {
      conf[x] = !has2        ? 1.0f
                : second > 0 ? static_cast<float>(second - best) / static_cast<float>(second)
                             : 0.0f;
    }
  }
  if (a.clip_border) drop_unrivalled(disp, conf, cols, dmin, nd);
}

// ------------------------------------------------------------------------------------------
// 8-bit costs (RawRow8Fn, BoxRow8Fn): one template for AVX2 (B256) and AVX-512 (B512).

#if defined(__AVX2__)
struct B256 {
  using R = __m256i;
  static constexpr int kLanes = 32;
  static R load(const void* p) { return _mm256_loadu_si256(static_cast<const R*>(p)); }
  static void store(void* p, R v) { _mm256_storeu_si256(static_cast<R*>(p), v); }
  static R set1(int v) { return _mm256_set1_epi8(static_cast<char>(v)); }
  static R add(R a, R b) { return _mm256_add_epi8(a, b); }
  // Set bits of each byte (the AVX-512 build: vpopcntb, BITALG; else nibbles looked up).
  static R popcount(R v) {
#if defined(__AVX512BITALG__)
    return _mm256_popcnt_epi8(v);
#else
    const R table = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2,
                                     1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
    const R low4 = _mm256_set1_epi8(0x0F);
    return _mm256_add_epi8(
        _mm256_shuffle_epi8(table, _mm256_and_si256(v, low4)),
        _mm256_shuffle_epi8(table, _mm256_and_si256(_mm256_srli_epi16(v, 4), low4)));
#endif
  }
  static R hamming(R lo, R hi, R llo, R lhi) {
    return add(popcount(_mm256_xor_si256(lo, llo)), popcount(_mm256_xor_si256(hi, lhi)));
  }
  // Two halves from two addresses; the low half stored alone.
  static R load2(const void* p0, const void* p1) {
    return _mm256_inserti128_si256(
        _mm256_castsi128_si256(_mm_loadu_si128(static_cast<const __m128i*>(p0))),
        _mm_loadu_si128(static_cast<const __m128i*>(p1)), 1);
  }
  static void store_lo(void* p, R v) {
    _mm_storeu_si128(static_cast<__m128i*>(p), _mm256_castsi256_si128(v));
  }
  static __m128i low(R v) { return _mm256_castsi256_si128(v); }
};

// The same with 16 bytes, for the transposed layout's costs when nd is an odd multiple of 16
// (16, 48, 80, ...): whole vectors, where B256 would leave 16 bytes of each column to a
// scalar tail.
struct B128 {
  using R = __m128i;
  static constexpr int kLanes = 16;
  static R load(const void* p) { return _mm_loadu_si128(static_cast<const R*>(p)); }
  static void store(void* p, R v) { _mm_storeu_si128(static_cast<R*>(p), v); }
  static R set1(int v) { return _mm_set1_epi8(static_cast<char>(v)); }
  static R add(R a, R b) { return _mm_add_epi8(a, b); }
  static R popcount(R v) {
#if defined(__AVX512BITALG__)
    return _mm_popcnt_epi8(v);
#else
    const R table = _mm_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
    const R low4 = _mm_set1_epi8(0x0F);
    return _mm_add_epi8(_mm_shuffle_epi8(table, _mm_and_si128(v, low4)),
                        _mm_shuffle_epi8(table, _mm_and_si128(_mm_srli_epi16(v, 4), low4)));
#endif
  }
  static R hamming(R lo, R hi, R llo, R lhi) {
    return add(popcount(_mm_xor_si128(lo, llo)), popcount(_mm_xor_si128(hi, lhi)));
  }
};
#endif

#if defined(__AVX512BW__)
struct B512 {
  using R = __m512i;
  static constexpr int kLanes = 64;
  static R load(const void* p) { return _mm512_loadu_si512(p); }
  static void store(void* p, R v) { _mm512_storeu_si512(p, v); }
  static R set1(int v) { return _mm512_set1_epi8(static_cast<char>(v)); }
  static R add(R a, R b) { return _mm512_add_epi8(a, b); }
  static R popcount(R v) {
#if defined(__AVX512BITALG__)
    return _mm512_popcnt_epi8(v);
#else
    const R table = _mm512_broadcast_i32x4(
        _mm_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4));
    const R low4 = _mm512_set1_epi8(0x0F);
    return _mm512_add_epi8(
        _mm512_shuffle_epi8(table, _mm512_and_si512(v, low4)),
        _mm512_shuffle_epi8(table, _mm512_and_si512(_mm512_srli_epi16(v, 4), low4)));
#endif
  }
  static R hamming(R lo, R hi, R llo, R lhi) {
    return add(popcount(_mm512_xor_si512(lo, llo)), popcount(_mm512_xor_si512(hi, lhi)));
  }
  static R load2(const void* p0, const void* p1) {
    return _mm512_inserti64x4(
        _mm512_castsi256_si512(_mm256_loadu_si256(static_cast<const __m256i*>(p0))),
        _mm256_loadu_si256(static_cast<const __m256i*>(p1)), 1);
  }
  static void store_lo(void* p, R v) {
    _mm256_storeu_si256(static_cast<__m256i*>(p), _mm512_castsi512_si256(v));
  }
  static __m256i low(R v) { return _mm512_castsi512_si256(v); }
};
#endif

#if defined(__AVX2__)
// rev: the right census row reversed and split into its low bytes (rev[u]) and high bytes
// (rev[cols + nd + 32 + u]) for u in 0 .. cols + nd - 1: right[clamp(cols - 1 - min_d - u)];
// the right pixel of column x and index k is at u = cols - 1 - x + k, rising with k.
inline void split_reversed(const uint16_t* rrow, ptrdiff_t cols, int nd, int min_d,
                           uint8_t* rev) {
  const ptrdiff_t rl = cols + nd;
  uint8_t* rlo = rev;
  uint8_t* rhi = rev + rl + 32;
  // u with cols - 1 - min_d - u inside the image: u0 .. u1 - 1; the edge pixels outside.
  const ptrdiff_t u0 = clamp_index(-min_d, 0, rl);
  const ptrdiff_t u1 = clamp_index(cols - min_d, u0, rl);
  for (ptrdiff_t u = 0; u < u0; ++u) {
    rlo[u] = static_cast<uint8_t>(rrow[cols - 1] & 0xFF);
    rhi[u] = static_cast<uint8_t>(rrow[cols - 1] >> 8);
  }
  const uint16_t* __restrict src = rrow + (cols - 1 - min_d);
  for (ptrdiff_t u = u0; u < u1; ++u) {
    const uint16_t v = src[-u];
    rlo[u] = static_cast<uint8_t>(v & 0xFF);
    rhi[u] = static_cast<uint8_t>(v >> 8);
  }
  for (ptrdiff_t u = u1; u < rl; ++u) {
    rlo[u] = static_cast<uint8_t>(rrow[0] & 0xFF);
    rhi[u] = static_cast<uint8_t>(rrow[0] >> 8);
  }
}

// The pixel costs of left column x (census l) against the split right row, into o (nd bytes).
template <class B>
inline void hamming_column(uint16_t l, const uint8_t* rev, ptrdiff_t cols, ptrdiff_t x, int nd,
                           uint8_t* __restrict o) {
  constexpr int N = B::kLanes;
  const uint8_t* __restrict lo = rev + (cols - 1 - x);
  const uint8_t* __restrict hi = rev + (cols + nd + 32) + (cols - 1 - x);
  const typename B::R llo = B::set1(l & 0xFF), lhi = B::set1(l >> 8);
  int k = 0;
  for (; k + N <= nd; k += N) {
    B::store(o + k, B::hamming(B::load(lo + k), B::load(hi + k), llo, lhi));
  }
  for (; k < nd; ++k) {
    o[k] = static_cast<uint8_t>(popcount16(static_cast<uint16_t>(l ^ (lo[k] | hi[k] << 8))));
  }
}

// The transposed layout of a pixel's nd values for vectors of kT lanes (nv = nd / kT
// vectors): value k at position (k % nv) * kT + k / nv, so that lane j of vector v holds
// k = j * nv + v and the neighbours k - 1, k + 1 of vector v are vectors v - 1, v + 1 (only
// the first and the last vector need a shift by one lane). kT == 0: the plain layout.
// o at the positions of k = k0 .. k1 - 1 set to v (k0 == 0 or k1 == nd): in the transposed
// layout one run of lanes per vector.
template <int kT>
inline void fill_range(uint8_t* __restrict o, ptrdiff_t k0, ptrdiff_t k1, int nd, int v) {
  if (k0 >= k1) return;
  if constexpr (kT == 0) {
    for (ptrdiff_t k = k0; k < k1; ++k) o[k] = static_cast<uint8_t>(v);
  } else {
    // One masked store per vector (a plain loop here becomes a memset call per vector).
    static_assert(kT == 16 || kT == 32, "16 or 32 lanes");
    auto set1 = [](int b) {
      if constexpr (kT == 16) {
        return _mm_set1_epi8(static_cast<char>(b));
      } else {
        return _mm256_set1_epi8(static_cast<char>(b));
      }
    };
    auto iota = [] {
      if constexpr (kT == 16) {
        return _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
      } else {
        return _mm256_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18,
                                19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31);
      }
    };
    using W = decltype(iota());
    const W lanes = iota(), fill = set1(v);
    const ptrdiff_t nv = nd / kT;
    for (ptrdiff_t r = 0; r < nv; ++r) {
      // Lanes j with k0 <= j * nv + r < k1: j0 <= j < j1 (at most kT).
      const ptrdiff_t j0 = k0 > r ? (k0 - r + nv - 1) / nv : 0;
      const ptrdiff_t j1 = k1 > r ? (k1 - r + nv - 1) / nv : 0;
      if (j0 >= j1) continue;
      uint8_t* p = o + r * kT;
      if constexpr (kT == 16) {
        // in: lane > j0 - 1 and j1 > lane (signed bytes: lanes, j0 and j1 are at most 32).
        // Two compares and an AND: GCC 12.2 with the AVX-512 flags compiled the earlier
        // andnot(j0 > lane, j1 > lane) so that this function filled the lanes below j0
        // instead (wrong costs in the left border band; seen on the first AVX-512 machine
        // the tests ran on, fine with the AVX2 flags, under the sanitizers and with clang).
        const W in = _mm_and_si128(_mm_cmpgt_epi8(lanes, set1(static_cast<int>(j0 - 1))),
                                   _mm_cmpgt_epi8(set1(static_cast<int>(j1)), lanes));
        const W cur = _mm_loadu_si128(reinterpret_cast<const W*>(p));
        _mm_storeu_si128(reinterpret_cast<W*>(p), _mm_blendv_epi8(cur, fill, in));
      } else {
        const W in = _mm256_and_si256(_mm256_cmpgt_epi8(lanes, set1(static_cast<int>(j0 - 1))),
                                      _mm256_cmpgt_epi8(set1(static_cast<int>(j1)), lanes));
        const W cur = _mm256_loadu_si256(reinterpret_cast<const W*>(p));
        _mm256_storeu_si256(reinterpret_cast<W*>(p), _mm256_blendv_epi8(cur, fill, in));
      }
    }
  }
}

// The box's output column x: the disparities whose right pixel leaves the image (outside
// klo .. khi, as in raw_row) set to cmax; only columns of the border bands have any.
template <int kT>
inline void fill_border_column(uint8_t* __restrict o, ptrdiff_t x, ptrdiff_t cols, int nd,
                               int min_d, int cmax) {
  const ptrdiff_t khi = x - min_d;
  const ptrdiff_t klo = x - min_d - cols + 1;
  if (khi + 1 < nd || klo > 0) {
    fill_range<kT>(o, clamp_index(khi + 1, 0, nd), nd, nd, cmax);
    fill_range<kT>(o, 0, clamp_index(klo, 0, nd), nd, cmax);
  }
}

inline ptrdiff_t floor_div(ptrdiff_t a, ptrdiff_t b) {
  const ptrdiff_t q = a / b;
  return (a % b != 0 && (a < 0) != (b < 0)) ? q - 1 : q;
}

// The right census row for the transposed layout (kT lanes, nv = nd / kT): lane j of vector
// v of left column x needs the right pixel x - min_d - v - j * nv (clamped to the image), i.e.
// vector v is Z[x - v] with Z[t] lane j = right[t - min_d - j * nv]. Z is stored with t
// falling (Z[cols - 1] first), so that a column's nv vectors are nd consecutive bytes, as in
// the plain layout: low bytes in zlo, high bytes in zhi (rev8_bytes() of scratch in rev).
// Built from each residue r = w mod nv's run of the right pixels q * nv + r, q falling (the
// comb, cols + nd - 1 values), where Z[t] is kT consecutive bytes.
struct ZRow {
  const uint8_t* lo;
  const uint8_t* hi;
};

inline ZRow split_z(const uint16_t* rrow, ptrdiff_t cols, int nd, int min_d, int lanes,
                    uint8_t* rev) {
  const int nv = nd / lanes;
  const ptrdiff_t nz = (cols + nv - 1 + 1) * lanes;  // one spare vector after the last
  uint8_t* zlo = rev;
  uint8_t* zhi = rev + nz;
  uint8_t* clo = rev + 2 * nz;
  uint8_t* chi = clo + cols + nd;
  ptrdiff_t base[kMaxNumDisparities / 16];
  ptrdiff_t qlos[kMaxNumDisparities / 16], qhis[kMaxNumDisparities / 16];
  const ptrdiff_t wlo = -static_cast<ptrdiff_t>(min_d) - nd + 1;
  const ptrdiff_t whi = cols - 1 - min_d;
  ptrdiff_t off = 0;
  for (int r = 0; r < nv; ++r) {
    qlos[r] = -floor_div(r - wlo, nv);  // ceil((wlo - r) / nv)
    qhis[r] = floor_div(whi - r, nv);
    base[r] = off + qhis[r];  // w = q * nv + r at base[r] - q
    off += qhis[r] - qlos[r] + 1;
  }
  // With nv a multiple of 8, the q of whole blocks of 8 inside every run and the image
  // (w = q * nv + r in 0 .. cols - 1) by 8x8 transposes of the right row (nv / 8 per block
  // of 8 rows, of residues g .. g + 7 each): q from qb0 to qb1 - 1.
  ptrdiff_t qb0 = 0, qb1 = 0;
  if (nv % 8 == 0 && cols >= nv) {
    ptrdiff_t q0 = 0, q1 = cols / nv;  // rows q * nv .. q * nv + nv - 1 inside the image
    for (int r = 0; r < nv; ++r) {
      q0 = std::max(q0, qlos[r]);
      q1 = std::min(q1, qhis[r] + 1);
    }
    if (q1 - q0 >= 8) {
      qb0 = q0;
      qb1 = q0 + (q1 - q0) / 8 * 8;
      // Each block's run r: the values for q = q0 + 7 down to q0, at base[r] - q0 - 7 on;
      // the shuffle reverses the eight words and puts their low bytes first.
      const __m128i rev_split =
          _mm_setr_epi8(14, 12, 10, 8, 6, 4, 2, 0, 15, 13, 11, 9, 7, 5, 3, 1);
      // Residues g .. g + 7 of the rows q .. q + 7.
      auto transpose = [&](ptrdiff_t q, int g) {
        __m128i a[8];
        for (int i = 0; i < 8; ++i) {
          a[i] = _mm_loadu_si128(reinterpret_cast<const __m128i*>(rrow + (q + i) * nv + g));
        }
        const __m128i t0 = _mm_unpacklo_epi16(a[0], a[1]), t1 = _mm_unpackhi_epi16(a[0], a[1]);
        const __m128i t2 = _mm_unpacklo_epi16(a[2], a[3]), t3 = _mm_unpackhi_epi16(a[2], a[3]);
        const __m128i t4 = _mm_unpacklo_epi16(a[4], a[5]), t5 = _mm_unpackhi_epi16(a[4], a[5]);
        const __m128i t6 = _mm_unpacklo_epi16(a[6], a[7]), t7 = _mm_unpackhi_epi16(a[6], a[7]);
        const __m128i u0 = _mm_unpacklo_epi32(t0, t2), u1 = _mm_unpackhi_epi32(t0, t2);
        const __m128i u2 = _mm_unpacklo_epi32(t1, t3), u3 = _mm_unpackhi_epi32(t1, t3);
        const __m128i u4 = _mm_unpacklo_epi32(t4, t6), u5 = _mm_unpackhi_epi32(t4, t6);
        const __m128i u6 = _mm_unpacklo_epi32(t5, t7), u7 = _mm_unpackhi_epi32(t5, t7);
        const __m128i col[8] = {_mm_unpacklo_epi64(u0, u4), _mm_unpackhi_epi64(u0, u4),
                                _mm_unpacklo_epi64(u1, u5), _mm_unpackhi_epi64(u1, u5),
                                _mm_unpacklo_epi64(u2, u6), _mm_unpackhi_epi64(u2, u6),
                                _mm_unpacklo_epi64(u3, u7), _mm_unpackhi_epi64(u3, u7)};
        for (int r = 0; r < 8; ++r) {
          const __m128i b = _mm_shuffle_epi8(col[r], rev_split);
          const ptrdiff_t at = base[g + r] - q - 7;
          _mm_storel_epi64(reinterpret_cast<__m128i*>(clo + at), b);
          _mm_storel_epi64(reinterpret_cast<__m128i*>(chi + at), _mm_unpackhi_epi64(b, b));
        }
      };
      for (ptrdiff_t q = qb0; q < qb1; q += 8) {
        if (nv == 8) {
          transpose(q, 0);
        } else {
          for (int g = 0; g < nv; g += 8) transpose(q, g);
        }
      }
    }
  }
  for (int r = 0; r < nv; ++r) {
    // The run's q not done by the blocks: qhis[r] down to qb1, then qb0 - 1 down to qlos[r]
    // (all of them without blocks), in three parts each: right of the image (its last
    // pixel), inside it, left of it (its first pixel). In locals, as the byte stores may
    // alias base[] for the compiler.
    uint8_t* __restrict lo = clo + base[r];
    uint8_t* __restrict hi = chi + base[r];
    const ptrdiff_t qin_hi = floor_div(cols - 1 - r, nv);  // the last q inside the image
    const ptrdiff_t qin_lo = -floor_div(r, nv);             // the first (ceil(-r / nv))
    auto put = [&](ptrdiff_t q, uint16_t v) {
      lo[-q] = static_cast<uint8_t>(v & 0xFF);
      hi[-q] = static_cast<uint8_t>(v >> 8);
    };
    auto part = [&](ptrdiff_t qa, ptrdiff_t qb) {  // q = qa down to qb
      ptrdiff_t q = qa;
      for (; q >= qb && q > qin_hi; --q) put(q, rrow[cols - 1]);
      const ptrdiff_t qstop = std::max(qb, qin_lo);
      const uint16_t* __restrict src = rrow + r;
      for (; q >= qstop; --q) put(q, src[q * nv]);
      for (; q >= qb; --q) put(q, rrow[0]);
    };
    if (qb1 > qb0) {
      part(qhis[r], std::max(qb1, qlos[r]));
      part(std::min(qb0 - 1, qhis[r]), qlos[r]);
    } else {
      part(qhis[r], qlos[r]);
    }
  }
  // Z[t] for t = cols - 1 down to 1 - nv: w = t - min_d.
  ptrdiff_t w = cols - 1 - min_d;
  ptrdiff_t q = floor_div(w, nv);
  int r = static_cast<int>(w - q * nv);
  for (ptrdiff_t u = 0; u < cols + nv - 1; ++u) {
    const ptrdiff_t at = base[r] - q;
    std::memcpy(zlo + u * lanes, clo + at, static_cast<std::size_t>(lanes));
    std::memcpy(zhi + u * lanes, chi + at, static_cast<std::size_t>(lanes));
    if (--r < 0) {
      r = nv - 1;
      --q;
    }
  }
  return ZRow{zlo, zhi};
}

// The pixel costs of left column x (census l) in the transposed layout (kT lanes), into o.
template <class B, int kT>
inline void hamming_column_t(uint16_t l, const ZRow& z, ptrdiff_t cols, ptrdiff_t x, int nd,
                             uint8_t* __restrict o) {
  constexpr int N = B::kLanes;
  const uint8_t* __restrict lo = z.lo + (cols - 1 - x) * kT;
  const uint8_t* __restrict hi = z.hi + (cols - 1 - x) * kT;
  const typename B::R llo = B::set1(l & 0xFF), lhi = B::set1(l >> 8);
  int k = 0;
  for (; k + N <= nd; k += N) {
    B::store(o + k, B::hamming(B::load(lo + k), B::load(hi + k), llo, lhi));
  }
  if constexpr (N == 2 * kT) {
    if (k < nd) {  // kT bytes left (the spare vector after Z's last one is read, not used)
      B::store_lo(o + k, B::hamming(B::load(lo + k), B::load(hi + k), llo, lhi));
    }
  } else {
    static_assert(N == kT, "vectors of kT or 2 * kT bytes");  // nd % kT == 0: no tail
  }
}

// kT: the layout (0 plain, else transposed for kT lanes, B of 2 * kT bytes).
template <class B, int kT>
void raw_row8_impl(const uint16_t* lrow, const uint16_t* rrow, ptrdiff_t cols, ptrdiff_t x0,
                   ptrdiff_t x1, int radius, int nd, int min_d, uint8_t* rev, uint8_t* out) {
  ZRow z{};
  if constexpr (kT == 0) {
    split_reversed(rrow, cols, nd, min_d, rev);
  } else {
    z = split_z(rrow, cols, nd, min_d, kT, rev);
  }
  const ptrdiff_t n = x1 - x0 + 2 * radius;
  for (ptrdiff_t j = 0; j < n; ++j) {
    const ptrdiff_t x = clamp_index(x0 - radius + j, 0, cols - 1);
    if constexpr (kT == 0) {
      hamming_column<B>(lrow[x], rev, cols, x, nd, out + j * nd);
    } else {
      hamming_column_t<B, kT>(lrow[x], z, cols, x, nd, out + j * nd);
    }
  }
}

// box_row8_impl's one sweep for nd = M vectors (M small enough for the register file): the
// sums of the last two column sums (P) and the last one (Q) stay in registers from one
// column to the next, so no ring of column sums is stored and read back. fo, b, c: the
// fresh and the other two raw rows at raw column j + 1 of the first column x0.
template <class B, int M, int kT>
void box_sweep_regs(const uint8_t* zlo, const uint8_t* zhi, const uint16_t* lrow,
                    ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int min_d, int cmax,
                    const uint8_t* ring, uint8_t* fo, const uint8_t* b, const uint8_t* c,
                    uint8_t* out) {
  using R = typename B::R;
  constexpr int N = B::kLanes;
  constexpr int nd = M * N;
  constexpr ptrdiff_t step = kT == 0 ? 1 : kT;
  R pv[M], qv[M];
  for (int m = 0; m < M; ++m) {
    const R p = B::load(ring + m * N), q = B::load(ring + nd + m * N);
    pv[m] = B::add(p, q);
    qv[m] = q;
  }
  for (ptrdiff_t x = x0; x < x1; ++x) {
    uint8_t* __restrict o = out + x * nd;
    const ptrdiff_t xc = x + 1 < cols ? x + 1 : cols - 1;
    const ptrdiff_t zat = (cols - 1 - xc) * step;
    const uint16_t l = lrow[xc];
    const R llo = B::set1(l & 0xFF), lhi = B::set1(l >> 8);
#pragma GCC unroll 8
    for (int m = 0; m < M; ++m) {
      const R h = B::hamming(B::load(zlo + zat + m * N), B::load(zhi + zat + m * N), llo, lhi);
      B::store(fo + m * N, h);
      const R cs = B::add(B::add(h, B::load(b + m * N)), B::load(c + m * N));
      B::store(o + m * N, B::add(pv[m], cs));
      pv[m] = B::add(qv[m], cs);
      qv[m] = cs;
    }
    fo += nd;
    b += nd;
    c += nd;
    fill_border_column<kT>(o, x, cols, nd, min_d, cmax);
  }
}

// box_sweep_regs for the vector count m when 1 <= m <= kMax (one instance each); false for
// any other m.
template <class B, int kT, int kMax, int M = 1>
bool box_sweep_regs_upto(int m, const uint8_t* zlo, const uint8_t* zhi, const uint16_t* lrow,
                         ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int min_d, int cmax,
                         const uint8_t* ring, uint8_t* fo, const uint8_t* b, const uint8_t* c,
                         uint8_t* out) {
  if constexpr (M > kMax) {
    return false;
  } else {
    if (m == M) {
      box_sweep_regs<B, M, kT>(zlo, zhi, lrow, cols, x0, x1, min_d, cmax, ring, fo, b, c, out);
      return true;
    }
    return box_sweep_regs_upto<B, kT, kMax, M + 1>(m, zlo, zhi, lrow, cols, x0, x1, min_d, cmax,
                                                   ring, fo, b, c, out);
  }
}

// box_sweep_regs for nd = M2 wide vectors and one of half their width at the end (W of 2 * H
// bytes; nd = 32 * M2 + 16 with B256 and B128, or 64 * M2 + 32 with B512 and B256), which
// the wide vectors alone cannot cover. The sums are byte by byte, so the width of the vectors
// does not change them (box_sweep_regs with the narrow vectors alone gives the same bytes
// with almost twice the instructions).
template <class W, class H, int M2, int kT>
void box_sweep_mixed(const uint8_t* zlo, const uint8_t* zhi, const uint16_t* lrow,
                     ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int min_d, int cmax,
                     const uint8_t* ring, uint8_t* fo, const uint8_t* b, const uint8_t* c,
                     uint8_t* out) {
  static_assert(W::kLanes == 2 * H::kLanes, "a wide vector is two half ones");
  constexpr int NW = W::kLanes;
  constexpr int nd = NW * M2 + H::kLanes;
  constexpr ptrdiff_t t0 = NW * M2;  // the half vector's offset
  constexpr ptrdiff_t step = kT == 0 ? 1 : kT;
  typename W::R pv[M2], qv[M2];
  for (int m = 0; m < M2; ++m) {
    const typename W::R p = W::load(ring + m * NW), q = W::load(ring + nd + m * NW);
    pv[m] = W::add(p, q);
    qv[m] = q;
  }
  typename H::R pt = H::add(H::load(ring + t0), H::load(ring + nd + t0));
  typename H::R qt = H::load(ring + nd + t0);
  for (ptrdiff_t x = x0; x < x1; ++x) {
    uint8_t* __restrict o = out + x * nd;
    const ptrdiff_t xc = x + 1 < cols ? x + 1 : cols - 1;
    const ptrdiff_t zat = (cols - 1 - xc) * step;
    const uint16_t l = lrow[xc];
    const typename W::R llo = W::set1(l & 0xFF), lhi = W::set1(l >> 8);
#pragma GCC unroll 8
    for (int m = 0; m < M2; ++m) {
      const typename W::R h =
          W::hamming(W::load(zlo + zat + m * NW), W::load(zhi + zat + m * NW), llo, lhi);
      W::store(fo + m * NW, h);
      const typename W::R cs = W::add(W::add(h, W::load(b + m * NW)), W::load(c + m * NW));
      W::store(o + m * NW, W::add(pv[m], cs));
      pv[m] = W::add(qv[m], cs);
      qv[m] = cs;
    }
    {
      const typename H::R h = H::hamming(H::load(zlo + zat + t0), H::load(zhi + zat + t0),
                                         W::low(llo), W::low(lhi));
      H::store(fo + t0, h);
      const typename H::R cs = H::add(H::add(h, H::load(b + t0)), H::load(c + t0));
      H::store(o + t0, H::add(pt, cs));
      pt = H::add(qt, cs);
      qt = cs;
    }
    fo += nd;
    b += nd;
    c += nd;
    fill_border_column<kT>(o, x, cols, nd, min_d, cmax);
  }
}

// box_sweep_mixed for m2 wide vectors when 1 <= m2 <= kMax (one instance each); false for
// any other m2.
template <class W, class H, int kT, int kMax, int M2 = 1>
bool box_sweep_mixed_upto(int m2, const uint8_t* zlo, const uint8_t* zhi, const uint16_t* lrow,
                          ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int min_d, int cmax,
                          const uint8_t* ring, uint8_t* fo, const uint8_t* b, const uint8_t* c,
                          uint8_t* out) {
  if constexpr (M2 > kMax) {
    return false;
  } else {
    if (m2 == M2) {
      box_sweep_mixed<W, H, M2, kT>(zlo, zhi, lrow, cols, x0, x1, min_d, cmax, ring, fo, b, c,
                                    out);
      return true;
    }
    return box_sweep_mixed_upto<W, H, kT, kMax, M2 + 1>(m2, zlo, zhi, lrow, cols, x0, x1, min_d,
                                                        cmax, ring, fo, b, c, out);
  }
}

template <class B, int kT>
void box_row8_impl(uint8_t* const* raws, int fresh, const uint16_t* lrow, const uint16_t* rrow,
                   uint8_t* rev, int radius, ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int nd,
                   int min_d, int cmax, uint8_t* ring, uint8_t* out) {
  constexpr int N = B::kLanes;
  ZRow z{};
  if (fresh >= 0) {
    if constexpr (kT == 0) {
      split_reversed(rrow, cols, nd, min_d, rev);
    } else {
      z = split_z(rrow, cols, nd, min_d, kT, rev);
    }
  }
  // The fresh row (computed here, column by column) and the others.
  uint8_t* f = fresh >= 0 ? raws[fresh] : nullptr;
  const uint8_t* other[3];
  int n_other = 0;
  for (int i = 0; i < 2 * radius + 1; ++i) {
    if (i != fresh) other[n_other++] = raws[i];
  }
  // Raw column j (image column clamp(x0 - r + j)): the fresh row's costs, and the column sum
  // into ring slot j % 3 (radius 1) or the output (radius 0). The sums go value by value, so
  // they do not depend on the layout.
  auto column = [&](ptrdiff_t j, uint8_t* __restrict v) {
    const ptrdiff_t at = j * nd;
    if (f) {
      const ptrdiff_t x = clamp_index(x0 - radius + j, 0, cols - 1);
      if constexpr (kT == 0) {
        hamming_column<B>(lrow[x], rev, cols, x, nd, f + at);
      } else {
        hamming_column_t<B, kT>(lrow[x], z, cols, x, nd, f + at);
      }
    }
    if (radius == 0) {
      std::memcpy(v, (f ? f : other[0]) + at, static_cast<std::size_t>(nd));
      return;
    }
    const uint8_t* __restrict a = f ? f + at : other[2] + at;
    const uint8_t* __restrict b = other[0] + at;
    const uint8_t* __restrict c = other[1] + at;
    int k = 0;
    for (; k + N <= nd; k += N) {
      B::store(v + k, B::add(B::add(B::load(a + k), B::load(b + k)), B::load(c + k)));
    }
    for (; k < nd; ++k) v[k] = static_cast<uint8_t>(a[k] + b[k] + c[k]);
  };
  if (radius) {
    column(0, ring);
    column(1, ring + nd);
  }
  // With a fresh row and a 3x3 box: the fresh row's new column, its column sum and the box
  // sum in one sweep over the disparities (the same sums, fewer loads and loops). The ring's
  // three column sums rotate by pointer (no index mod 3 per column), the row pointers advance
  // by nd, and the border fill runs only for the columns whose range leaves the right image.
  // (B512 also takes nd = 64 * m + 32, the transposed layout's 96, 160, 224, ...: box_sweep_mixed.)
  constexpr bool kHalf = N == 64;  // B512 (not declared in the AVX2 build)
  if (radius == 1 && f != nullptr && (nd % N == 0 || (kHalf && nd % N == N / 2))) {
    uint8_t* p = ring;  // the column sums of raw columns j - 1, j and (new) j + 1
    uint8_t* q = ring + nd;
    uint8_t* s = ring + 2 * nd;
    const ptrdiff_t step = kT == 0 ? 1 : kT;
    const uint8_t* __restrict zlo;
    const uint8_t* __restrict zhi;
    if constexpr (kT == 0) {
      zlo = rev;
      zhi = rev + (cols + nd + 32);
    } else {
      zlo = z.lo;
      zhi = z.hi;
    }
    // Raw column j + 1 = x - x0 + 2 is image column x + 1 (clamped).
    uint8_t* fo = f + 2 * nd;
    const uint8_t* b = other[0] + 2 * nd;
    const uint8_t* c = other[1] + 2 * nd;
    if constexpr (std::is_same_v<B, B128>) {
      // nd an odd multiple of 16 from 48 on: 32-byte vectors and a 16-byte one (up to 144).
      if (nd % 32 == 16 && box_sweep_mixed_upto<B256, B128, kT, 4>(nd / 32, zlo, zhi, lrow, cols,
                                                                   x0, x1, min_d, cmax, ring,
                                                                   fo, b, c, out)) {
        return;
      }
    }
#if defined(__AVX512BW__)
    if constexpr (kHalf) {
      // nd = 64 * m + 32 (m = 1 .. 4: up to 288): 64-byte vectors and a 32-byte one; beyond,
      // the way of any width below.
      if (nd % N != 0) {
        if (box_sweep_mixed_upto<B512, B256, kT, 4>(nd / 64, zlo, zhi, lrow, cols, x0, x1,
                                                    min_d, cmax, ring, fo, b, c, out)) {
          return;
        }
      }
    }
#endif
    if (nd % N == 0) {
      // Up to 5 vectors the two sums per vector fit the 16 registers of AVX2.
      if (box_sweep_regs_upto<B, kT, 5>(nd / N, zlo, zhi, lrow, cols, x0, x1, min_d, cmax,
                                        ring, fo, b, c, out)) {
        return;
      }
      for (ptrdiff_t x = x0; x < x1; ++x) {
        uint8_t* __restrict o = out + x * nd;
        const ptrdiff_t xc = x + 1 < cols ? x + 1 : cols - 1;
        const uint8_t* __restrict lo = zlo + (cols - 1 - xc) * step;
        const uint8_t* __restrict hi = zhi + (cols - 1 - xc) * step;
        const uint16_t l = lrow[xc];
        const typename B::R llo = B::set1(l & 0xFF), lhi = B::set1(l >> 8);
        const uint8_t* __restrict pk = p;
        const uint8_t* __restrict qk = q;
        uint8_t* __restrict sk = s;
        for (int k = 0; k < nd; k += N) {
          const typename B::R h = B::hamming(B::load(lo + k), B::load(hi + k), llo, lhi);
          B::store(fo + k, h);
          const typename B::R cs = B::add(B::add(h, B::load(b + k)), B::load(c + k));
          B::store(sk + k, cs);
          B::store(o + k, B::add(B::add(B::load(pk + k), B::load(qk + k)), cs));
        }
        uint8_t* const t = p;
        p = q;
        q = s;
        s = t;
        fo += nd;
        b += nd;
        c += nd;
        fill_border_column<kT>(o, x, cols, nd, min_d, cmax);
      }
      return;
    }
  }
  for (ptrdiff_t x = x0; x < x1; ++x) {
    uint8_t* __restrict o = out + x * nd;
    const ptrdiff_t j = x - x0 + radius;
    if (radius == 0) {
      column(j, o);
    } else {
      column(j + 1, ring + ((j + 1) % 3) * nd);
      const uint8_t* __restrict p = ring + ((j - 1) % 3) * nd;
      const uint8_t* __restrict q = ring + (j % 3) * nd;
      const uint8_t* __restrict s = ring + ((j + 1) % 3) * nd;
      int k = 0;
      for (; k + N <= nd; k += N) {
        B::store(o + k, B::add(B::add(B::load(p + k), B::load(q + k)), B::load(s + k)));
      }
      for (; k < nd; ++k) o[k] = static_cast<uint8_t>(p[k] + q[k] + s[k]);
    }
    fill_border_column<kT>(o, x, cols, nd, min_d, cmax);
  }
}

// The plain layout's vectors: the widest whose bytes divide nd (nd is a multiple of 16), so
// that no column ends in a scalar tail (nd = 16, 48, 80, ... take 16 bytes, or 32 and 16 in
// box_sweep_mixed; the AVX-512 build 64 bytes only when they divide nd). A scalar tail cost
// paths=8 on Tsukuba (nd 16) a quarter of its time.
enum class Plain8 { k128, k256, k512 };
inline Plain8 plain8_width(int nd) {
#if defined(__AVX512BW__)
  if (nd % 64 == 0) return Plain8::k512;
#endif
  return nd % 32 == 0 ? Plain8::k256 : Plain8::k128;
}

void raw_row8(const uint16_t* lrow, const uint16_t* rrow, ptrdiff_t cols, ptrdiff_t x0,
              ptrdiff_t x1, int radius, int nd, int min_d, uint8_t* rev, uint8_t* out) {
  switch (plain8_width(nd)) {
#if defined(__AVX512BW__)
    case Plain8::k512:
      raw_row8_impl<B512, 0>(lrow, rrow, cols, x0, x1, radius, nd, min_d, rev, out);
      return;
#endif
    case Plain8::k256:
      raw_row8_impl<B256, 0>(lrow, rrow, cols, x0, x1, radius, nd, min_d, rev, out);
      return;
    default:
      raw_row8_impl<B128, 0>(lrow, rrow, cols, x0, x1, radius, nd, min_d, rev, out);
  }
}

void box_row8(uint8_t* const* raws, int fresh, const uint16_t* lrow, const uint16_t* rrow,
              uint8_t* rev, int radius, ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int nd,
              int min_d, int cmax, uint8_t* ring, uint8_t* out) {
  switch (plain8_width(nd)) {
#if defined(__AVX512BW__)
    case Plain8::k512:
      box_row8_impl<B512, 0>(raws, fresh, lrow, rrow, rev, radius, cols, x0, x1, nd, min_d,
                             cmax, ring, out);
      return;
#endif
    case Plain8::k256:
      box_row8_impl<B256, 0>(raws, fresh, lrow, rrow, rev, radius, cols, x0, x1, nd, min_d,
                             cmax, ring, out);
      return;
    default:
      box_row8_impl<B128, 0>(raws, fresh, lrow, rrow, rev, radius, cols, x0, x1, nd, min_d,
                             cmax, ring, out);
  }
}

#if defined(__AVX512BW__)
// Whether the AVX-512 build lays the transposed rows out for 512-bit vectors (32 lanes, V512)
// rather than 256-bit ones (16 lanes, V256): when nd makes at least two 512-bit vectors. With
// one, a pixel's fixed work (the shifts at the first and last vector of each path step, the
// horizontal minima) weighs more than the wider vectors save. One thread, in-process A/B,
// 512-bit over 256-bit time (Cones, Adirondack; bench/README, twenty-third round): ndisp 32:
// 1.315, 1.303; 64: 0.933, 0.945; 96: 0.871, 0.888. (Before P2' lost its branch, 64 and 96
// were the other way round: Cones, ns per pixel, 39 against 38 and 54 against 46.)
inline bool wide_transposed(int nd) { return nd % 32 == 0 && nd >= 64; }
#endif

// The same in the transposed layout of fused_row_t: the lanes of its vectors (32 when the
// AVX-512 build runs V512, i.e. wide_transposed(nd); else 16).
void raw_row8_t(const uint16_t* lrow, const uint16_t* rrow, ptrdiff_t cols, ptrdiff_t x0,
                ptrdiff_t x1, int radius, int nd, int min_d, uint8_t* rev, uint8_t* out) {
#if defined(__AVX512BW__)
  if (wide_transposed(nd)) {
    raw_row8_impl<B512, 32>(lrow, rrow, cols, x0, x1, radius, nd, min_d, rev, out);
    return;
  }
#endif
  raw_row8_impl<B256, 16>(lrow, rrow, cols, x0, x1, radius, nd, min_d, rev, out);
}

void box_row8_t(uint8_t* const* raws, int fresh, const uint16_t* lrow, const uint16_t* rrow,
                uint8_t* rev, int radius, ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, int nd,
                int min_d, int cmax, uint8_t* ring, uint8_t* out) {
#if defined(__AVX512BW__)
  if (wide_transposed(nd)) {
    box_row8_impl<B512, 32>(raws, fresh, lrow, rrow, rev, radius, cols, x0, x1, nd, min_d, cmax,
                            ring, out);
    return;
  }
#endif
  if (nd % B256::kLanes != 0) {
    box_row8_impl<B128, 16>(raws, fresh, lrow, rrow, rev, radius, cols, x0, x1, nd, min_d, cmax,
                            ring, out);
    return;
  }
  box_row8_impl<B256, 16>(raws, fresh, lrow, rrow, rev, radius, cols, x0, x1, nd, min_d, cmax,
                          ring, out);
}
#endif

// ------------------------------------------------------------------------------------------
// The fused row (FusedRowFn): explicit SIMD, one template for AVX2 (V256) and AVX-512 (V512),
// so both builds run the same steps. Every value read back was stored at the same address
// and width (no store-forwarding stalls): the neighbours d - 1 and d + 1 come from shifts of
// whole vectors in registers.

#if defined(__AVX2__)
struct V256 {
  using R = __m256i;
  static constexpr int kLanes = 16;
  static R load(const void* p) { return _mm256_load_si256(static_cast<const R*>(p)); }
  static R loadu(const void* p) { return _mm256_loadu_si256(static_cast<const R*>(p)); }
  static void store(void* p, R v) { _mm256_store_si256(static_cast<R*>(p), v); }
  static void storeu(void* p, R v) { _mm256_storeu_si256(static_cast<R*>(p), v); }
  static R widen(const std::uint8_t* p) {
    return _mm256_cvtepu8_epi16(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
  }
  // Neighbour lanes of consecutive vectors a, b: X = cross(a, b) serves down(a, X) (lane i:
  // a[i + 1], the last lane b[0]) and up(b, X) (lane 0: a's last lane, lane i: b[i - 1]);
  // one lane permute per vector pair.
  using X = R;
  static X cross(R a, R b) { return _mm256_permute2x128_si256(a, b, 0x21); }
  static R up(R b, X x) { return _mm256_alignr_epi8(b, x, 14); }
  static R down(R a, X x) { return _mm256_alignr_epi8(x, a, 2); }
  static R set1(int v) { return _mm256_set1_epi16(static_cast<short>(v)); }
  static R iota() {
    return _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  }
  static R add(R a, R b) { return _mm256_add_epi16(a, b); }
  static R sub(R a, R b) { return _mm256_sub_epi16(a, b); }
  static R min(R a, R b) { return _mm256_min_epu16(a, b); }
  static R max(R a, R b) { return _mm256_max_epu16(a, b); }
  // b in the lanes where k - lo (mod 2^16) <= 2, a elsewhere.
  static R blend_near(R a, R b, R k, R lo) {
    const R rel = _mm256_sub_epi16(k, lo);
    const R two = _mm256_set1_epi16(2);
    return _mm256_blendv_epi8(a, b, _mm256_cmpeq_epi16(_mm256_min_epu16(rel, two), rel));
  }
  // lane 0: prev's last lane; lane i: cur[i - 1].
  static R shift_up(R prev, R cur) {
    return _mm256_alignr_epi8(cur, _mm256_permute2x128_si256(prev, cur, 0x21), 14);
  }
  // lane i: cur[i + 1]; the last lane: next[0].
  static R shift_down(R cur, R next) {
    return _mm256_alignr_epi8(_mm256_permute2x128_si256(cur, next, 0x21), cur, 2);
  }
  static std::uint32_t hmin(R v) { return hmin_epu16(v); }
  // The least lane in every lane (no trip through a general register).
  static R hmin_v(R v) {
    const __m128i m = _mm_min_epu16(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
    return _mm256_broadcastw_epi16(_mm_minpos_epu16(m));
  }
  static std::uint32_t lane0(R v) {
    return static_cast<std::uint32_t>(_mm_cvtsi128_si32(_mm256_castsi256_si128(v)) & 0xFFFF);
  }
  // Where v <= r: r = v, a = k.
  static void take_le(R& r, R& a, R v, R k) {
    const R m = _mm256_min_epu16(r, v);
    a = _mm256_blendv_epi8(a, k, _mm256_cmpeq_epi16(m, v));
    r = m;
  }
  // Where v < r: r = v, a = k.
  static void take_lt(R& r, R& a, R v, R k) {
    const R m = _mm256_min_epu16(r, v);
    a = _mm256_blendv_epi8(k, a, _mm256_cmpeq_epi16(m, r));
    r = m;
  }
  // The least of the lanes of a whose lane of r equals b.
  static R hmin_where_eq(R a, R r, R b) {
    return hmin_v(_mm256_or_si256(a, _mm256_xor_si256(_mm256_cmpeq_epi16(r, b), set1(-1))));
  }
  // v with 0xFFFF in the lanes where k - lo (mod 2^16) > span.
  static R or_outside(R v, R k, R lo, R span) {
    const R rel = _mm256_sub_epi16(k, lo);
    const R in = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, span), rel);
    return _mm256_or_si256(v, _mm256_xor_si256(in, _mm256_set1_epi16(-1)));
  }
  // The least of b << 16 | a over the lanes: the least b and, among its lanes, the least a.
  static std::uint32_t min_key(R a, R b) {
    const R m8 = _mm256_min_epu32(_mm256_unpacklo_epi16(a, b), _mm256_unpackhi_epi16(a, b));
    __m128i m = _mm_min_epu32(_mm256_castsi256_si128(m8), _mm256_extracti128_si256(m8, 1));
    m = _mm_min_epu32(m, _mm_shuffle_epi32(m, 0x4E));
    m = _mm_min_epu32(m, _mm_shuffle_epi32(m, 0xB1));
    return static_cast<std::uint32_t>(_mm_cvtsi128_si32(m));
  }
};
#endif

#if defined(__AVX512BW__)
struct V512 {
  using R = __m512i;
  static constexpr int kLanes = 32;
  static R load(const void* p) { return _mm512_load_si512(p); }
  static R loadu(const void* p) { return _mm512_loadu_si512(p); }
  static void store(void* p, R v) { _mm512_store_si512(p, v); }
  static void storeu(void* p, R v) { _mm512_storeu_si512(p, v); }
  struct X {
    R a, b;
  };
  static X cross(R a, R b) { return X{a, b}; }
  static R up(R, X x) { return shift_up(x.a, x.b); }
  static R down(R, X x) { return shift_down(x.a, x.b); }
  static R widen(const std::uint8_t* p) {
    return _mm512_cvtepu8_epi16(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)));
  }
  static R set1(int v) { return _mm512_set1_epi16(static_cast<short>(v)); }
  static R iota() {
    return _mm512_set_epi16(31, 30, 29, 28, 27, 26, 25, 24, 23, 22, 21, 20, 19, 18, 17, 16, 15,
                            14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
  }
  static R add(R a, R b) { return _mm512_add_epi16(a, b); }
  static R sub(R a, R b) { return _mm512_sub_epi16(a, b); }
  static R min(R a, R b) { return _mm512_min_epu16(a, b); }
  static R max(R a, R b) { return _mm512_max_epu16(a, b); }
  static R blend_near(R a, R b, R k, R lo) {
    return _mm512_mask_mov_epi16(a, _mm512_cmple_epu16_mask(_mm512_sub_epi16(k, lo), set1(2)), b);
  }
  // Index i < 32 picks the first operand's lane i, 32 + i the second's.
  static R shift_up(R prev, R cur) {
    const R idx = _mm512_add_epi16(iota(), _mm512_set1_epi16(31));  // 31, 32, .., 62
    return _mm512_permutex2var_epi16(prev, idx, cur);
  }
  static R shift_down(R cur, R next) {
    const R idx = _mm512_add_epi16(iota(), _mm512_set1_epi16(1));  // 1, 2, .., 32
    return _mm512_permutex2var_epi16(cur, idx, next);
  }
  static std::uint32_t hmin(R v) {
    return hmin_epu16(_mm256_min_epu16(_mm512_castsi512_si256(v), _mm512_extracti64x4_epi64(v, 1)));
  }
  static void take_le(R& r, R& a, R v, R k) {
    a = _mm512_mask_mov_epi16(a, _mm512_cmple_epu16_mask(v, r), k);
    r = _mm512_min_epu16(r, v);
  }
  static void take_lt(R& r, R& a, R v, R k) {
    a = _mm512_mask_mov_epi16(a, _mm512_cmplt_epu16_mask(v, r), k);
    r = _mm512_min_epu16(r, v);
  }
  static R hmin_v(R v) {
    const __m256i h = _mm256_min_epu16(_mm512_castsi512_si256(v), _mm512_extracti64x4_epi64(v, 1));
    const __m128i m = _mm_min_epu16(_mm256_castsi256_si128(h), _mm256_extracti128_si256(h, 1));
    return _mm512_broadcastw_epi16(_mm_minpos_epu16(m));
  }
  static std::uint32_t lane0(R v) {
    return static_cast<std::uint32_t>(_mm_cvtsi128_si32(_mm512_castsi512_si128(v)) & 0xFFFF);
  }
  static R hmin_where_eq(R a, R r, R b) {
    return hmin_v(_mm512_mask_mov_epi16(set1(-1), _mm512_cmpeq_epi16_mask(r, b), a));
  }
  static R or_outside(R v, R k, R lo, R span) {
    return _mm512_mask_mov_epi16(v, _mm512_cmpgt_epu16_mask(_mm512_sub_epi16(k, lo), span),
                                 _mm512_set1_epi16(-1));
  }
  static std::uint32_t min_key(R a, R b) {
    const R m16 = _mm512_min_epu32(_mm512_unpacklo_epi16(a, b), _mm512_unpackhi_epi16(a, b));
    const __m256i m8 =
        _mm256_min_epu32(_mm512_castsi512_si256(m16), _mm512_extracti64x4_epi64(m16, 1));
    __m128i m = _mm_min_epu32(_mm256_castsi256_si128(m8), _mm256_extracti128_si256(m8, 1));
    m = _mm_min_epu32(m, _mm_shuffle_epi32(m, 0x4E));
    m = _mm_min_epu32(m, _mm_shuffle_epi32(m, 0xB1));
    return static_cast<std::uint32_t>(_mm_cvtsi128_si32(m));
  }
};
#endif

#if defined(__AVX2__)
// path_step on one vector: a = L(q, d), lo = L(q, d - 1), hi = L(q, d + 1) (all >= 0 and
// below 2^15, so unsigned minima are the signed ones).
template <class V>
inline typename V::R step_vec(typename V::R lo, typename V::R a, typename V::R hi,
                              typename V::R c, typename V::R vp1, typename V::R mp2,
                              typename V::R m) {
  const typename V::R v = V::min(V::min(a, mp2), V::add(V::min(lo, hi), vp1));
  return V::add(c, V::sub(v, m));
}

// Pass 1's work on one pixel: the path from the left (hrow: the previous pixel's, with a
// sentinel vector after it; kHFirst: the path starts) and, kVertical, the path from above
// (lvx: the pixel's row of path costs, in place, with a sentinel before and after it;
// kVFirst: the path starts). Returns nothing; writes partial and the least path costs.
template <class V, bool kVertical, bool kBase, bool kHFirst, bool kVFirst>
inline void pass1_pixel(int nv, const uint8_t* __restrict cx, int16_t* __restrict hrow,
                        int16_t* __restrict lvx, const uint16_t* __restrict bx,
                        uint16_t* __restrict px, typename V::R vp1, typename V::R mh_v,
                        typename V::R mp2h, typename V::R mv_v, typename V::R mp2v,
                        typename V::R& mh_out, int16_t* lvmin_out) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const R sent = V::set1(kSentinel);
  const R ones = V::set1(-1);
  R hcur = sent;
  typename V::X xprev{};
  if constexpr (!kHFirst) {
    hcur = V::load(hrow);
    xprev = V::cross(sent, hcur);
  }
  R vlo = sent, va = sent, vhi = sent;
  if constexpr (kVertical && !kVFirst) {
    vlo = V::loadu(lvx - 1);
    va = V::load(lvx);
    vhi = V::loadu(lvx + 1);
  }
  R hmin_v = ones, vmin_v = ones;
  for (int i = 0; i < nv; ++i) {
    const R c = V::widen(cx + i * N);
    R lh;
    if constexpr (kHFirst) {
      lh = c;
    } else {
      const R hnext = V::load(hrow + (i + 1) * N);  // the sentinel after the last
      const typename V::X xcur = V::cross(hcur, hnext);
      lh = step_vec<V>(V::up(hcur, xprev), hcur, V::down(hcur, xcur), c, vp1, mp2h, mh_v);
      hcur = hnext;
      xprev = xcur;
    }
    V::store(hrow + i * N, lh);
    hmin_v = V::min(hmin_v, lh);
    R part = lh;
    if constexpr (kVertical) {
      R lvn;
      if constexpr (kVFirst) {
        lvn = c;
      } else {
        // The next vector's neighbours, read before this one is overwritten.
        const int at = (i + 1) * N;
        const R nlo = V::loadu(lvx + at - 1), na = V::load(lvx + at), nhi = V::loadu(lvx + at + 1);
        lvn = step_vec<V>(vlo, va, vhi, c, vp1, mp2v, mv_v);
        vlo = nlo;
        va = na;
        vhi = nhi;
      }
      V::store(lvx + i * N, lvn);
      vmin_v = V::min(vmin_v, lvn);
      part = V::add(part, lvn);
    }
    if constexpr (kBase) part = V::add(part, V::load(bx + i * N));
    V::store(px + i * N, part);
  }
  mh_out = V::hmin_v(hmin_v);
  if constexpr (kVertical) *lvmin_out = static_cast<int16_t>(V::hmin(vmin_v));
}

// Pass 2's paths and sums on one pixel: the path from the right (hrow as in pass 1), the
// sums (0xFFFF outside klo .. klo + span when kBorder), the right winners' window
// moved down one lane and updated. Returns the least sum of each lane, its lowest index in
// arg_v and the lane's second least (the least of the others; equal to the least on a tie)
// in sec_v.
template <class V, bool kFirst, bool kBorder, int kNv = 0>
inline typename V::R pass2_pixel(int nv_rt, const uint8_t* __restrict cx,
                                 int16_t* __restrict hrow, const uint16_t* __restrict px,
                                 uint16_t* __restrict wmin, uint16_t* __restrict warg,
                                 typename V::R vp1, typename V::R mr_v, typename V::R mp2r,
                                 typename V::R lo_v, typename V::R span_v, typename V::R& mr_out,
                                 typename V::R& arg_v, typename V::R& sec_v,
                                 typename V::R* hreg = nullptr, typename V::R* wreg = nullptr,
                                 typename V::R* areg = nullptr) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const int nv = kNv > 0 ? kNv : nv_rt;
  const R sent = V::set1(kSentinel);
  const R ones = V::set1(-1);
  const R step_k = V::set1(N);
  // kNv > 0: the path from the right and the window in registers (hreg, wreg, areg); the
  // path is still stored to hrow, for the sums beside the winner.
  constexpr int kR = kNv > 0 ? kNv : 1;
  R nh[kR], nw[kR], na[kR];
  R rcur = sent;
  typename V::X xprev{};
  if constexpr (!kFirst) {
    rcur = kNv > 0 ? hreg[0] : V::load(hrow);
    xprev = V::cross(sent, rcur);
  }
  R wcur = kNv > 0 ? wreg[0] : V::load(wmin), acur = kNv > 0 ? areg[0] : V::load(warg);
  R rmin_v = ones, best_v = ones, barg = V::set1(0), bsec = ones;
  R kv = V::iota();
#pragma GCC unroll 8
  for (int i = 0; i < nv; ++i) {
    const R c = V::widen(cx + i * N);
    R lr;
    if constexpr (kFirst) {
      lr = c;
    } else {
      R rnext;
      if constexpr (kNv > 0) {
        rnext = i + 1 < kNv ? hreg[i + 1 < kNv ? i + 1 : 0] : sent;
      } else {
        rnext = V::load(hrow + (i + 1) * N);
      }
      const typename V::X xcur = V::cross(rcur, rnext);
      lr = step_vec<V>(V::up(rcur, xprev), rcur, V::down(rcur, xcur), c, vp1, mp2r, mr_v);
      rcur = rnext;
      xprev = xcur;
    }
    V::store(hrow + i * N, lr);
    rmin_v = V::min(rmin_v, lr);
    R t = V::add(V::load(px + i * N), lr);
    if constexpr (kBorder) t = V::or_outside(t, kv, lo_v, span_v);
    bsec = V::min(bsec, V::max(best_v, t));
    V::take_lt(best_v, barg, t, kv);
    R wnext, anext;  // 0xFFFF after the last
    if constexpr (kNv > 0) {
      wnext = i + 1 < kNv ? wreg[i + 1 < kNv ? i + 1 : 0] : ones;
      anext = i + 1 < kNv ? areg[i + 1 < kNv ? i + 1 : 0] : ones;
    } else {
      wnext = V::load(wmin + (i + 1) * N);
      anext = V::load(warg + (i + 1) * N);
    }
    R w = V::down(wcur, V::cross(wcur, wnext));
    R wa = V::down(acur, V::cross(acur, anext));
    V::take_le(w, wa, t, kv);
    if constexpr (kNv > 0) {
      nh[kNv > 0 ? i : 0] = lr;
      nw[kNv > 0 ? i : 0] = w;
      na[kNv > 0 ? i : 0] = wa;
    } else {
      V::store(wmin + i * N, w);
      V::store(warg + i * N, wa);
    }
    wcur = wnext;
    acur = anext;
    kv = V::add(kv, step_k);
  }
  if constexpr (kNv > 0) {
#pragma GCC unroll 8
    for (int i = 0; i < kNv; ++i) {
      hreg[i] = nh[i];
      wreg[i] = nw[i];
      areg[i] = na[i];
    }
  }
  mr_out = V::hmin_v(rmin_v);
  arg_v = barg;
  sec_v = bsec;
  return best_v;
}

// The checks and the sub-pixel step of a fused row, as decide_row, from a.result (per pixel:
// best, kb, second best, the sums at kb - 1 and kb + 1) and a.rfinal (the right winners).
inline void decide_fused(const FusedRowArgs& a) {
  const ptrdiff_t cols = a.d.cols;
  const int nd = a.d.nd;  // the disparities that may win (a.p.nd may be more)
  const ptrdiff_t dmin = a.d.min_d;
  const uint32_t* res = a.result;
  const DecideArgs& d = a.d;
  const bool lr_on = d.lr_max_diff >= 0;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // The pixels with the whole range (klo = 0, khi = nd - 1): xa .. xb - 1.
  const ptrdiff_t xa = clamp_index(dmin + nd - 1, 0, cols);
  const ptrdiff_t xb = clamp_index(dmin + cols, xa, cols);
  if (d.uniqueness_factor <= 0 && a.conf == nullptr) {
    // Without the uniqueness check and the confidence, a shorter loop over those pixels: the
    // left-right check on integers (diff <= lr_max_diff for an integer diff >= 0 is diff <=
    // floor(lr_max_diff)), the same float steps.
    const ptrdiff_t lr_int = !lr_on                     ? nd
                             : d.lr_max_diff >= nd      ? nd
                                                        : static_cast<ptrdiff_t>(d.lr_max_diff);
    const int fit = d.subpixel;
    const uint16_t* rfinal = a.rfinal - dmin;
    ptrdiff_t x0 = xa;
#if defined(__AVX2__)
    // Eight pixels at a time (from xa + 1: every right column x - dmin - kb read below is then
    // >= 1, so the 32-bit gather of rfinal[j - 1 .. j] stays inside rfinal): the same integer
    // and float steps, lanes in the pixel order 0 2 4 6 1 3 5 7 of the four-value records.
    if (xb - xa > 8) {
      const __m256i off = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
      const __m256i order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
      const __m256i vdmin = _mm256_set1_epi32(static_cast<int>(dmin));
      const __m256i vlr = _mm256_set1_epi32(static_cast<int>(lr_int));
      const __m256i vtop = _mm256_set1_epi32(nd - 1);
      const __m256i zero = _mm256_setzero_si256();
      const __m256i low16 = _mm256_set1_epi32(0xFFFF);
      const __m256 vnan = _mm256_set1_ps(nan);
      const int* rbase = reinterpret_cast<const int*>(a.rfinal - 1);
      x0 = xa + 1;
      for (; x0 + 8 <= xb; x0 += 8) {
        const uint32_t* rx = res + 4 * x0;
        auto ld = [&](int i) {
          return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(rx + 8 * i));
        };
        const __m256i r0 = ld(0), r1 = ld(1), r2 = ld(2), r3 = ld(3);
        const __m256i t0 = _mm256_unpacklo_epi32(r0, r1), t1 = _mm256_unpacklo_epi32(r2, r3);
        const __m256i t2 = _mm256_unpackhi_epi32(r0, r1), t3 = _mm256_unpackhi_epi32(r2, r3);
        const __m256i best = _mm256_unpacklo_epi64(t0, t1);
        const __m256i kb = _mm256_unpackhi_epi64(t0, t1);
        const __m256i nb = _mm256_unpackhi_epi64(t2, t3);
        const __m256i xv = _mm256_add_epi32(_mm256_set1_epi32(static_cast<int>(x0)), off);
        const __m256i j = _mm256_sub_epi32(_mm256_sub_epi32(xv, vdmin), kb);
        const __m256i kr = _mm256_srli_epi32(_mm256_i32gather_epi32(rbase, j, 2), 16);
        const __m256i bad =
            _mm256_cmpgt_epi32(_mm256_abs_epi32(_mm256_sub_epi32(kb, kr)), vlr);
        __m256 disp = _mm256_cvtepi32_ps(_mm256_add_epi32(kb, vdmin));
        if (fit != static_cast<int>(SubpixelFit::kNone)) {
          const __m256i c0 = _mm256_and_si256(nb, low16);
          const __m256i c2 = _mm256_srli_epi32(nb, 16);
          const __m256 num = _mm256_cvtepi32_ps(_mm256_sub_epi32(c0, c2));
          __m256i den2;
          if (fit == static_cast<int>(SubpixelFit::kParabola)) {
            den2 = _mm256_sub_epi32(_mm256_add_epi32(c0, c2), _mm256_add_epi32(best, best));
          } else {
            den2 = _mm256_max_epi32(_mm256_sub_epi32(c0, best), _mm256_sub_epi32(c2, best));
          }
          const __m256 den = _mm256_cvtepi32_ps(_mm256_add_epi32(den2, den2));
          const __m256i inside =
              _mm256_and_si256(_mm256_cmpgt_epi32(kb, zero), _mm256_cmpgt_epi32(vtop, kb));
          const __m256 use = _mm256_and_ps(_mm256_castsi256_ps(inside),
                                           _mm256_cmp_ps(den, _mm256_setzero_ps(), _CMP_GT_OQ));
          // Where not used: disp + 0.0f, which is disp (never -0.0f).
          disp = _mm256_add_ps(disp, _mm256_and_ps(_mm256_div_ps(num, den), use));
        }
        disp = _mm256_blendv_ps(disp, vnan, _mm256_castsi256_ps(bad));
        _mm256_storeu_ps(a.disp + x0, _mm256_permutevar8x32_ps(disp, order));
      }
    }
#endif
    for (ptrdiff_t x = xa; x < xb; ++x) {
      if (x == xa + 1 && x0 > x) x = x0;
      if (x >= xb) break;
      const uint32_t* rx = res + 4 * x;
      const ptrdiff_t kb = rx[1];
      const ptrdiff_t kr = rfinal[x - kb];
      const ptrdiff_t diff = kb > kr ? kb - kr : kr - kb;
      float disp = static_cast<float>(dmin + kb);
      if (fit != static_cast<int>(SubpixelFit::kNone) && kb >= 1 && kb + 1 <= nd - 1) {
        const int32_t c0 = static_cast<int32_t>(rx[3] & 0xFFFFu);
        const int32_t c1 = static_cast<int32_t>(rx[0]);
        const int32_t c2 = static_cast<int32_t>(rx[3] >> 16);
        const float num = static_cast<float>(c0 - c2);
        const float den =
            fit == static_cast<int>(SubpixelFit::kParabola)
                ? static_cast<float>(2 * (c0 + c2 - 2 * c1))
                : static_cast<float>(2 * (c0 - c1 > c2 - c1 ? c0 - c1 : c2 - c1));
        if (den > 0.0f) disp = disp + num / den;
      }
      a.disp[x] = diff <= lr_int ? disp : nan;
    }
  }
  const bool fast = d.uniqueness_factor <= 0 && a.conf == nullptr && xa < xb;
  for (ptrdiff_t x = 0; x < cols; ++x) {
    if (fast && x == xa) {
      x = xb - 1;
      continue;
    }
    const ptrdiff_t klo = clamp_index(x - dmin - cols + 1, 0, nd);
    const ptrdiff_t khi = clamp_index(x - dmin, -1, nd - 1);
    bool ok = klo <= khi;
    if (!d.clip_border) ok = ok && x - dmin - nd + 1 >= 0 && x - dmin <= cols - 1;
    if (!ok) {
      a.disp[x] = nan;
      if (a.conf) a.conf[x] = 0.0f;
      continue;
    }
    const uint32_t* rx = res + 4 * x;
    const uint32_t best = rx[0], second = rx[2];
    const ptrdiff_t kb = rx[1];
    const bool has2 = second != kNone;
    if (d.uniqueness_factor > 0 && has2) {
      ok = static_cast<double>(second) * 100.0 > static_cast<double>(best) * d.uniqueness_factor;
    }
    if (ok && lr_on) {
      const ptrdiff_t kr = a.rfinal[x - dmin - kb];
      const ptrdiff_t diff = kb > kr ? kb - kr : kr - kb;
      ok = static_cast<double>(diff) <= d.lr_max_diff;
    }
    if (!ok) {
      a.disp[x] = nan;
      if (a.conf) a.conf[x] = 0.0f;
      continue;
    }
    float disp = static_cast<float>(dmin + kb);
    if (d.subpixel != static_cast<int>(SubpixelFit::kNone) && kb - 1 >= klo && kb + 1 <= khi) {
      const int32_t c0 = static_cast<int32_t>(rx[3] & 0xFFFFu);
      const int32_t c1 = static_cast<int32_t>(best);
      const int32_t c2 = static_cast<int32_t>(rx[3] >> 16);
      const float num = static_cast<float>(c0 - c2);
      float den;
      if (d.subpixel == static_cast<int>(SubpixelFit::kParabola)) {
        den = static_cast<float>(2 * (c0 + c2 - 2 * c1));
      } else {
        den = static_cast<float>(2 * (c0 - c1 > c2 - c1 ? c0 - c1 : c2 - c1));
      }
      if (den > 0.0f) disp = disp + num / den;
    }
    a.disp[x] = disp;
    if (a.conf) {
      a.conf[x] = !has2        ? 1.0f
                  : second > 0 ? static_cast<float>(second - best) / static_cast<float>(second)
                               : 0.0f;
    }
  }
  if (d.clip_border) drop_unrivalled(a.disp, a.conf, cols, dmin, nd);
}

// The most vectors per pixel whose path from the right and right winners' window the plain
// layout's pass 2 (paths 4 and 8) keeps in registers: 4 with AVX-512, 2 with AVX2. In one
// process on Zen 4, paths=8 took 0.93-1.00 of the time there; beyond (5 and 6 vectors with
// AVX-512, 3 and 4 with AVX2) 0.96-1.05, noise (bench/README, twenty-fifth round).
#if defined(__AVX512F__)
constexpr int kPlainRegsMax = 4;
#else
constexpr int kPlainRegsMax = 2;
#endif

// fn(std::integral_constant<int, nv>{}) when 1 <= nv <= kMax, else
// fn(std::integral_constant<int, 0>{}) (the count known at run time only).
template <int kMax, int K = 1, class Fn>
inline void with_vector_count(int nv, Fn&& fn) {
  if constexpr (K > kMax) {
    fn(std::integral_constant<int, 0>{});
  } else {
    if (nv == K) {
      fn(std::integral_constant<int, K>{});
      return;
    }
    with_vector_count<kMax, K + 1>(nv, fn);
  }
}

template <class V, bool kVertical, bool kBase>
void fused_row_impl(const FusedRowArgs& a) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const ptrdiff_t cols = a.d.cols;
  const int nd = a.p.nd, nv = nd / N;
  const int ndw = a.d.nd;  // the disparities that may win (<= nd)
  const ptrdiff_t ls = nd + kFusedPad;
  const ptrdiff_t lvs = nd + N;  // lv: each pixel's nd path costs, then N sentinels
  const ptrdiff_t dmin = a.d.min_d;
  const R sent = V::set1(kSentinel);
  const R vp1 = V::set1(a.p.p1);
  const uint8_t* g = a.g;
  // small: the path along the row (nd, then a sentinel pad), the right winners' window: least
  // sums and their indices (nd each, then a pad of 0xFFFF).
  int16_t* hrow = reinterpret_cast<int16_t*>(a.small);
  uint16_t* wmin = a.small + ls;
  uint16_t* warg = a.small + 2 * ls;
  for (int k = 0; k < kFusedPad; ++k) {
    hrow[nd + k] = kSentinel;
    wmin[nd + k] = 0xFFFFu;
    warg[nd + k] = 0xFFFFu;
  }

  // Pass 1, x rising: the path from above (in place) and the path from the left.
  const bool vfirst = a.gprev == nullptr;
  int16_t* lv0 = kVertical ? a.lv + kFusedPad : nullptr;
  if (kVertical && vfirst) {
    // The sentinels around each pixel's path costs (written once per path start).
    for (int k = 0; k < kFusedPad; ++k) a.lv[k] = kSentinel;
    for (ptrdiff_t x = 0; x < cols; ++x) {
      for (int k = 0; k < N; ++k) lv0[x * lvs + nd + k] = kSentinel;
    }
  }
  R mh = sent;  // the previous pixel's least path cost from the left, in every lane
  for (ptrdiff_t x = 0; x < cols; ++x) {
    const uint8_t* cx = a.c + x * nd;
    uint16_t* px = a.partial + x * nd;
    const uint16_t* bx = kBase ? a.base + x * nd : nullptr;
    if constexpr (kBase) prefetch_ahead<false>(bx, 2 * nd);  // the sums ahead
    int16_t* lvx = kVertical ? lv0 + x * lvs : nullptr;
    int16_t* lvmin = kVertical ? a.lvmin + x : nullptr;
    R mv_v = sent, mp2v = sent;
    if (kVertical && !vfirst) {
      const int mv = a.lvmin[x];
      mv_v = V::set1(mv);
      mp2v = V::set1(mv + p2_for(a.p, g[x], a.gprev[x]));
    }
    if (x == 0) {
      if (vfirst) {
        pass1_pixel<V, kVertical, kBase, true, true>(nv, cx, hrow, lvx, bx, px, vp1, sent, sent,
                                                     mv_v, mp2v, mh, lvmin);
      } else {
        pass1_pixel<V, kVertical, kBase, true, false>(nv, cx, hrow, lvx, bx, px, vp1, sent, sent,
                                                      mv_v, mp2v, mh, lvmin);
      }
      continue;
    }
    const R mh_v = mh;
    const R mp2h = V::add(mh, V::set1(p2_for(a.p, g[x], g[x - 1])));
    if (vfirst) {
      pass1_pixel<V, kVertical, kBase, false, true>(nv, cx, hrow, lvx, bx, px, vp1, mh_v, mp2h,
                                                    mv_v, mp2v, mh, lvmin);
    } else {
      pass1_pixel<V, kVertical, kBase, false, false>(nv, cx, hrow, lvx, bx, px, vp1, mh_v, mp2h,
                                                     mv_v, mp2v, mh, lvmin);
    }
  }

  // Pass 2, x falling: the path from the right, the sums, the winner and second best, and
  // the right image's winners. wmin/warg lane k: right column x - dmin - k (the pixel's own
  // candidates); one pixel to the left, every column moves down one lane: lane 0 is final
  // (every candidate of that column has come) and the last lane starts empty. Candidates
  // arrive with k falling, so <= keeps the lowest k of a tie.
  for (int k = 0; k < nd; ++k) {
    wmin[k] = 0xFFFFu;
    warg[k] = 0;
  }
  uint32_t* res = a.result;
  R mr = sent;
  // With at most kPlainRegsMax vectors per pixel, the path from the right and the window stay
  // in registers from pixel to pixel (then stored for the columns still in the window).
  auto pass2 = [&](auto nv_c) {
    constexpr int kNv = decltype(nv_c)::value;
    constexpr int kR = kNv > 0 ? kNv : 1;
    R hreg[kR], wreg[kR], areg[kR];
    for (int v = 0; v < kR; ++v) {
      hreg[v] = sent;
      wreg[v] = V::set1(-1);
      areg[v] = V::set1(0);
    }
    for (ptrdiff_t x = cols - 1; x >= 0; --x) {
      const uint8_t* cx = a.c + x * nd;
      const uint16_t* px = a.partial + x * nd;
      const bool first = x == cols - 1;
      if (!first) {
        const ptrdiff_t xr = x + 1 - dmin;
        if (xr >= 0 && xr < cols) {
          a.rfinal[xr] = kNv > 0 ? static_cast<uint16_t>(V::lane0(areg[0])) : warg[0];
        }
      }
      // The candidates that may win, as in fused_row_t_impl (no candidate: every lane masked).
      const ptrdiff_t klo = clamp_index(x - dmin - cols + 1, 0, ndw);
      const ptrdiff_t khi = clamp_index(x - dmin, -1, ndw - 1);
      const bool border = klo != 0 || khi != nd - 1;
      const R lo_v = V::set1(klo > khi ? 0xFFFF : static_cast<int>(klo));
      const R span_v = V::set1(klo > khi ? 0 : static_cast<int>(khi - klo));
      R best_v, arg_v, sec_v;
      if (first) {
        best_v = pass2_pixel<V, true, true, kNv>(nv, cx, hrow, px, wmin, warg, vp1, sent, sent,
                                                 lo_v, span_v, mr, arg_v, sec_v, hreg, wreg,
                                                 areg);
      } else {
        const R mr_v = mr;
        const R mp2r = V::add(mr, V::set1(p2_for(a.p, g[x], g[x + 1])));
        if (border) {
          best_v = pass2_pixel<V, false, true, kNv>(nv, cx, hrow, px, wmin, warg, vp1, mr_v, mp2r,
                                               lo_v, span_v, mr, arg_v, sec_v, hreg, wreg, areg);
        } else {
          best_v = pass2_pixel<V, false, false, kNv>(nv, cx, hrow, px, wmin, warg, vp1, mr_v, mp2r,
                                                lo_v, span_v, mr, arg_v, sec_v, hreg, wreg, areg);
        }
      }
      uint32_t* rx = res + 4 * x;
      if (klo > khi) continue;
      const R best_b = V::hmin_v(best_v);
      const R kb_b = V::hmin_where_eq(arg_v, best_v, best_b);
      // The second best: the least over the lanes of each lane's least, or of its second least
      // where the lane's least first comes at kb - 1, kb or kb + 1 (the only index of kb - 1 ..
      // kb + 1 in that lane: a later equal least is then the second least).
      const uint32_t sec = V::hmin(V::blend_near(best_v, sec_v, arg_v, V::sub(kb_b, V::set1(1))));
      const uint32_t best = V::lane0(best_b);
      const int kb = static_cast<int>(V::lane0(kb_b));
      rx[0] = best;
      rx[1] = static_cast<uint32_t>(kb);
      rx[2] = sec == 0xFFFFu ? kNone : sec;
      // The sums beside the winner (used only when both are inside: unmasked), from the sums
      // of the other paths and the path from the right just stored.
      auto sum_at = [&](int k) {
        return static_cast<uint32_t>(static_cast<uint16_t>(px[k] + static_cast<uint16_t>(hrow[k])));
      };
      rx[3] = (kb > 0 ? sum_at(kb - 1) : 0u) | (kb + 1 < nd ? sum_at(kb + 1) << 16 : 0u);
    }
    if constexpr (kNv > 0) {
      for (int v = 0; v < kNv; ++v) V::store(warg + v * N, areg[v]);
    }
  };
  with_vector_count<kPlainRegsMax>(nv, pass2);
  // The columns still in the window are final.
  for (int k = 0; k < nd; ++k) {
    const ptrdiff_t xr = -dmin - k;
    if (xr >= 0 && xr < cols) a.rfinal[xr] = warg[k];
  }

  decide_fused(a);
}


// ------------------------------------------------------------------------------------------
// The fused row in the transposed layout (fused_row_t, the single pass: a path from above,
// none of base): costs, path rows, partial sums and the right winners' window hold each
// pixel's values as nv vectors whose lane j of vector v is the disparity index k = j * nv + v.
// The neighbours k - 1 and k + 1 of vector v are then the vectors v - 1 and v + 1 of the
// same pixel: only vector 0's k - 1 and vector nv - 1's k + 1 need a shift by one lane (a
// sentinel shifted in), two shifts per pixel and path instead of three per vector. One pixel
// to the left, the right winners' window moves down one index: vector v becomes vector v - 1
// (a ring of nv slots, nothing moves) and only the leaving vector 0 shifts down one lane to
// become vector nv - 1. kNv: nv when known at compile time (the loops unrolled), else 0.

// L(p, d) = C + min(L(q, d), L(q, d -+ 1) + P1, m + P2') - m, as min(min(L(q, d), L(q, d -+ 1)
// + P1) - m, P2') + C: the same integers (every L(q, .) >= m), and m enters late.
template <class V>
inline typename V::R step_t(typename V::R lo, typename V::R a, typename V::R hi,
                            typename V::R c, typename V::R vp1, typename V::R m,
                            typename V::R p2) {
  const typename V::R t = V::min(a, V::add(V::min(lo, hi), vp1));
  return V::add(V::min(V::sub(t, m), p2), c);
}

// The state of one path over a pixel's vectors: the previous pixel's (old) vectors are read
// from row as the new ones are written over them; lo and a roll along, first is kept for
// the last vector's k + 1.
template <class V>
struct PathCursor {
  using R = typename V::R;
  R lo, a, first;
  // Before vector 0 (not on a path's first pixel).
  void start(const int16_t* row, int nv) {
    first = V::load(row);
    lo = V::shift_up(V::set1(kSentinel), V::load(row + (nv - 1) * V::kLanes));
    a = first;
  }
  // Vector v's new path costs (v < nv - 1: the next old vector is loaded first).
  R step(const int16_t* row, int v, int nv, R c, R vp1, R m, R p2) {
    const R hi = v + 1 < nv ? V::load(row + (v + 1) * V::kLanes)
                            : V::shift_down(first, V::set1(kSentinel));
    const R l = step_t<V>(lo, a, hi, c, vp1, m, p2);
    lo = a;
    a = hi;
    return l;
  }
};

template <class V, int kNv, bool kHFirst, bool kVFirst>
inline void pass1_pixel_t(int nv_rt, const uint8_t* __restrict cx, int16_t* __restrict hrow,
                          int16_t* __restrict lvx, uint16_t* __restrict px, typename V::R vp1,
                          typename V::R mh, typename V::R p2h, typename V::R mv,
                          typename V::R p2v, typename V::R& mh_out, int16_t* lvmin_out) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const int nv = kNv ? kNv : nv_rt;
  const R ones = V::set1(-1);
  PathCursor<V> h, w;
  if constexpr (!kHFirst) h.start(hrow, nv);
  if constexpr (!kVFirst) w.start(lvx, nv);
  R hmin[2] = {ones, ones}, vmin[2] = {ones, ones};
#pragma GCC unroll 16
  for (int v = 0; v < nv; ++v) {
    const R c = V::widen(cx + v * N);
    R lh, lv;
    if constexpr (kHFirst) {
      lh = c;
    } else {
      lh = h.step(hrow, v, nv, c, vp1, mh, p2h);
    }
    if constexpr (kVFirst) {
      lv = c;
    } else {
      lv = w.step(lvx, v, nv, c, vp1, mv, p2v);
    }
    V::store(hrow + v * N, lh);
    V::store(lvx + v * N, lv);
    V::store(px + v * N, V::add(lh, lv));
    hmin[v & 1] = v < 2 ? lh : V::min(hmin[v & 1], lh);
    vmin[v & 1] = v < 2 ? lv : V::min(vmin[v & 1], lv);
  }
  mh_out = V::hmin_v(V::min(hmin[0], hmin[1]));
  *lvmin_out = static_cast<int16_t>(V::hmin(V::min(vmin[0], vmin[1])));
}

// The most vectors per pixel whose path from the left pass 1 keeps in registers: 6 with the
// 32 vector registers of AVX-512, 3 with the 16 of AVX2. Against the row in memory, in one
// process on Zen 4: 0.84-0.97 of the time of paths=3 at 1 to 5 vectors with AVX-512 and
// 0.94-0.97 at 1 to 3 with AVX2; 0.98-1.04 (noise) beyond (bench/README, twenty-fifth round).
#if defined(__AVX512F__)
constexpr int kRegsMax = 6;
#else
constexpr int kRegsMax = 3;
#endif

// The most vectors per pixel whose right winners' window (least sums and their indices) pass
// 2 keeps in registers, rotating them by one vector per pixel instead of rotating slots in
// memory: 5 with AVX-512, 3 with AVX2. In one process on Zen 4, paths=3 took 0.84-0.94 of the
// time at 1 to 5 vectors with AVX-512 and 0.87-0.96 at 1 to 3 with AVX2; at 6 to 10 vectors
// with AVX-512 (spills) 1.01-1.16, at 4 and 5 with AVX2 0.97-1.01 (bench/README, twenty-fifth
// round).
#if defined(__AVX512F__)
constexpr int kWinMax = 5;
#else
constexpr int kWinMax = 3;
#endif

// pass1_pixel_t with the path from the left in registers (h: the previous pixel's kNv
// vectors in, this pixel's out) rather than in a row of memory: a store and a load fewer per
// vector, and no trip through the store buffer on the chain from pixel to pixel.
template <class V, int kNv, bool kHFirst, bool kVFirst>
inline void pass1_pixel_r(const uint8_t* __restrict cx, typename V::R (&h)[kNv],
                          int16_t* __restrict lvx, uint16_t* __restrict px, typename V::R vp1,
                          typename V::R mh, typename V::R p2h, typename V::R mv,
                          typename V::R p2v, typename V::R& mh_out, int16_t* lvmin_out) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  constexpr int nv = kNv;
  const R ones = V::set1(-1);
  PathCursor<V> w;
  if constexpr (!kVFirst) w.start(lvx, nv);
  R nh[kNv];
  R hmin[2] = {ones, ones}, vmin[2] = {ones, ones};
#pragma GCC unroll 16
  for (int v = 0; v < nv; ++v) {
    const R c = V::widen(cx + v * N);
    R lh, lv;
    if constexpr (kHFirst) {
      lh = c;
    } else {
      const R lo = v > 0 ? h[v > 0 ? v - 1 : 0] : V::shift_up(V::set1(kSentinel), h[nv - 1]);
      const R hi =
          v + 1 < nv ? h[v + 1 < nv ? v + 1 : 0] : V::shift_down(h[0], V::set1(kSentinel));
      lh = step_t<V>(lo, h[v], hi, c, vp1, mh, p2h);
    }
    if constexpr (kVFirst) {
      lv = c;
    } else {
      lv = w.step(lvx, v, nv, c, vp1, mv, p2v);
    }
    nh[v] = lh;
    V::store(lvx + v * N, lv);
    V::store(px + v * N, V::add(lh, lv));
    hmin[v & 1] = v < 2 ? lh : V::min(hmin[v & 1], lh);
    vmin[v & 1] = v < 2 ? lv : V::min(vmin[v & 1], lv);
  }
#pragma GCC unroll 16
  for (int v = 0; v < nv; ++v) h[v] = nh[v];
  mh_out = V::hmin_v(V::min(hmin[0], hmin[1]));
  *lvmin_out = static_cast<int16_t>(V::hmin(V::min(vmin[0], vmin[1])));
}

// Pass 2 on one pixel: the path from the right, the sums (0xFFFF outside klo .. klo + span
// when kBorder; into px when kSecond), the winner per lane and the right winners' window.
template <class V, int kNv, bool kFirst, bool kBorder, bool kSecond, int kSlot0 = -1,
          bool kWin = false>
inline void pass2_pixel_t(int nv_rt, const uint8_t* __restrict cx, int16_t* __restrict hrow,
                          uint16_t* __restrict px, uint16_t* __restrict wmin,
                          uint16_t* __restrict warg, int slot0, typename V::R iota_nv,
                          typename V::R vp1, typename V::R mr, typename V::R p2r,
                          typename V::R lo_v, typename V::R span_v, typename V::R& mr_out,
                          typename V::R& best_out, typename V::R& arg_out,
                          typename V::R* wminr = nullptr, typename V::R* wargr = nullptr) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const int nv = kNv ? kNv : nv_rt;
  const R ones = V::set1(-1);
  const R one = V::set1(1);
  PathCursor<V> h;
  if constexpr (!kFirst) h.start(hrow, nv);
  R rmin[2] = {ones, ones};
  R best = ones, barg = V::set1(0);
  R kv = iota_nv;
  int slot = slot0;
#pragma GCC unroll 16
  for (int v = 0; v < nv; ++v) {
    const R c = V::widen(cx + v * N);
    R lr;
    if constexpr (kFirst) {
      lr = c;
    } else {
      lr = h.step(hrow, v, nv, c, vp1, mr, p2r);
    }
    V::store(hrow + v * N, lr);
    rmin[v & 1] = v < 2 ? lr : V::min(rmin[v & 1], lr);
    R s = V::add(V::load(px + v * N), lr);
    if constexpr (kBorder) s = V::or_outside(s, kv, lo_v, span_v);
    if constexpr (kSecond) V::store(px + v * N, s);  // for the second best
    V::take_lt(best, barg, s, kv);
    if constexpr (kWin) {
      // The window in registers, vector v at index v.
      V::take_le(wminr[v], wargr[v], s, kv);
    } else {
      // With kSlot0 (slot0 known at compile time) every slot is a constant of the unrolled
      // loop: no index arithmetic per vector.
      const int sl = kSlot0 >= 0 ? (kSlot0 + v) % (kNv > 0 ? kNv : 1) : slot;
      uint16_t* wp = wmin + sl * N;
      uint16_t* ap = warg + sl * N;
      R wv = V::load(wp), wa = V::load(ap);
      V::take_le(wv, wa, s, kv);
      V::store(wp, wv);
      V::store(ap, wa);
      if constexpr (kSlot0 < 0) slot = slot + 1 == nv ? 0 : slot + 1;
    }
    kv = V::add(kv, one);
  }
  mr_out = V::hmin_v(V::min(rmin[0], rmin[1]));
  best_out = best;
  arg_out = barg;
}

// fn(std::integral_constant<int, value>{}) for value in 0 .. kN - 1 (the last for any other).
template <int kN, int S = 0, class Fn>
inline void with_constant(int value, Fn&& fn) {
  if constexpr (S + 1 >= kN) {
    fn(std::integral_constant<int, S>{});
  } else {
    if (value == S) {
      fn(std::integral_constant<int, S>{});
      return;
    }
    with_constant<kN, S + 1>(value, fn);
  }
}

// The vector counts whose pass 2 gets one instance per window slot (the code grows as nv^2).
constexpr int kConstSlotsMax = 10;

template <class V, int kNv, bool kSecond>
void fused_row_t_impl(const FusedRowArgs& a) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const ptrdiff_t cols = a.d.cols;
  const int nd = a.p.nd, nv = kNv ? kNv : nd / N;
  const int ndw = a.d.nd;  // the disparities that may win (<= nd)
  const ptrdiff_t dmin = a.d.min_d;
  const R sent = V::set1(kSentinel);
  const R ones = V::set1(-1);
  const R one = V::set1(1);
  const R vp1 = V::set1(a.p.p1);
  const uint8_t* g = a.g;
  // small: the path along the row (nd), the right winners' window: least sums and their
  // indices (nd each, nv slots of N lanes).
  int16_t* hrow = reinterpret_cast<int16_t*>(a.small);
  uint16_t* wmin = a.small + nd + kFusedPad;
  uint16_t* warg = a.small + 2 * (nd + kFusedPad);

  // Pass 1, x rising: the path from above (in place in lv, nd values per pixel) and the
  // path from the left.
  const bool vfirst = a.gprev == nullptr;
  int16_t* lv0 = a.lv + kFusedPad;
  R mh = sent;  // the previous pixel's least path cost from the left, in every lane
  // With at most kRegsMax vectors per pixel, the path from the left stays in registers
  // (pass1_pixel_r); else it goes through hrow.
  constexpr bool kRegs = kNv >= 1 && kNv <= kRegsMax;
  R h[kRegs ? kNv : 1];
  auto pixel = [&](auto h_first, auto v_first, const uint8_t* cx, int16_t* lvx, uint16_t* px,
                   R mh_in, R p2h, R mv, R p2v, int16_t* lvmin) {
    constexpr bool kH = decltype(h_first)::value, kV = decltype(v_first)::value;
    if constexpr (kRegs) {
      pass1_pixel_r<V, kNv, kH, kV>(cx, h, lvx, px, vp1, mh_in, p2h, mv, p2v, mh, lvmin);
    } else {
      pass1_pixel_t<V, kNv, kH, kV>(nv, cx, hrow, lvx, px, vp1, mh_in, p2h, mv, p2v, mh, lvmin);
    }
  };
  const std::true_type first;
  const std::false_type later;
  for (ptrdiff_t x = 0; x < cols; ++x) {
    const uint8_t* cx = a.c + x * nd;
    uint16_t* px = a.partial + x * nd;
    int16_t* lvx = lv0 + x * nd;
    int16_t* lvmin = a.lvmin + x;
    if (vfirst) {
      if (x == 0) {
        pixel(first, first, cx, lvx, px, sent, sent, sent, sent, lvmin);
      } else {
        const R p2h = V::set1(p2_for(a.p, g[x], g[x - 1]));
        pixel(later, first, cx, lvx, px, mh, p2h, sent, sent, lvmin);
      }
      continue;
    }
    const R mv = V::set1(a.lvmin[x]);
    const R p2v = V::set1(p2_for(a.p, g[x], a.gprev[x]));
    if (x == 0) {
      pixel(first, later, cx, lvx, px, sent, sent, mv, p2v, lvmin);
    } else {
      const R p2h = V::set1(p2_for(a.p, g[x], g[x - 1]));
      pixel(later, later, cx, lvx, px, mh, p2h, mv, p2v, lvmin);
    }
  }

  // Pass 2, x falling: the path from the right, the sums, the winner, and the right image's
  // winners. Step t = cols - 1 - x keeps the window's vector v in slot (v + t) mod nv; its
  // lane j is right column x - dmin - k (k = j * nv + v); candidates arrive with k falling,
  // so <= keeps the lowest k of a tie.
  for (int k = 0; k < nd; ++k) {
    wmin[k] = 0xFFFFu;
    warg[k] = 0;
  }
  const R iota_nv = [&] {
    alignas(64) uint16_t tmp[N];
    for (int j = 0; j < N; ++j) tmp[j] = static_cast<uint16_t>(j * nv);
    return V::load(tmp);
  }();
  uint32_t* res = a.result;
  R mr = sent;
  int slot0 = 0;  // the slot of vector 0
  // With kNv: where index k sits in the transposed layout, (k % nv) * N + k / nv, for the
  // winner's neighbours (a table rather than a division and a remainder per pixel).
  static const auto at_of = [] {  // once per instance
    std::array<uint16_t, (kNv > 0 ? kNv * N : 1)> t{};
    for (int k = 0; k < kNv * N; ++k) t[k] = static_cast<uint16_t>((k % kNv) * N + k / kNv);
    return t;
  }();
  // With at most kWinMax vectors per pixel, the window stays in registers.
  constexpr bool kWin = kNv >= 1 && kNv <= kWinMax;
  constexpr int kWinNv = kWin ? kNv : 1;
  R wminr[kWinNv], wargr[kWinNv];
  for (int v = 0; v < kWinNv; ++v) {
    wminr[v] = ones;
    wargr[v] = V::set1(0);
  }
  for (ptrdiff_t x = cols - 1; x >= 0; --x) {
    const uint8_t* cx = a.c + x * nd;
    uint16_t* px = a.partial + x * nd;
    // The candidates that may win: inside the image and below a.d.nd (the sums of the others
    // are 0xFFFF; with a.d.nd < nd every pixel takes the border's instance).
    const ptrdiff_t klo = clamp_index(x - dmin - cols + 1, 0, ndw);
    const ptrdiff_t khi = clamp_index(x - dmin, -1, ndw - 1);
    // No candidate (klo > khi): lo = 0xFFFF, span 0 masks every lane (k - lo = k + 1 > 0),
    // so that the candidates above ndw, whose right columns may lie inside the image, stay
    // out of the right winners.
    // (Made only for the pixels that take the border's instance.)
    auto lo_span = [&](R& lo_v, R& span_v) {
      lo_v = V::set1(klo > khi ? 0xFFFF : static_cast<int>(klo));
      span_v = V::set1(klo > khi ? 0 : static_cast<int>(khi - klo));
    };
    R lo_v = ones, span_v = ones;
    R best_v, arg_v;
    if (x == cols - 1) {
      lo_span(lo_v, span_v);
      pass2_pixel_t<V, kNv, true, true, kSecond, -1, kWin>(
          nv, cx, hrow, px, wmin, warg, slot0, iota_nv, vp1, sent, sent, lo_v, span_v, mr,
          best_v, arg_v, wminr, wargr);
    } else {
      // The leaving vector 0: lane 0 is final; the rest moves down one lane and becomes
      // vector nv - 1 (same slot, or the last register); vector v + 1 becomes vector v.
      const ptrdiff_t xr = x + 1 - dmin;
      if constexpr (kWin) {
        if (xr >= 0 && xr < cols) a.rfinal[xr] = static_cast<uint16_t>(V::lane0(wargr[0]));
        const R w0 = V::shift_down(wminr[0], ones), a0 = V::shift_down(wargr[0], ones);
#pragma GCC unroll 16
        for (int v = 0; v + 1 < kWinNv; ++v) {
          wminr[v] = wminr[v + 1];
          wargr[v] = wargr[v + 1];
        }
        wminr[kWinNv - 1] = w0;
        wargr[kWinNv - 1] = a0;
      } else {
        uint16_t* w0 = wmin + slot0 * N;
        uint16_t* a0 = warg + slot0 * N;
        if (xr >= 0 && xr < cols) a.rfinal[xr] = a0[0];
        V::store(w0, V::shift_down(V::load(w0), ones));
        V::store(a0, V::shift_down(V::load(a0), ones));
        slot0 = slot0 + 1 == nv ? 0 : slot0 + 1;
      }
      const R p2r = V::set1(p2_for(a.p, g[x], g[x + 1]));
      if (klo != 0 || khi != nd - 1) {
        lo_span(lo_v, span_v);
        pass2_pixel_t<V, kNv, false, true, kSecond, -1, kWin>(
            nv, cx, hrow, px, wmin, warg, slot0, iota_nv, vp1, mr, p2r, lo_v, span_v, mr,
            best_v, arg_v, wminr, wargr);
      } else if constexpr (!kWin && kNv >= 2 && kNv <= kConstSlotsMax) {
        // One instance per slot0 (it cycles through 0 .. nv - 1, so the branch predicts).
        with_constant<kNv>(slot0, [&](auto s0) {
          pass2_pixel_t<V, kNv, false, false, kSecond, decltype(s0)::value>(
              nv, cx, hrow, px, wmin, warg, slot0, iota_nv, vp1, mr, p2r, lo_v, span_v, mr,
              best_v, arg_v, wminr, wargr);
        });
      } else {
        pass2_pixel_t<V, kNv, false, false, kSecond, -1, kWin>(
            nv, cx, hrow, px, wmin, warg, slot0, iota_nv, vp1, mr, p2r, lo_v, span_v, mr,
            best_v, arg_v, wminr, wargr);
      }
    }
    uint32_t* rx = res + 4 * x;
    if (klo > khi) continue;
    const uint32_t key = V::min_key(arg_v, best_v);
    const uint32_t best = key >> 16;
    const int kb = static_cast<int>(key & 0xFFFFu);
    rx[0] = best;
    rx[1] = static_cast<uint32_t>(kb);
    if constexpr (kSecond) {
      // The least sum more than one index away from kb (the sums, masked, are in px).
      const R near = V::set1(kb - 1);
      R s2 = ones;
      R k2 = iota_nv;
      for (int v = 0; v < nv; ++v) {
        s2 = V::min(s2, V::blend_near(V::load(px + v * N), ones, k2, near));
        k2 = V::add(k2, one);
      }
      const uint32_t sec = V::hmin(s2);
      rx[2] = sec == 0xFFFFu ? kNone : sec;
    } else {
      rx[2] = kNone;
    }
    if (!kSecond && kb >= 1 && kb + 1 < nd) {
      // The sums beside the winner (used only when both are inside: unmasked), from the
      // other paths' sums and the path from the right just stored.
      const unsigned km = static_cast<unsigned>(kb - 1), kp = static_cast<unsigned>(kb + 1);
      const unsigned unv = static_cast<unsigned>(nv);
      ptrdiff_t am, ap;
      if constexpr (kNv > 0) {
        am = at_of[km];
        ap = at_of[kp];
      } else {
        am = (km % unv) * N + km / unv;
        ap = (kp % unv) * N + kp / unv;
      }
      auto sum = [&](ptrdiff_t at) {
        const uint16_t v = static_cast<uint16_t>(px[at] + static_cast<uint16_t>(hrow[at]));
        return static_cast<uint32_t>(v);
      };
      rx[3] = sum(am) | sum(ap) << 16;
    }
  }
  // The columns still in the window are final (vector v in slot (slot0 + v) mod nv; with
  // the window in registers, vector v in register v, stored as slot v).
  if constexpr (kWin) {
    for (int v = 0; v < kWinNv; ++v) V::store(warg + v * N, wargr[v]);
    slot0 = 0;
  }
  for (int v = 0; v < nv; ++v) {
    const int s = (slot0 + v) % nv;
    for (int j = 0; j < N; ++j) {
      const ptrdiff_t xr = -dmin - (static_cast<ptrdiff_t>(j) * nv + v);
      if (xr >= 0 && xr < cols) a.rfinal[xr] = warg[s * N + j];
    }
  }
  // With the second best, the sums beside the winners from the row's sums kept in partial
  // (used only when both are inside the range, where they are not masked).
  if (kSecond && a.d.subpixel != static_cast<int>(SubpixelFit::kNone)) {
    for (ptrdiff_t x = 0; x < cols; ++x) {
      const ptrdiff_t klo = clamp_index(x - dmin - cols + 1, 0, ndw);
      const ptrdiff_t khi = clamp_index(x - dmin, -1, ndw - 1);
      uint32_t* rx = res + 4 * x;
      const int kb = static_cast<int>(rx[1]);
      if (klo > khi || kb - 1 < klo || kb + 1 > khi) continue;
      const uint16_t* sx = a.partial + x * nd;
      const unsigned km = static_cast<unsigned>(kb - 1), kp = static_cast<unsigned>(kb + 1);
      const unsigned unv = static_cast<unsigned>(nv);
      rx[3] = static_cast<uint32_t>(sx[(km % unv) * N + km / unv]) |
              static_cast<uint32_t>(sx[(kp % unv) * N + kp / unv]) << 16;
    }
  }
  decide_fused(a);
}

// PathRowsFn: per pixel, every direction's step and the sum in one sweep over the
// disparities. A path's first pixel reads a row of zeros (m = 0): L = C + min(0, ..) - 0 = C.
inline constexpr int kZeroRow = kMaxNumDisparities + 64;
alignas(64) const int16_t kZeros[kZeroRow] = {};

template <class V, int kNv, bool kWrite>
void path_rows_impl(const PathParams& p, const uint8_t* c, const uint8_t* g, const uint8_t* gprev,
                    const int16_t* const* prev, int16_t* const* cur, const int* dxs,
                    ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, uint16_t* s) {
  using R = typename V::R;
  constexpr int N = V::kLanes;
  const int nd = p.nd, ls = p.ls, nvec = nd / N;
  const R vp1 = V::set1(p.p1);
  const R ones = V::set1(-1);
  for (ptrdiff_t x = x0; x < x1; ++x) {
    // The sums kPrefetchBytes ahead: to be written on the way down, read on the way up.
    prefetch_ahead<kWrite>(s + x * nd, 2 * nd);
    const int16_t* q[kNv];
    int16_t* out[kNv];
    R m_v[kNv], mp2_v[kNv], mn[kNv];
    for (int v = 0; v < kNv; ++v) {
      const ptrdiff_t xq = x - dxs[v];
      out[v] = cur[v] + x * ls;
      mn[v] = ones;
      if (prev == nullptr || xq < 0 || xq >= cols) {
        q[v] = kZeros;
        m_v[v] = V::set1(0);
        mp2_v[v] = V::set1(0);
      } else {
        q[v] = prev[v] + xq * ls;
        const int m = q[v][nd + 2];
        m_v[v] = V::set1(m);
        mp2_v[v] = V::set1(m + p2_for(p, g[x], gprev[xq]));
      }
    }
    const uint8_t* cx = c + x * nd;
    uint16_t* sx = s + x * nd;
    for (int i = 0; i < nvec; ++i) {
      const R cv = V::widen(cx + i * N);
      R acc = kWrite ? V::set1(0) : V::loadu(sx + i * N);
      for (int v = 0; v < kNv; ++v) {
        const int16_t* qi = q[v] + i * N;
        const R l = step_vec<V>(V::loadu(qi), V::loadu(qi + 1), V::loadu(qi + 2), cv, vp1,
                                mp2_v[v], m_v[v]);
        V::storeu(out[v] + 1 + i * N, l);
        mn[v] = V::min(mn[v], l);
        acc = V::add(acc, l);
      }
      V::storeu(sx + i * N, acc);
    }
    for (int v = 0; v < kNv; ++v) out[v][nd + 2] = static_cast<int16_t>(V::hmin(mn[v]));
  }
}

template <class V>
void path_rows_v(const PathParams& p, const uint8_t* c, const uint8_t* g, const uint8_t* gprev,
                 const int16_t* const* prev, int16_t* const* cur, int nv, const int* dxs,
                 ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, uint16_t* s, bool write) {
  if (nv == 3) {
    if (write) {
      path_rows_impl<V, 3, true>(p, c, g, gprev, prev, cur, dxs, cols, x0, x1, s);
    } else {
      path_rows_impl<V, 3, false>(p, c, g, gprev, prev, cur, dxs, cols, x0, x1, s);
    }
  } else if (write) {
    path_rows_impl<V, 1, true>(p, c, g, gprev, prev, cur, dxs, cols, x0, x1, s);
  } else {
    path_rows_impl<V, 1, false>(p, c, g, gprev, prev, cur, dxs, cols, x0, x1, s);
  }
}

void path_rows(const PathParams& p, const uint8_t* c, const uint8_t* g, const uint8_t* gprev,
               const int16_t* const* prev, int16_t* const* cur, int nv, const int* dxs,
               ptrdiff_t cols, ptrdiff_t x0, ptrdiff_t x1, uint16_t* s, bool write) {
#if defined(__AVX512BW__)
  if (p.nd % V512::kLanes == 0) {
    path_rows_v<V512>(p, c, g, gprev, prev, cur, nv, dxs, cols, x0, x1, s, write);
    return;
  }
#endif
  path_rows_v<V256>(p, c, g, gprev, prev, cur, nv, dxs, cols, x0, x1, s, write);
}

template <class V>
void fused_row_v(const FusedRowArgs& a) {
  if (a.lv) {
    if (a.base) {
      fused_row_impl<V, true, true>(a);
    } else {
      fused_row_impl<V, true, false>(a);
    }
  } else if (a.base) {
    fused_row_impl<V, false, true>(a);
  } else {
    fused_row_impl<V, false, false>(a);
  }
}

void fused_row(const FusedRowArgs& a) {
#if defined(__AVX512BW__)
  if (a.p.nd % V512::kLanes == 0) {
    fused_row_v<V512>(a);
    return;
  }
#endif
  fused_row_v<V256>(a);
}

template <class V, int kNv>
void fused_row_t_v2(const FusedRowArgs& a) {
  if (a.d.uniqueness_factor > 0 || a.conf != nullptr) {
    fused_row_t_impl<V, kNv, true>(a);
  } else {
    fused_row_t_impl<V, kNv, false>(a);
  }
}

// fused_row_t_v2 with the vector count nv as a constant when kNv <= nv <= 12 or nv == 16, so
// that the loops over the vectors unroll (whole calls 1.2-1.3x faster than with the run-time
// count at ndisp 16, 32, 80 and 160 with AVX2); larger counts take the run-time one.
template <class V, int kNv = 1>
void fused_row_t_v(const FusedRowArgs& a) {
  const int nv = a.p.nd / V::kLanes;
  if constexpr (kNv <= 12) {
    if (nv == kNv) {
      fused_row_t_v2<V, kNv>(a);
    } else {
      fused_row_t_v<V, kNv + 1>(a);
    }
  } else if (nv == 16) {
    fused_row_t_v2<V, 16>(a);
  } else {
    fused_row_t_v2<V, 0>(a);
  }
}

void fused_row_t(const FusedRowArgs& a) {
#if defined(__AVX512BW__)
  if (wide_transposed(a.p.nd)) {
    fused_row_t_v<V512>(a);
    return;
  }
#endif
  fused_row_t_v<V256>(a);
}
#endif

// ------------------------------------------------------------------------------------------
// The 3x3 median of the valid disparities.

// The 3x3 median of whole vectors of pixels (explicit SIMD; one template for AVX2 and
// AVX-512). When no window of the vector holds NaN (most of them), the median of nine by their
// sorted columns; else NaN becomes +inf (after every valid value), the five least of the nine
// are sorted by bubbling, and the lower median of the n valid values is the ((n - 1) / 2)-th
// least.
#if defined(__AVX2__)
struct F256 {
  using R = __m256;
  static constexpr int kLanes = 8;
  static R load(const float* p) { return _mm256_loadu_ps(p); }
  static void store(float* p, R v) { _mm256_storeu_ps(p, v); }
  static R set1(float v) { return _mm256_set1_ps(v); }
  static R min(R a, R b) { return _mm256_min_ps(a, b); }
  static R max(R a, R b) { return _mm256_max_ps(a, b); }
  static R add(R a, R b) { return _mm256_add_ps(a, b); }
  // Whether no lane of v is NaN.
  static bool none_nan(R v) { return _mm256_movemask_ps(_mm256_cmp_ps(v, v, _CMP_UNORD_Q)) == 0; }
  // v, or +inf where v is NaN (minps returns its second operand when either is NaN).
  static R nan_to_inf(R v) { return _mm256_min_ps(v, _mm256_set1_ps(INFINITY)); }
  static R count_valid(R n, R v) {
    return _mm256_add_ps(n, _mm256_and_ps(_mm256_cmp_ps(v, v, _CMP_ORD_Q), _mm256_set1_ps(1.0f)));
  }
  // b where n >= t, else a.
  static R select_ge(R a, R b, R n, float t) {
    return _mm256_blendv_ps(a, b, _mm256_cmp_ps(n, _mm256_set1_ps(t), _CMP_GE_OQ));
  }
  // mid where mid is NaN, else r.
  static R keep_nan(R mid, R r) {
    return _mm256_blendv_ps(r, mid, _mm256_cmp_ps(mid, mid, _CMP_UNORD_Q));
  }
};
#endif

#if defined(__AVX512F__)
struct F512 {
  using R = __m512;
  static constexpr int kLanes = 16;
  static R load(const float* p) { return _mm512_loadu_ps(p); }
  static void store(float* p, R v) { _mm512_storeu_ps(p, v); }
  static R set1(float v) { return _mm512_set1_ps(v); }
  static R min(R a, R b) { return _mm512_min_ps(a, b); }
  static R max(R a, R b) { return _mm512_max_ps(a, b); }
  static R add(R a, R b) { return _mm512_add_ps(a, b); }
  static bool none_nan(R v) { return _mm512_cmp_ps_mask(v, v, _CMP_UNORD_Q) == 0; }
  static R nan_to_inf(R v) { return _mm512_min_ps(v, _mm512_set1_ps(INFINITY)); }
  static R count_valid(R n, R v) {
    return _mm512_mask_add_ps(n, _mm512_cmp_ps_mask(v, v, _CMP_ORD_Q), n, _mm512_set1_ps(1.0f));
  }
  static R select_ge(R a, R b, R n, float t) {
    return _mm512_mask_blend_ps(_mm512_cmp_ps_mask(n, _mm512_set1_ps(t), _CMP_GE_OQ), a, b);
  }
  static R keep_nan(R mid, R r) {
    return _mm512_mask_blend_ps(_mm512_cmp_ps_mask(mid, mid, _CMP_UNORD_Q), r, mid);
  }
};
#endif

#if defined(__AVX2__)
// Columns x0 .. x1 - 1 (1 <= x0, x1 <= cols - 1) of a row with rows above and below.
template <class F>
ptrdiff_t median_vec(const float* up, const float* mid, const float* down, float* out,
                     ptrdiff_t x0, ptrdiff_t x1) {
  using R = typename F::R;
  constexpr int N = F::kLanes;
  ptrdiff_t x = x0;
  for (; x + N <= x1; x += N) {
    R v[9];
    const float* rows[3] = {up, mid, down};
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) v[3 * i + j] = F::load(rows[i] + x - 1 + j);
    }
    {
      // Every window whole (their sum is not NaN: disparities are finite or NaN): the median
      // of nine from the three sorted columns, the median of (the greatest of the columns'
      // least, the median of their middles, the least of their greatest); min and max pick
      // one of the values, so the result is that value exactly, as by sorting.
      R sum = v[0];
      for (int i = 1; i < 9; ++i) sum = F::add(sum, v[i]);
      if (F::none_nan(sum)) {
        R c[9];
        for (int j = 0; j < 3; ++j) {
          R a = v[j], b = v[3 + j], d = v[6 + j];
          R t = F::min(a, b);
          b = F::max(a, b);
          a = t;
          t = F::min(b, d);
          d = F::max(b, d);
          b = F::max(a, t);
          a = F::min(a, t);
          c[j] = a, c[3 + j] = b, c[6 + j] = d;
        }
        auto med3 = [](R a, R b, R d) { return F::max(F::min(a, b), F::min(F::max(a, b), d)); };
        const R lo = F::max(F::max(c[0], c[1]), c[2]);
        const R md = med3(c[3], c[4], c[5]);
        const R hi = F::min(F::min(c[6], c[7]), c[8]);
        F::store(out + x, med3(lo, md, hi));
        continue;
      }
    }
    R n = F::set1(0.0f);
    for (int i = 0; i < 9; ++i) {
      n = F::count_valid(n, v[i]);
      v[i] = F::nan_to_inf(v[i]);
    }
    // Bubble the five least to the front, in order.
    for (int i = 0; i < 5; ++i) {
      for (int j = 8; j > i; --j) {
        const R lo = F::min(v[j - 1], v[j]);
        v[j] = F::max(v[j - 1], v[j]);
        v[j - 1] = lo;
      }
    }
    R r = v[0];
    r = F::select_ge(r, v[1], n, 3.0f);
    r = F::select_ge(r, v[2], n, 5.0f);
    r = F::select_ge(r, v[3], n, 7.0f);
    r = F::select_ge(r, v[4], n, 9.0f);
    F::store(out + x, F::keep_nan(F::load(mid + x), r));
  }
  return x;
}
#endif


// The lower median of the valid values of a window (n <= 9), by insertion.
inline float median_slow(const float* const* rows, int nrows, ptrdiff_t x, ptrdiff_t cols) {
  float v[9];
  int n = 0;
  for (int i = 0; i < nrows; ++i) {
    for (ptrdiff_t xx = x > 0 ? x - 1 : 0; xx <= x + 1 && xx < cols; ++xx) {
      const float f = rows[i][xx];
      if (f == f) {
        int j = n++;
        while (j > 0 && v[j - 1] > f) {
          v[j] = v[j - 1];
          --j;
        }
        v[j] = f;
      }
    }
  }
  return v[(n - 1) / 2];
}

inline void order(float& a, float& b) {
  const float lo = a < b ? a : b;
  const float hi = a < b ? b : a;
  a = lo;
  b = hi;
}

void median_row(const float* up, const float* mid, const float* down, float* out,
                std::uint8_t* flags, ptrdiff_t cols) {
  const float* rows[3];
  int nrows = 0;
  if (up) rows[nrows++] = up;
  rows[nrows++] = mid;
  if (down) rows[nrows++] = down;
  ptrdiff_t x0 = 0, x1 = 0;  // columns done by the network
#if defined(__AVX2__)
  if (up && down && cols >= 3) {
    // Vectors over the inner columns, the rest one by one.
#if defined(__AVX512F__)
    using F = F512;
#else
    using F = F256;
#endif
    ptrdiff_t xv = median_vec<F>(up, mid, down, out, 1, cols - 1);
    if (xv < cols - 1 && cols - 2 >= F::kLanes) {
      // The tail: one more vector ending at the last inner column (overlapping the previous
      // one, whose columns it computes again, identically).
      median_vec<F>(up, mid, down, out, cols - 1 - F::kLanes, cols - 1);
      xv = cols - 1;
    }
    auto one = [&](ptrdiff_t x) {
      out[x] = mid[x] != mid[x] ? mid[x] : median_slow(rows, nrows, x, cols);
    };
    one(0);
    for (ptrdiff_t x = std::max<ptrdiff_t>(xv, 1); x < cols; ++x) one(x);
    return;
  }
#endif
  if (up && down && cols >= 3) {
    x0 = 1;
    x1 = cols - 1;
    // Nine valid values: the median by a fixed network of 19 compare-exchanges (min/max
    // pick one of the values, so the result is that value exactly), across columns.
    for (ptrdiff_t x = x0; x < x1; ++x) {
      float p0 = up[x - 1], p1 = up[x], p2 = up[x + 1];
      float p3 = mid[x - 1], p4 = mid[x], p5 = mid[x + 1];
      float p6 = down[x - 1], p7 = down[x], p8 = down[x + 1];
      order(p1, p2); order(p4, p5); order(p7, p8);
      order(p0, p1); order(p3, p4); order(p6, p7);
      order(p1, p2); order(p4, p5); order(p7, p8);
      order(p0, p3); order(p5, p8); order(p4, p7);
      order(p3, p6); order(p1, p4); order(p2, p5);
      order(p4, p7); order(p4, p2); order(p6, p4);
      order(p4, p2);
      out[x] = p4;
      // Whether any of the nine is NaN (then the slow path decides).
      const bool all = (p0 == p0) & (up[x] == up[x]) & (up[x + 1] == up[x + 1]) &
                       (mid[x - 1] == mid[x - 1]) & (mid[x] == mid[x]) &
                       (mid[x + 1] == mid[x + 1]) & (down[x - 1] == down[x - 1]) &
                       (down[x] == down[x]) & (down[x + 1] == down[x + 1]) &
                       (up[x - 1] == up[x - 1]);
      flags[x] = all ? 1 : 0;
    }
  }
  for (ptrdiff_t x = 0; x < cols; ++x) {
    if (mid[x] != mid[x]) {
      out[x] = mid[x];
    } else if (x < x0 || x >= x1 || !flags[x]) {
      out[x] = median_slow(rows, nrows, x, cols);
    }
  }
}

}  // namespace

const SemiGlobalKernels& semi_global_kernels() {
  static const SemiGlobalKernels kernels = {
      &raw_row,
      &box_row,
      &horizontal_row,
      &path_row,
      &decide_row,
      &median_row,
#if defined(__AVX2__)
      &raw_row8,
      &box_row8,
      &path_rows,
      &fused_row,
      16,
      &raw_row8_t,
      &box_row8_t,
      &fused_row_t,
#else
      nullptr,
      nullptr,
      nullptr,
      nullptr,
      0,
      nullptr,
      nullptr,
      nullptr,
#endif
  };
  return kernels;
}

}  // namespace stereodepth::detail::STEREODEPTH_ISA_NS
