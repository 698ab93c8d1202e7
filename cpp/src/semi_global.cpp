#include "stereodepth/semi_global.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "block_match_kernels.hpp"
#include "module_support.hpp"
#include "semi_global_kernels.hpp"
#include "speckle.hpp"
#include "stereodepth/parallel.hpp"

namespace stereodepth {
namespace {

const detail::BlockMatchKernels& shared_kernels(Isa isa) {
  return STEREODEPTH_KERNELS_FOR(isa, block_match_kernels);
}

const detail::SemiGlobalKernels& sgm_kernels(Isa isa) {
  return STEREODEPTH_KERNELS_FOR(isa, semi_global_kernels);
}

using detail::fail;

int cost_max(int block_size) { return 16 * block_size * block_size; }

// int16 per pixel in path rows: sentinel, nd costs, sentinel, least cost; rounded up to 16.
int path_stride(int nd) { return (nd + 3 + 15) / 16 * 16; }

int vertical_paths(int paths) { return paths == 8 ? 3 : 1; }

// paths == 3: the stripes, whose path from above starts at their first row. ceil(rows / 64)
// of them, one more when that is odd and above 1, of nearly equal height (stripe s starts at
// row s * rows / n), so that two threads get the same number of rows: at 1280 x 720, twelve
// stripes of 60 rows rather than eleven of 64 and one of 16 (a ceiling of 1.875x on the
// speed-up from one thread to two). semi_global.py's stripe_starts states the same rule.
constexpr std::ptrdiff_t kStripeRows = 64;

// The disparities the costs and paths run over: num_disparities rounded up to a multiple of
// 16 (the lanes of the SIMD kernels' vectors); the ones above num_disparities take part in the
// paths but never win (the decision treats them as outside the image). Without this, a
// num_disparities of 60 ran the plain kernels at 3-4x the time of 64 (paths 4 and 8: 2-3x).
int run_disparities(int nd) { return (nd + 15) / 16 * 16; }

std::ptrdiff_t stripe_count(std::ptrdiff_t rows) {
  std::ptrdiff_t n = std::max<std::ptrdiff_t>(1, (rows + kStripeRows - 1) / kStripeRows);
  if (n > 1 && n % 2 == 1) ++n;
  return n;
}

// Threads meet at every row (the diagonal paths read the previous row across band edges).
// A row's share takes tens of microseconds, less than waking a blocked thread costs, so a
// waiting thread spins on the generation count for up to kSpin, yielding the CPU every few
// microseconds, and only then blocks. Both matter on a virtual machine after an idle spell
// (a call per camera frame): the kernel may run two bands on one CPU for milliseconds, and a
// spin of 0.1 ms without yielding then ended in a block and a wake-up at nearly every row
// (paths=8 on Tsukuba after 50 ms idle: 14 ms, against 4.5 back to back and 6-10 with this
// spin; more callers than CPUs gained as much; bench/README, twenty-fourth round).
// wait() returns whether the call was asked to stop, as its last arrival saw it, so that every
// band gets the same answer (a band that stopped alone would leave the others waiting for
// ever).
class Barrier {
 public:
  explicit Barrier(std::ptrdiff_t n) : n_(n) {}
  bool wait() {
    const std::uint64_t gen = gen_.load(std::memory_order_acquire);
    if (count_.fetch_add(1, std::memory_order_acq_rel) + 1 == n_) {
      count_.store(0, std::memory_order_relaxed);
      // Read by the others after they see the new generation; written again only when all of
      // them have arrived once more.
      stop_.store(stop_requested(), std::memory_order_relaxed);
      {
        std::lock_guard<std::mutex> lock(m_);
        gen_.store(gen + 1, std::memory_order_release);
      }
      cv_.notify_all();
      return stop_.load(std::memory_order_relaxed);
    }
    auto arrived = [&] { return gen_.load(std::memory_order_acquire) != gen; };
    if (!spin_until(arrived, kSpin)) {
      std::unique_lock<std::mutex> lock(m_);
      cv_.wait(lock, arrived);
    }
    return stop_.load(std::memory_order_relaxed);
  }

 private:
  static constexpr std::chrono::microseconds kSpin{1000};
  std::mutex m_;
  std::condition_variable cv_;
  const std::ptrdiff_t n_;
  std::atomic<std::ptrdiff_t> count_{0};
  std::atomic<std::uint64_t> gen_{0};
  std::atomic<bool> stop_{false};
};

// The threads a call runs. Paths 4 and 8 run at most one per CPU this process may use
// (default_threads()), whatever `threads` asks: their vertical passes split the columns into
// bands that meet at every row, and a band whose thread waits for a core holds every other
// band up at each row (16 threads on 2 cores took 8 to 20 times as long as 2). The single
// pass (paths 3) hands out stripes and keeps the count asked for. The output does not
// depend on it.
int team_threads(int threads, int paths) {
  const int n = std::max(1, threads);
  return paths == 3 ? n : std::min(n, default_threads());
}

// Tests only (set_column_bands_for_tests): two threads take the column bands too, so that a
// machine with two CPUs, where paths 4 and 8 never run more threads, still runs them.
std::atomic<bool> g_column_bands{false};

// Paths 4 and 8 on two threads: the downward and the upward pass run at once, one thread
// each (step 1), and wait for each other once, at the middle row, rather than splitting the
// columns between them (paths 8: meeting at a barrier at every row); each then does step 2
// on the rows it completes, while their sums are in its cache. In one process on Zen 4, two
// threads, against the column bands and a step 2 of its own: paths 8 on the ten shared scenes
// 0.62-1.00 of the time with AVX2 and 0.64-0.94 with AVX-512 for the passes at once, and
// 0.89-1.005 more for step 2 in them (1280 x 720 x 128: 0.90-0.99, then 0.90-0.93); paths 4
// 0.79-0.93 for both (bench/README, twenty-seventh round). Three or more threads keep the
// bands, which use them all.
bool concurrent_passes(int paths, int threads) {
  return paths != 3 && threads == 2 && !g_column_bands.load(std::memory_order_relaxed);
}

// How long a pass spins (yielding) before it checks for a stop again, waiting for the other.
constexpr std::chrono::microseconds kPassWait{1000};

// Paths 4 and 8: the bands of columns of the vertical passes, one thread each.
std::ptrdiff_t vertical_bands(int threads, std::ptrdiff_t cols) {
  return std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(threads, cols / 16));
}

// Paths 4 and 8: the threads of step 1, the two passes at once (each over every column) or
// the column bands.
std::ptrdiff_t pass_bands(int paths, int threads, std::ptrdiff_t cols) {
  return concurrent_passes(paths, threads) ? 2 : vertical_bands(threads, cols);
}

// Paths 4 and 8: whether step 1 also does step 2, each pass on the rows it completes (the
// passes at once, or one thread), each keeping step 2's scratch beside its own.
bool finish_in_passes(int paths, int threads) {
  return concurrent_passes(paths, threads) || threads == 1;
}

// Runs fn(b) for b in [0, n), each on its own thread (the caller's is the first).
template <typename Fn>
void run_bands(std::ptrdiff_t n, Fn fn) {
  parallel_for_rows(n, static_cast<int>(n), 1, [&](std::ptrdiff_t b0, std::ptrdiff_t b1) {
    for (std::ptrdiff_t b = b0; b < b1; ++b) fn(b);
  });
}

// The pixel costs of the last census rows a thread used (raw_row or raw_row8: T is uint16_t
// or uint8_t), so that each image row computes one new census row's costs rather than the
// box's 2r + 1.
template <typename T>
struct RawRows {
  T* slot[3] = {nullptr, nullptr, nullptr};
  std::ptrdiff_t row[3] = {-1, -1, -1};
  int slots = 3;  // the slots in use (2r + 1 suffice)

  // The costs of the census rows y - r .. y + r (clamped) into raws; compute(yy, out) fills
  // one slot with census row yy's costs. With `deferred` (not null), the last missing row,
  // when it is needed once, is left to the caller: its index in raws, else -1.
  template <typename Compute>
  void get(std::ptrdiff_t rows, int r, std::ptrdiff_t y, T** raws, Compute compute,
           int* deferred = nullptr) {
    std::ptrdiff_t need[3];
    for (int i = 0; i < 2 * r + 1; ++i) {
      need[i] = std::clamp<std::ptrdiff_t>(y + i - r, 0, rows - 1);
    }
    auto needed = [&](std::ptrdiff_t yy) {
      for (int i = 0; i < 2 * r + 1; ++i) {
        if (need[i] == yy) return true;
      }
      return false;
    };
    int last = -1;  // the last missing row's index in need, when it is needed once
    if (deferred) {
      *deferred = -1;
      for (int i = 0; i < 2 * r + 1; ++i) {
        bool have = false;
        int uses = 0;
        for (int s = 0; s < slots; ++s) have = have || row[s] == need[i];
        for (int j = 0; j < 2 * r + 1; ++j) uses += need[j] == need[i] ? 1 : 0;
        if (!have) last = uses == 1 ? i : -1;
      }
    }
    for (int i = 0; i < 2 * r + 1; ++i) {
      int at = -1;
      for (int s = 0; s < slots; ++s) {
        if (row[s] == need[i]) at = s;
      }
      if (at < 0) {
        for (int s = 0; s < slots && at < 0; ++s) {
          if (row[s] < 0 || !needed(row[s])) at = s;
        }
        if (i == last) {
          *deferred = i;
        } else {
          compute(need[i], slot[at]);
        }
        row[at] = need[i];
      }
      raws[i] = slot[at];
    }
  }
};

template <typename T>
T* aligned(std::vector<std::uint8_t>& v, std::size_t count) {
  const std::size_t bytes = count * sizeof(T) + 64;
  if (v.size() < bytes) v.resize(bytes);
  const auto addr = reinterpret_cast<std::uintptr_t>(v.data());
  return reinterpret_cast<T*>(v.data() + (64 - addr % 64) % 64);
}

std::size_t sz(std::ptrdiff_t n) { return static_cast<std::size_t>(n); }

// uint16 units rounded up to whole 64-byte lines.
std::size_t r64(std::size_t n16) { return (n16 + 31) / 32 * 32; }

// Bytes aligned<>() allocates for n16 uint16 units.
double bytes16(std::size_t n16) { return 2.0 * static_cast<double>(n16) + 64.0; }

// The fused row's scratch (offsets in uint16 units, each piece 64-byte aligned): the sums of
// the vertical path and the path from the left, the per-disparity pieces, the per-pixel
// results.
struct FusedScratch {
  std::size_t small, result, rfinal, total;
  FusedScratch(std::size_t c, int nd) {
    small = r64(c * sz(nd));
    result = small + r64(8 * sz(nd) + 512);
    rfinal = result + r64(8 * c);
    total = rfinal + r64(c);
  }
};

// Paths 4 and 8, step 2's scratch per thread (uint16 units): the fused row's, or the plain
// row's copy of the sums, right winners (2 x c), winners (2 x c) and horizontal paths.
std::size_t row_scratch_n16(std::size_t c, int nd, int ls, bool fused) {
  return fused ? FusedScratch(c, nd).total : c * sz(nd) + 4 * c + 2 * sz(ls) + 32;
}

// The single-pass mode's grey and census rows, computed by each thread when it needs them
// rather than for the whole image: census row y of an image from its grey rows y - 2 .. y + 2
// (clamped); the grey rows of an RGB pair (and the 8-bit grey of a uint16 left image, for
// P2') in a ring of kRing rows per image, row y in slot y % kRing, so that any kRing
// consecutive rows are there at once. Grey uint8 images are read in place.
class PairRows {
 public:
  static constexpr std::ptrdiff_t kRing = 8;

  static int ring_images(PixelFormat f) {
    return is_colour(f) ? 2 : f == PixelFormat::kGrey16 ? 1 : 0;
  }
  // uint16 units of scratch for `cols` columns.
  static std::size_t n16(std::size_t c, int ring_images) {
    return r64(2 * c + 32) + 2 * r64(c + 32) + r64((sz(ring_images * kRing) * c + 1) / 2);
  }

  PairRows(const detail::BlockMatchKernels& bk, const StereoImage& left,
           const StereoImage& right, std::uint16_t* at)
      : bk_(bk), rows_(left.rows), cols_(left.cols), format_(left.format) {
    const auto c = sz(cols_);
    img_[0] = &left;
    img_[1] = &right;
    tmp_ = reinterpret_cast<std::uint32_t*>(at);
    at += r64(2 * c + 32);
    for (auto& cen : cen_) {
      cen = at;
      at += r64(c + 32);
    }
    for (int im = 0; im < 2; ++im) {
      grey_[im] = reinterpret_cast<std::uint8_t*>(at) + sz(im * kRing) * c;
      for (auto& t : tag_[im]) t = -1;
    }
  }

  // Grey row y (clamped) of image `im` on the 8-bit scale.
  const std::uint8_t* grey8(int im, std::ptrdiff_t y) {
    y = std::clamp<std::ptrdiff_t>(y, 0, rows_ - 1);
    const StereoImage& src = *img_[im];
    const auto* row = static_cast<const std::uint8_t*>(src.data) + y * src.row_stride;
    if (format_ == PixelFormat::kGrey8) return row;
    const std::ptrdiff_t slot = y % kRing;
    std::uint8_t* g = grey_[im] + slot * cols_;
    if (tag_[im][slot] != y) {
      if (is_colour(format_)) {
        bk_.rgb_to_grey(row, g, cols_, format_ == PixelFormat::kBgr8);
      } else {
        const auto* s16 = reinterpret_cast<const std::uint16_t*>(row);
        for (std::ptrdiff_t x = 0; x < cols_; ++x) g[x] = static_cast<std::uint8_t>(s16[x] >> 8);
      }
      tag_[im][slot] = y;
    }
    return g;
  }

  // The buffer census(im, ...) writes (its last row; a valid pointer before any call).
  const std::uint16_t* last(int im) const { return cen_[im]; }

  // Census row y of image `im`, valid until the next call for that image.
  const std::uint16_t* census(int im, std::ptrdiff_t y) {
    if (format_ == PixelFormat::kGrey16) {
      const std::uint16_t* r5[5];
      for (int i = 0; i < 5; ++i) {
        const std::ptrdiff_t yy = std::clamp<std::ptrdiff_t>(y + i - 2, 0, rows_ - 1);
        r5[i] = reinterpret_cast<const std::uint16_t*>(
            static_cast<const std::uint8_t*>(img_[im]->data) + yy * img_[im]->row_stride);
      }
      bk_.census_row16(r5, tmp_, cols_);
    } else {
      const std::uint8_t* r5[5];
      for (int i = 0; i < 5; ++i) r5[i] = grey8(im, y + i - 2);
      bk_.census_row8(r5, tmp_, cols_);
    }
    std::uint16_t* out = cen_[im];
    for (std::ptrdiff_t x = 0; x < cols_; ++x) out[x] = static_cast<std::uint16_t>(tmp_[x]);
    return out;
  }

 private:
  const detail::BlockMatchKernels& bk_;
  const StereoImage* img_[2];
  std::ptrdiff_t rows_, cols_;
  PixelFormat format_;
  std::uint32_t* tmp_;
  std::uint16_t* cen_[2];
  std::uint8_t* grey_[2];
  std::ptrdiff_t tag_[2][kRing];
};

// A single-pass thread's scratch with the fused row (uint16 offsets from a 64-byte aligned
// start): the raw rows' and the box's scratch (rev), the 2r + 1 raw rows of 8-bit costs and the
// box's ring, the row's box costs, the path from above, its least costs per pixel, the fused
// row's scratch, the grey and census rows.
struct FusedStripeLayout {
  std::size_t raw, crow, lv, lvmin, fused, pair, total;
  FusedStripeLayout(std::size_t c, int nd, int r, int ring_images) {
    const std::size_t d = sz(nd);
    raw = r64((detail::rev8_bytes(static_cast<std::ptrdiff_t>(c), nd) + 1) / 2);
    crow = raw + r64((sz(2 * r + 1) * (c + 2) * d + 3 * d + 1) / 2);
    lv = crow + r64((c * d + 1) / 2);
    lvmin = lv + r64(detail::kFusedPad + c * (d + detail::kFusedPad) + 64);
    fused = lvmin + r64(c);
    pair = fused + FusedScratch(c, nd).total;
    total = pair + PairRows::n16(c, ring_images);
  }
};

// The same without the fused row (16-bit costs): rev, the box's column sums and the 2r + 1 raw
// rows, the row's sums, rmin and rarg, the box costs, two rows of path costs, the horizontal
// paths' scratch, the winners, the grey and census rows.
struct PlainStripeLayout {
  std::size_t colraw, sums, rmin, rarg, crow, rows16, tmp, winners, pair, total;
  PlainStripeLayout(std::size_t c, int nd, int ls, int r, int ring_images) {
    const std::size_t d = sz(nd), n_col = c * d;
    colraw = r64(c + d);
    sums = colraw + r64(sz(2 * r + 2) * (c + 2) * d);
    rmin = sums + r64(n_col);
    rarg = rmin + r64(c);
    crow = rarg + r64(c);
    rows16 = crow + r64((n_col + 1) / 2);
    tmp = rows16 + r64(2 * c * sz(ls));
    winners = tmp + r64(2 * sz(ls));
    pair = winners + r64(2 * c);
    total = pair + PairRows::n16(c, ring_images);
  }
};

// The in-place median's scratch per thread: two rows as they were, the kernel's flags.
std::size_t median_n16(std::size_t c) { return 2 * r64(2 * c) + r64((c + 1) / 2); }

}  // namespace

void set_column_bands_for_tests(bool on) { g_column_bands.store(on); }

void validate(const SemiGlobalParams& p) {
  if (p.num_disparities < 1 || p.num_disparities > kMaxNumDisparities) {
    fail("num_disparities must be an integer in [1, " + std::to_string(kMaxNumDisparities) + "]",
         p.num_disparities);
  }
  if (p.min_disparity < -kMaxAbsMinDisparity || p.min_disparity > kMaxAbsMinDisparity) {
    fail("min_disparity must be an integer in [-" + std::to_string(kMaxAbsMinDisparity) + ", " +
             std::to_string(kMaxAbsMinDisparity) + "]",
         p.min_disparity);
  }
  if (p.block_size != 1 && p.block_size != 3) {
    fail("block_size must be 1 or 3 (box costs are stored in 8 bits)", p.block_size);
  }
  if (p.paths != 3 && p.paths != 4 && p.paths != 8) fail("paths must be 3, 4 or 8", p.paths);
  if (p.p1 < 0) fail("p1 must be an integer >= 0", p.p1);
  const int limit = std::min(65535 / p.paths, 16383) - cost_max(p.block_size);
  if (p.p2 < p.p1 || p.p2 > limit) {
    fail("p2 must be an integer in [p1, " + std::to_string(limit) +
             "] (the sum over the paths must fit in 16 bits)",
         p.p2);
  }
  if (p.p2_step < 0 || p.p2_step > 65535) {
    fail("p2_step must be an integer in [0, 65535]", p.p2_step);
  }
  if (p.subpixel != SubpixelFit::kNone && p.subpixel != SubpixelFit::kParabola &&
      p.subpixel != SubpixelFit::kEquiangular) {
    fail("subpixel must be none, parabola or equiangular", static_cast<int>(p.subpixel));
  }
  if (!(std::isfinite(p.uniqueness_ratio) && p.uniqueness_ratio >= 0)) {
    fail("uniqueness_ratio must be a finite number >= 0", p.uniqueness_ratio);
  }
  if (!std::isfinite(p.lr_max_diff)) {
    fail("lr_max_diff must be a finite number (negative: off)", p.lr_max_diff);
  }
  if (p.speckle_window < 0) fail("speckle_window must be an integer >= 0", p.speckle_window);
  if (!(std::isfinite(p.speckle_range) && p.speckle_range >= 0)) {
    fail("speckle_range must be a finite number >= 0", p.speckle_range);
  }
  if (!(std::isfinite(p.max_memory_mb) && p.max_memory_mb > 0)) {
    fail("max_memory_mb must be a finite number > 0", p.max_memory_mb);
  }
}

std::size_t semi_global_memory(std::ptrdiff_t rows, std::ptrdiff_t cols, int nd, int paths,
                               int threads, Isa isa, int block_size) {
  threads = team_threads(threads, paths);
  nd = run_disparities(nd);
  // What compute() allocates for an RGB pair (grey pairs need a little less), with the median
  // on; the speckle filter's runs, which depend on the disparities, are left out.
  const detail::SemiGlobalKernels& k = sgm_kernels(isa);
  const bool fused = k.fused_row != nullptr && nd % k.fused_lanes == 0;
  const int r = block_size / 2;
  const std::size_t c = sz(std::max<std::ptrdiff_t>(cols, 1));
  const double h = static_cast<double>(std::max<std::ptrdiff_t>(rows, 1));
  const double w = static_cast<double>(c), d = nd;
  const int ls = path_stride(nd);
  const std::ptrdiff_t nt =
      std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(std::max(1, threads), rows));
  const double median = bytes16(median_n16(c));
  double bytes = 2.0 * static_cast<double>(nt - 1) * w * 4.0;  // the median's band edges
  if (paths == 3) {
    // Per thread: a few rows of W x D (the stripes' threads) or the median's rows.
    const std::ptrdiff_t stripes = stripe_count(rows);
    const std::ptrdiff_t ns = std::min<std::ptrdiff_t>(nt, stripes);
    const double stripe = bytes16(fused ? FusedStripeLayout(c, nd, r, 2).total
                                        : PlainStripeLayout(c, nd, ls, r, 2).total);
    bytes += static_cast<double>(ns) * std::max(stripe, median) +
             static_cast<double>(nt - ns) * median;
  } else {
    // The images' census (2 x 2 bytes per pixel), the left grey for P2' (1) and the RGB
    // pair's grey (2); the sums and the costs (3 bytes per pixel and disparity); the path rows.
    bytes += h * w * 7.0 + 64.0 * 4;
    bytes += h * w * d * 3.0 + 128.0;
    // The path rows: one set, or one per pass when the passes run at once.
    const bool concurrent = concurrent_passes(paths, threads);
    bytes += bytes16((concurrent ? 2 : 1) * 2 * sz(vertical_paths(paths)) * c * sz(ls));
    // Per thread, the most of its stages: census, the vertical paths over a band of columns
    // (all of them when the passes run at once), the row's horizontal paths and decision, the
    // median.
    const std::ptrdiff_t nb = pass_bands(paths, threads, cols);
    const std::size_t band_cols = concurrent ? c : (c + sz(nb) - 1) / sz(nb);
    const double vertical =
        bytes16(c + sz(nd) + 32 + 4 * (band_cols + 2) * sz(nd) + sz(nd));
    const double row = bytes16(row_scratch_n16(c, nd, ls, fused));
    const double census = 4.0 * w + 64.0;
    for (std::ptrdiff_t b = 0; b < std::max(nt, nb); ++b) {
      double most = 0.0;
      if (b < nt) most = std::max({census, row, median});
      if (b < nb) most = std::max(most, vertical);
      // Step 2 in step 1: each pass also keeps the row's scratch.
      if (finish_in_passes(paths, threads)) most = std::max({census, median, vertical}) + row;
      bytes += most;
    }
  }
  return static_cast<std::size_t>(std::min(bytes, 1.8e19));
}

struct SemiGlobalMatcher::Workspace {
  std::vector<std::uint8_t> sums, costs, census_l, census_r, grey, pgrey, path_rows;
  std::vector<float> median_edges;  // rows around the boundaries of the median's bands
  std::vector<std::vector<std::uint8_t>> scratch;  // per thread
  std::vector<std::vector<std::uint8_t>> finish;   // paths 4, 8: step 2's, per pass (1-2)
  std::vector<detail::SpeckleBand> speckle;
  detail::SpeckleJoin speckle_join;
};

SemiGlobalMatcher::SemiGlobalMatcher(const SemiGlobalParams& params, int threads, Isa isa)
    : params_(params), threads_(resolve_threads(threads)), isa_(isa),
      workspace_(std::make_unique<Workspace>()) {
  validate(params_);
}

SemiGlobalMatcher::~SemiGlobalMatcher() = default;

void SemiGlobalMatcher::check_memory(std::ptrdiff_t rows, std::ptrdiff_t cols) const {
  const SemiGlobalParams& p = params_;
  const int nd_win = p.num_disparities;
  const std::size_t need =
      semi_global_memory(rows, cols, nd_win, p.paths, threads_, isa_, p.block_size);
  const double need_mb = static_cast<double>(need) / 1048576.0;
  if (need_mb > p.max_memory_mb) {
    std::ostringstream msg;
    msg.precision(need_mb < 10.0 ? 2 : 0);  // no "needs about 0 MiB" for a tiny limit
    msg << std::fixed << "semi-global matching of a " << cols << "x" << rows  // width x height
        << " px pair with num_disparities=" << nd_win << " and paths=" << p.paths << " needs about "
        << need_mb << " MiB, above max_memory_mb=";
    msg.unsetf(std::ios::floatfield);
    msg.precision(6);
    msg << p.max_memory_mb << "; lower num_disparities, ";
    if (p.paths != 3) {
      msg << "use paths=3 (a few rows per thread instead of 3 bytes per pixel and disparity), ";
    }
    msg << "match a smaller (cropped or downscaled) pair, or raise max_memory_mb";
    throw std::invalid_argument(msg.str());
  }
}

void SemiGlobalMatcher::compute(const StereoImage& left, const StereoImage& right,
                                const ImageView<float>& disparity,
                                const ImageView<float>& confidence) {
  const SemiGlobalParams& p = params_;
  if (left.rows < 1 || left.cols < 1) {
    throw std::invalid_argument("left must have at least one row and one column");
  }
  if (left.rows != right.rows || left.cols != right.cols || left.format != right.format) {
    throw std::invalid_argument("left and right must have the same shape and pixel format");
  }
  if (disparity.rows != left.rows || disparity.cols != left.cols) {
    throw std::invalid_argument("disparity must have the shape of the images");
  }
  if (confidence.data && (confidence.rows != left.rows || confidence.cols != left.cols)) {
    throw std::invalid_argument("confidence must have the shape of the images");
  }
  const std::ptrdiff_t rows = left.rows, cols = left.cols;
  const int nd_win = p.num_disparities;  // the disparities that may win
  const int nd = run_disparities(nd_win);
  check_memory(rows, cols);
  const int threads = team_threads(threads_, p.paths);

  std::lock_guard<std::mutex> lock(mutex_);
  Workspace& ws = *workspace_;
  const detail::BlockMatchKernels& bk = shared_kernels(isa_);
  const detail::SemiGlobalKernels& k = sgm_kernels(isa_);
  const bool sixteen = left.format == PixelFormat::kGrey16;
  const bool colour = is_colour(left.format);
  const bool bgr = left.format == PixelFormat::kBgr8;
  const int r = p.block_size / 2;
  const int cmax = cost_max(p.block_size);
  const auto npix = static_cast<std::size_t>(rows * cols);
  const std::size_t vol = npix * static_cast<std::size_t>(nd);
  const int ls = path_stride(nd);

  // paths == 3 keeps no image-sized buffer: its threads compute the grey and census rows
  // they need (PairRows). Paths 4 and 8 keep the census and grey images.
  const bool single_pass = p.paths == 3;
  const std::size_t whole = single_pass ? 0 : npix;
  auto* sums = aligned<std::uint16_t>(ws.sums, single_pass ? 0 : vol);
  auto* costs = aligned<std::uint8_t>(ws.costs, single_pass ? 0 : vol);
  auto* lcen = aligned<std::uint16_t>(ws.census_l, whole);
  auto* rcen = aligned<std::uint16_t>(ws.census_r, whole);
  auto* grey = aligned<std::uint8_t>(ws.grey, colour ? 2 * whole : 0);
  auto* pgrey = aligned<std::uint8_t>(ws.pgrey, whole);  // grey levels for P2', 8-bit scale

  const std::ptrdiff_t nt = std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(threads, rows));
  const auto unt = static_cast<std::size_t>(nt);
  if (ws.scratch.size() < unt) ws.scratch.resize(unt);
  auto band = [](std::ptrdiff_t n, std::ptrdiff_t parts, std::ptrdiff_t b) {
    return n * b / parts;
  };

  // 0. Paths 4 and 8: the grey and census images (rows split between the threads).
  const StereoImage* images[2] = {&left, &right};
  std::uint16_t* census[2] = {lcen, rcen};
  if (colour && !single_pass) {
    run_bands(nt, [&](std::ptrdiff_t b) {
      for (int im = 0; im < 2; ++im) {
        for (std::ptrdiff_t y = band(rows, nt, b); y < band(rows, nt, b + 1); ++y) {
          bk.rgb_to_grey(static_cast<const std::uint8_t*>(images[im]->data) +
                             y * images[im]->row_stride,
                         grey + static_cast<std::size_t>(im) * npix + y * cols, cols, bgr);
        }
      }
    });
  }
  run_bands(single_pass ? 0 : nt, [&](std::ptrdiff_t b) {
    auto* tmp = aligned<std::uint32_t>(ws.scratch[static_cast<std::size_t>(b)],
                                       static_cast<std::size_t>(cols));
    for (int im = 0; im < 2; ++im) {
      const StereoImage& src = *images[im];
      auto row_ptr = [&](std::ptrdiff_t y) -> const void* {
        y = std::clamp<std::ptrdiff_t>(y, 0, rows - 1);
        if (colour) return grey + static_cast<std::size_t>(im) * npix + y * cols;
        return static_cast<const std::uint8_t*>(src.data) + y * src.row_stride;
      };
      for (std::ptrdiff_t y = band(rows, nt, b); y < band(rows, nt, b + 1); ++y) {
        const void* r5[5];
        for (int i = 0; i < 5; ++i) r5[i] = row_ptr(y + i - 2);
        if (sixteen) {
          bk.census_row16(reinterpret_cast<const std::uint16_t* const*>(r5), tmp, cols);
        } else {
          bk.census_row8(reinterpret_cast<const std::uint8_t* const*>(r5), tmp, cols);
        }
        std::uint16_t* out = census[im] + y * cols;
        for (std::ptrdiff_t x = 0; x < cols; ++x) out[x] = static_cast<std::uint16_t>(tmp[x]);
        if (im == 0) {
          std::uint8_t* g = pgrey + y * cols;
          if (sixteen) {
            const auto* s16 = static_cast<const std::uint16_t*>(row_ptr(y));
            for (std::ptrdiff_t x = 0; x < cols; ++x) g[x] = static_cast<std::uint8_t>(s16[x] >> 8);
          } else {
            std::memcpy(g, row_ptr(y), static_cast<std::size_t>(cols));
          }
        }
      }
    }
  });

  // P2' = max(P1, P2 * k // (k + |step|)) for each signed intensity step -255 .. 255 (k =
  // p2_step; 0: P2), at p2_table[255 + step]: the kernels index it by the signed step, with no
  // branch on its sign (a branch that real images mispredict about every other pixel).
  std::int16_t p2_table[511];
  for (int step = 0; step <= 255; ++step) {
    const long long v =
        p.p2_step > 0 ? static_cast<long long>(p.p2) * p.p2_step / (p.p2_step + step) : p.p2;
    p2_table[255 + step] = p2_table[255 - step] =
        static_cast<std::int16_t>(std::max<long long>(v, p.p1));
  }
  detail::PathParams pp{nd, ls, p.p1, p2_table + 255};

  detail::DecideArgs da{};
  da.cols = cols;
  da.nd = nd_win;
  da.stride = nd;
  da.min_d = p.min_disparity;
  da.subpixel = static_cast<int>(p.subpixel);
  da.uniqueness_factor = p.uniqueness_ratio > 0 ? 100.0 + p.uniqueness_ratio : 0.0;
  da.lr_max_diff = p.lr_max_diff;
  da.clip_border = p.clip_border;

  const auto n_col = static_cast<std::size_t>(cols) * static_cast<std::size_t>(nd);
  const bool fused = k.fused_row != nullptr && nd % k.fused_lanes == 0;
  const FusedScratch fs(sz(cols), nd);
  auto fused_args = [&](std::uint16_t* at) {
    detail::FusedRowArgs fa{};
    fa.p = pp;
    fa.d = da;
    fa.partial = at;
    fa.small = at + fs.small;
    fa.result = reinterpret_cast<std::uint32_t*>(at + fs.result);
    fa.rfinal = at + fs.rfinal;
    return fa;
  };
  const int ring_images = PairRows::ring_images(left.format);
  if (single_pass && fused) {
    // As below, with the fused row: per row the costs, then the path from above (in place in
    // one row of path costs) and the paths along the row, the sums and the decision.
    const std::ptrdiff_t stripes = stripe_count(rows);
    const std::ptrdiff_t ns = std::min<std::ptrdiff_t>(nt, stripes);
    std::atomic<std::ptrdiff_t> next_stripe{0};  // handed out in order, one at a time
    run_bands(ns, [&](std::ptrdiff_t b) {
      const auto c = sz(cols);
      const FusedStripeLayout lay(c, nd, r, ring_images);
      auto* rev = aligned<std::uint16_t>(ws.scratch[sz(b)], lay.total);
      auto* rev8 = reinterpret_cast<std::uint8_t*>(rev);
      auto* raw8 = reinterpret_cast<std::uint8_t*>(rev + lay.raw);
      const std::size_t raw_len = (c + 2) * sz(nd);
      RawRows<std::uint8_t> raw;
      raw.slots = 2 * r + 1;
      for (int i = 0; i < raw.slots; ++i) raw.slot[i] = raw8 + sz(i) * raw_len;
      std::uint8_t* ring = raw8 + sz(raw.slots) * raw_len;
      auto* crow = reinterpret_cast<std::uint8_t*>(rev + lay.crow);
      PairRows src(bk, left, right, rev + lay.pair);
      detail::FusedRowArgs fa = fused_args(rev + lay.fused);
      fa.c = crow;
      fa.lv = reinterpret_cast<std::int16_t*>(rev + lay.lv);
      fa.lvmin = reinterpret_cast<std::int16_t*>(rev + lay.lvmin);
      for (std::ptrdiff_t st = next_stripe++; st < stripes; st = next_stripe++) {
        const std::ptrdiff_t y0 = band(rows, stripes, st), y1 = band(rows, stripes, st + 1);
        for (std::ptrdiff_t y = y0; y < y1; ++y) {
          throw_if_stopped();
          std::uint8_t* raws[3];
          int fresh = -1;
          raw.get(
              rows, r, y, raws,
              [&](std::ptrdiff_t yy, std::uint8_t* out) {
                const std::uint16_t* lrow = src.census(0, yy);
                k.raw_row8_t(lrow, src.census(1, yy), cols, 0, cols, r, nd, p.min_disparity,
                             rev8, out);
              },
              &fresh);
          const std::uint16_t* lrow = src.last(0);  // unread unless fresh >= 0
          const std::uint16_t* rrow = src.last(1);
          if (fresh >= 0) {
            const std::ptrdiff_t yf = std::clamp<std::ptrdiff_t>(y + fresh - r, 0, rows - 1);
            lrow = src.census(0, yf);
            rrow = src.census(1, yf);
          }
          k.box_row8_t(raws, fresh, lrow, rrow, rev8, r, cols, 0, cols, nd, p.min_disparity,
                       cmax, ring, crow);
          fa.g = src.grey8(0, y);
          fa.gprev = y == y0 ? nullptr : src.grey8(0, y - 1);
          fa.disp = disparity.row(y);
          fa.conf = confidence.data ? confidence.row(y) : nullptr;
          k.fused_row_t(fa);
        }
      }
    });
  } else if (single_pass) {
    // paths == 3, one pass: stripes of at most kStripeRows rows (stripe_count), each matched
    // top to bottom by one thread with the path from above restarting at its first row, so
    // the output does not depend on the number of threads; per row, the costs, the path from
    // above, the paths along the row and the decision, all in row buffers.
    const std::ptrdiff_t stripes = stripe_count(rows);
    const std::ptrdiff_t ns = std::min<std::ptrdiff_t>(nt, stripes);
    std::atomic<std::ptrdiff_t> next_stripe{0};  // handed out in order, one at a time
    run_bands(ns, [&](std::ptrdiff_t b) {
      const auto c = sz(cols);
      const auto lsz = sz(ls);
      const PlainStripeLayout lay(c, nd, ls, r, ring_images);
      auto* rev = aligned<std::uint16_t>(ws.scratch[sz(b)], lay.total);
      std::uint16_t* colraw = rev + lay.colraw;
      RawRows<std::uint16_t> raw;
      raw.slots = 2 * r + 1;
      const std::size_t raw_len = (c + 2) * sz(nd);
      for (int i = 0; i < raw.slots; ++i) raw.slot[i] = colraw + sz(i + 1) * raw_len;
      std::uint16_t* total = rev + lay.sums;
      std::uint16_t* rmin = rev + lay.rmin;
      std::uint16_t* rarg = rev + lay.rarg;
      auto* crow = reinterpret_cast<std::uint8_t*>(rev + lay.crow);
      auto* rows16 = reinterpret_cast<std::int16_t*>(rev + lay.rows16);
      const std::size_t n_row = c * lsz;
      std::int16_t* prow[2] = {rows16, rows16 + n_row};
      auto* tmp = reinterpret_cast<std::int16_t*>(rev + lay.tmp);
      auto* winners = reinterpret_cast<std::uint32_t*>(rev + lay.winners);
      PairRows src(bk, left, right, rev + lay.pair);
      for (std::size_t i = 0; i < 2 * c; ++i) {
        rows16[i * lsz] = detail::kSentinel;
        rows16[i * lsz + sz(nd) + 1] = detail::kSentinel;
      }
      for (std::ptrdiff_t st = next_stripe++; st < stripes; st = next_stripe++) {
        const std::ptrdiff_t y0 = band(rows, stripes, st), y1 = band(rows, stripes, st + 1);
        int flip = 0;
        for (std::ptrdiff_t y = y0; y < y1; ++y) {
          throw_if_stopped();
          std::uint16_t* raws[3];
          raw.get(rows, r, y, raws, [&](std::ptrdiff_t yy, std::uint16_t* out) {
            const std::uint16_t* lrow = src.census(0, yy);
            k.raw_row(lrow, src.census(1, yy), cols, 0, cols, r, nd, p.min_disparity, rev, out);
          });
          k.box_row(raws, r, cols, 0, cols, nd, p.min_disparity, cmax, colraw, crow);
          const bool first = y == y0;
          const std::uint8_t* g = src.grey8(0, y);
          k.path_row(pp, crow, g, first ? nullptr : src.grey8(0, y - 1),
                     first ? nullptr : prow[1 - flip], prow[flip], cols, 0, cols, 0, total, true);
          k.horizontal_row(pp, crow, g, cols, total, tmp);
          k.decide_row(da, total, disparity.row(y), confidence.data ? confidence.row(y) : nullptr,
                       rmin, rarg, winners);
          flip = 1 - flip;
        }
      }
    });
  } else {
    const bool concurrent = concurrent_passes(p.paths, threads);
    const bool in_passes = finish_in_passes(p.paths, threads);  // step 2 done in step 1
    // Step 2 on row y, with a thread's scratch `at` (n_finish uint16 units): the horizontal
    // paths added to a copy of the row's sums, then the winner, checks and sub-pixel step on
    // that copy.
    const auto c = sz(cols);
    const std::size_t n_finish = row_scratch_n16(c, nd, ls, fused);
    auto finish_row = [&](std::uint16_t* at, std::ptrdiff_t y) {
      if (fused) {
        detail::FusedRowArgs fa = fused_args(at);
        fa.c = costs + sz(y) * n_col;
        fa.base = sums + sz(y) * n_col;
        fa.g = pgrey + y * cols;
        fa.disp = disparity.row(y);
        fa.conf = confidence.data ? confidence.row(y) : nullptr;
        k.fused_row(fa);
        return;
      }
      std::uint16_t* total = at;
      std::uint16_t* rmin = total + n_col;
      std::uint16_t* rarg = rmin + c;
      auto* tmp = reinterpret_cast<std::int16_t*>(rarg + c);
      auto* winners = reinterpret_cast<std::uint32_t*>(
          (reinterpret_cast<std::uintptr_t>(tmp + 2 * ls) + 3) & ~std::uintptr_t{3});
      std::memcpy(total, sums + sz(y) * n_col, n_col * sizeof(std::uint16_t));
      k.horizontal_row(pp, costs + sz(y) * n_col, pgrey + y * cols, cols, total, tmp);
      k.decide_row(da, total, disparity.row(y), confidence.data ? confidence.row(y) : nullptr,
                   rmin, rarg, winners);
    };
    // 1. Downward, then upward: the costs (computed on the way down) and the vertical and
    //    diagonal paths; the columns are split between the threads, which meet at every row
    //    when the diagonals read the previous row across band edges. The way down writes the
    //    sums, the way up adds to them. On two threads the two ways run at once instead, one
    //    thread each (concurrent_passes), and each does step 2 on the rows it completes.
    {
      const int nv = vertical_paths(p.paths);
      const std::ptrdiff_t nb = pass_bands(p.paths, threads, cols);
      if (ws.scratch.size() < static_cast<std::size_t>(nb)) {
        ws.scratch.resize(static_cast<std::size_t>(nb));
      }
      // The path rows, this row's and the previous row's for each path: one set, or one per
      // pass when the passes run at once.
      const auto row_len = static_cast<std::size_t>(cols) * static_cast<std::size_t>(ls);
      const std::size_t n_prow = 2 * static_cast<std::size_t>(nv) * row_len;
      const std::size_t n_sets = concurrent ? 2 : 1;
      auto* prow_sets = aligned<std::int16_t>(ws.path_rows, n_sets * n_prow);
      for (std::size_t i = 0; i < n_sets * 2 * sz(nv) * sz(cols); ++i) {
        prow_sets[i * sz(ls)] = detail::kSentinel;
        prow_sets[i * sz(ls) + sz(nd) + 1] = detail::kSentinel;
      }
      const int dxs[3] = {0, 1, -1};
      // Each band's scratch is sized here, before the bands start: an allocation that failed
      // inside a band would leave the other bands waiting at the barrier for ever.
      const std::size_t n_rev = sz(cols) + sz(nd) + 32;
      // A band's columns: a share of them, or all of them for a pass of its own.
      auto band_x0 = [&](std::ptrdiff_t b) { return concurrent ? 0 : band(cols, nb, b); };
      auto band_x1 = [&](std::ptrdiff_t b) { return concurrent ? cols : band(cols, nb, b + 1); };
      // A band's rows of raw costs: its columns and one either side, nd each.
      auto raw_len = [&](std::ptrdiff_t b) { return sz(band_x1(b) - band_x0(b) + 2) * sz(nd); };
      auto band_scratch = [&](std::ptrdiff_t b) {
        return aligned<std::uint16_t>(ws.scratch[sz(b)], n_rev + 4 * raw_len(b) + sz(nd));
      };
      for (std::ptrdiff_t b = 0; b < nb; ++b) band_scratch(b);
      // Band b's way through the rows, downward (dy = 1) or upward, with the path rows prow.
      // first(y): whether this band is the first to reach row y, then computing the row's
      // costs and storing its sums, which the other pass reads and adds to; it may wait for
      // the other pass. row_done(i) after the band's i-th row.
      auto pass_rows = [&](std::ptrdiff_t b, int dy, std::int16_t* prow, auto&& first,
                           auto&& row_done) {
        const std::ptrdiff_t x0 = band_x0(b), x1 = band_x1(b);
        const std::size_t n_raw = raw_len(b);
        std::uint16_t* rev = band_scratch(b);  // sized already: no allocation here
        std::uint16_t* colraw = rev + n_rev;
        RawRows<std::uint16_t> raw;
        RawRows<std::uint8_t> raw8;  // with the 8-bit cost kernels
        for (int j = 0; j < 3; ++j) {
          raw.slot[j] = colraw + static_cast<std::size_t>(j + 1) * n_raw;
          raw8.slot[j] = reinterpret_cast<std::uint8_t*>(colraw) + j * n_raw;
        }
        std::uint8_t* ring = reinterpret_cast<std::uint8_t*>(colraw) + 3 * n_raw;
        int flip = 0;
        for (std::ptrdiff_t i = 0; i < rows; ++i) {
          const std::ptrdiff_t y = dy > 0 ? i : rows - 1 - i;
          const std::ptrdiff_t yq = y - dy;
          std::uint8_t* crow = costs + static_cast<std::size_t>(y) * n_col;
          const bool store = first(y);
          if (store) {
            if (k.raw_row8) {
              std::uint8_t* raws[3];
              int fresh = -1;
              auto* rev8 = reinterpret_cast<std::uint8_t*>(rev);
              raw8.get(
                  rows, r, y, raws,
                  [&](std::ptrdiff_t yy, std::uint8_t* out) {
                    k.raw_row8(lcen + yy * cols, rcen + yy * cols, cols, x0, x1, r, nd,
                               p.min_disparity, rev8, out);
                  },
                  &fresh);
              const std::ptrdiff_t yf =
                  fresh < 0 ? 0 : std::clamp<std::ptrdiff_t>(y + fresh - r, 0, rows - 1);
              k.box_row8(raws, fresh, lcen + yf * cols, rcen + yf * cols, rev8, r, cols, x0, x1,
                         nd, p.min_disparity, cmax, ring, crow);
            } else {
              std::uint16_t* raws[3];
              raw.get(rows, r, y, raws, [&](std::ptrdiff_t yy, std::uint16_t* out) {
                k.raw_row(lcen + yy * cols, rcen + yy * cols, cols, x0, x1, r, nd,
                          p.min_disparity, rev, out);
              });
              k.box_row(raws, r, cols, x0, x1, nd, p.min_disparity, cmax, colraw, crow);
            }
          }
          if (fused) {
            std::int16_t* cur[3];
            const std::int16_t* prev[3];
            for (int v = 0; v < nv; ++v) {
              const auto pair = 2 * static_cast<std::size_t>(v);
              cur[v] = prow + (pair + static_cast<std::size_t>(flip)) * row_len;
              prev[v] = prow + (pair + static_cast<std::size_t>(1 - flip)) * row_len;
            }
            k.path_rows(pp, crow, pgrey + y * cols, i > 0 ? pgrey + yq * cols : nullptr,
                        i > 0 ? prev : nullptr, cur, nv, dxs, cols, x0, x1,
                        sums + static_cast<std::size_t>(y) * n_col, store);
          }
          for (int v = 0; v < nv && !fused; ++v) {
            const auto pair = 2 * static_cast<std::size_t>(v);
            std::int16_t* cur = prow + (pair + static_cast<std::size_t>(flip)) * row_len;
            std::int16_t* prev = prow + (pair + static_cast<std::size_t>(1 - flip)) * row_len;
            k.path_row(pp, crow, pgrey + y * cols, i > 0 ? pgrey + yq * cols : nullptr,
                       i > 0 ? prev : nullptr, cur, cols, x0, x1, dxs[v],
                       sums + static_cast<std::size_t>(y) * n_col, store && v == 0);
          }
          flip = 1 - flip;
          row_done(i);
        }
      };
      if (concurrent) {
        // The two passes at once, the downward one on band 0's thread and the upward one on
        // band 1's, each over whole rows with its own path rows. Each row's costs and sums
        // come from the pass that reaches it first: the downward one above the middle row m,
        // the upward one from m down. It stores the sums; the other, once the first has
        // finished the row, reads its costs and adds to them (the same integers in either
        // order). Each pass waits for the other once, where it crosses the middle, rather than
        // at a barrier at every row; the results are the same.
        const std::ptrdiff_t m = rows / 2;
        std::atomic<std::ptrdiff_t> done[2];  // the rows each pass has finished
        done[0].store(0);
        done[1].store(0);
        std::atomic<bool> quit{false};  // a pass stopped: the other must not wait for it
        if (ws.finish.size() < 2) ws.finish.resize(2);
        for (std::size_t b = 0; b < 2; ++b) aligned<std::uint16_t>(ws.finish[b], n_finish);
        run_bands_together(2, [&](std::ptrdiff_t b) {
          const int dy = b == 0 ? 1 : -1;
          const std::atomic<std::ptrdiff_t>& other = done[1 - b];
          // Sized above: no allocation here.
          std::uint16_t* fin = aligned<std::uint16_t>(ws.finish[sz(b)], n_finish);
          auto first = [&](std::ptrdiff_t y) {
            if (dy > 0 ? y < m : y >= m) return true;
            // The other pass has finished row y when it has done `need` rows.
            const std::ptrdiff_t need = dy > 0 ? rows - y : y + 1;
            auto ready = [&] {
              return other.load(std::memory_order_acquire) >= need ||
                     quit.load(std::memory_order_relaxed);
            };
            while (!spin_until(ready, kPassWait)) throw_if_stopped();
            if (quit.load(std::memory_order_relaxed)) throw Stopped();
            return false;
          };
          try {
            pass_rows(b, dy, prow_sets + sz(b) * n_prow, first, [&](std::ptrdiff_t i) {
              done[b].store(i + 1, std::memory_order_release);
              // The second pass over a row completes its sums: step 2 on it at once, while
              // its sums and costs are in this thread's cache.
              const std::ptrdiff_t y = dy > 0 ? i : rows - 1 - i;
              if (dy > 0 ? y >= m : y < m) finish_row(fin, y);
              throw_if_stopped();
            });
          } catch (...) {
            quit.store(true, std::memory_order_relaxed);
            throw;
          }
        });
      } else {
        // One thread: the way up finishes each row as it completes it (as the passes at once
        // do), while its sums are in the cache: in one process on Zen 4, 0.86-1.01 of the time
        // of a step 2 of its own, paths 4 and 8 (bench/README, twenty-seventh round).
        std::uint16_t* fin = nullptr;
        if (in_passes) {
          if (ws.finish.empty()) ws.finish.resize(1);
          fin = aligned<std::uint16_t>(ws.finish[0], n_finish);
        }
        for (int dy : {1, -1}) {
          Barrier barrier(nb);
          // The bands meet at the barrier: each needs its own thread, all at once.
          run_bands_together(nb, [&](std::ptrdiff_t b) {
            pass_rows(
                b, dy, prow_sets, [&](std::ptrdiff_t) { return dy > 0; },
                [&](std::ptrdiff_t i) {
                  if (fin && dy < 0) finish_row(fin, rows - 1 - i);
                  // With a barrier the bands stop together, at the row its last arrival
                  // decides.
                  if (nv > 1 && nb > 1) {
                    if (barrier.wait()) throw Stopped();
                  } else {
                    throw_if_stopped();
                  }
                });
          });
        }
      }
    }
  
    // 2. Row by row (the rows split between the threads; done in step 1 when the passes ran
    //    at once or on one thread): finish_row.
    if (!in_passes) {
      run_bands(nt, [&](std::ptrdiff_t b) {
        std::uint16_t* at = aligned<std::uint16_t>(ws.scratch[sz(b)], n_finish);
        for (std::ptrdiff_t y = band(rows, nt, b); y < band(rows, nt, b + 1); ++y) {
          throw_if_stopped();
          finish_row(at, y);
        }
      });
    }
  }

  const bool speckle = p.speckle_window > 0;
  const float rf = detail::speckle_range_f(p.speckle_range);
  if (speckle && ws.speckle.size() < unt) ws.speckle.resize(unt);
  // With the median, each band labels its rows for the speckle filter (step 5) as the median
  // leaves them, still in the cache, rather than in a pass of its own: in one process,
  // 0.91-1.01 of the time of paths=3 on the shared scenes, median 0.99 with AVX2 and 0.997
  // with AVX-512 (bench/README, twenty-sixth round).
  const bool label_in_median = p.median && speckle;

  // 4. The 3x3 median of the valid disparities (the lower median; NaN stays NaN), in place:
  //    each band of rows keeps a copy of the rows it still reads as they were; the rows on
  //    either side of each boundary between bands are copied first.
  if (p.median) {
    const auto c = sz(cols);
    ws.median_edges.resize(2 * sz(nt - 1) * c);
    auto edge = [&](std::ptrdiff_t b, int side) {  // boundary b (1 .. nt - 1): row start - 1, start
      return ws.median_edges.data() + (2 * sz(b - 1) + sz(side)) * c;
    };
    for (std::ptrdiff_t b = 1; b < nt; ++b) {
      const std::ptrdiff_t y = band(rows, nt, b);
      std::memcpy(edge(b, 0), disparity.row(y - 1), c * sizeof(float));
      std::memcpy(edge(b, 1), disparity.row(y), c * sizeof(float));
    }
    run_bands(nt, [&](std::ptrdiff_t b) {
      auto* kept = aligned<float>(ws.scratch[sz(b)], median_n16(c) / 2);
      float* orig[2] = {kept, kept + r64(2 * c) / 2};
      auto* flags = reinterpret_cast<std::uint8_t*>(kept + r64(2 * c));
      const std::ptrdiff_t y0 = band(rows, nt, b), y1 = band(rows, nt, b + 1);
      const float* up = b > 0 ? edge(b, 0) : nullptr;
      detail::SpeckleBand* lab = label_in_median ? &ws.speckle[sz(b)] : nullptr;
      if (lab) detail::speckle_begin(y0, cols, *lab);
      for (std::ptrdiff_t y = y0; y < y1; ++y) {
        float* mid = orig[y % 2];
        std::memcpy(mid, disparity.row(y), c * sizeof(float));
        const float* down = y + 1 < y1 ? disparity.row(y + 1)
                            : y + 1 < rows ? edge(b + 1, 1)
                                           : nullptr;
        k.median_row(up, mid, down, disparity.row(y), flags, cols);
        if (lab) detail::speckle_rows(bk, disparity, y + 1, rf, *lab);
        up = mid;
      }
      if (lab) detail::speckle_end(p.speckle_window, *lab);
    });
  }

  // 5. The speckle filter (the block matcher's): the bands' labels (here when step 4 has not
  //    made them), joined, and the small regions cleared.
  if (speckle) {
    if (!label_in_median) {
      run_bands(nt, [&](std::ptrdiff_t b) {
        detail::speckle_band(bk, disparity, band(rows, nt, b), band(rows, nt, b + 1), rf,
                             p.speckle_window, ws.speckle[static_cast<std::size_t>(b)]);
      });
    }
    std::vector<detail::SpeckleBand*> labels;
    std::vector<std::ptrdiff_t> starts;
    for (std::ptrdiff_t b = 0; b < nt; ++b) {
      labels.push_back(&ws.speckle[static_cast<std::size_t>(b)]);
      starts.push_back(band(rows, nt, b));
    }
    starts.push_back(rows);
    detail::speckle_finish(bk, disparity, confidence, p.speckle_window, rf, labels, starts,
                           ws.speckle_join, static_cast<int>(nt));
  }
}

}  // namespace stereodepth
