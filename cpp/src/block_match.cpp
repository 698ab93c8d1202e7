#include "stereodepth/block_match.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "block_match_kernels.hpp"
#include "module_support.hpp"
#include "speckle.hpp"
#include "stereodepth/parallel.hpp"

#if defined(__SANITIZE_ADDRESS__)
#include <sanitizer/asan_interface.h>
#define STEREODEPTH_POISON(p, n) ASAN_POISON_MEMORY_REGION(p, n)
#define STEREODEPTH_UNPOISON(p, n) ASAN_UNPOISON_MEMORY_REGION(p, n)
#else
#define STEREODEPTH_POISON(p, n) ((void)(p), (void)(n))
#define STEREODEPTH_UNPOISON(p, n) ((void)(p), (void)(n))
#endif

namespace stereodepth {
namespace {

using detail::SpeckleBand;
using detail::SpeckleRun;
using detail::speckle_band;
using detail::speckle_finish;
using detail::speckle_range_f;

const detail::BlockMatchKernels& kernels_for(Isa isa) {
  return STEREODEPTH_KERNELS_FOR(isa, block_match_kernels);
}

using detail::fail;

const char* cost_name(MatchCost cost) { return cost == MatchCost::kCensus ? "census" : "sad"; }

// Grow-only byte storage, left uninitialised (every piece is written before it is read):
// std::vector would zero it, page by page, on every growth.
struct ByteBuffer {
  std::unique_ptr<std::uint8_t[]> bytes;
  std::size_t size = 0;
  void grow(std::size_t n) {
    if (n <= size) return;
    bytes.reset();
    bytes.reset(new std::uint8_t[n]);
    size = n;
  }
};

// 64-byte aligned pieces carved out of one byte buffer, with a 64-byte gap after each piece
// that AddressSanitizer builds poison, so an overrun of any piece is caught.
class Arena {
 public:
  explicit Arena(ByteBuffer* storage) : storage_(storage) {}
  // First pass: count; second pass (after reserve()): hand out pointers.
  template <typename T>
  T* take(std::size_t count) {
    const std::size_t bytes = count * sizeof(T);
    const std::size_t step = ((bytes + 63) & ~std::size_t{63}) + 64;
    T* p = nullptr;
    if (base_) {
      p = reinterpret_cast<T*>(base_ + used_);
      STEREODEPTH_POISON(base_ + used_ + bytes, step - bytes);
    }
    used_ += step;
    return p;
  }
  void reserve() {
    STEREODEPTH_UNPOISON(storage_->bytes.get(), storage_->size);
    storage_->grow(used_ + 64);
    const auto addr = reinterpret_cast<std::uintptr_t>(storage_->bytes.get());
    base_ = storage_->bytes.get() + ((64 - addr % 64) % 64);
    used_ = 0;
  }

 private:
  ByteBuffer* storage_;
  std::uint8_t* base_ = nullptr;
  std::size_t used_ = 0;
};

detail::BandScratch carve_band(Arena& arena, std::ptrdiff_t cols, int dp, std::size_t feat_size,
                               int lanes, int radius) {
  const auto c = static_cast<std::size_t>(cols);
  const std::size_t row = c + static_cast<std::size_t>(dp) + detail::kRowPad;
  detail::BandScratch s{};
  s.colsum = arena.take<std::uint16_t>(c * static_cast<std::size_t>(dp));
  s.acc = arena.take<std::uint16_t>(static_cast<std::size_t>(dp));
  s.rpad_in = arena.take<std::uint8_t>(row * feat_size);
  s.rpad_out = arena.take<std::uint8_t>(row * feat_size);
  const std::size_t quad = feat_size == 4 ? row * detail::regrouped_bytes(lanes) : 0;
  s.quad_in = arena.take<std::uint8_t>(quad);
  s.quad_out = arena.take<std::uint8_t>(quad);
  s.rmin = arena.take<std::uint16_t>(row);
  s.rarg = arena.take<std::uint16_t>(row);
  s.texcol = arena.take<std::uint32_t>(c);
  s.records = arena.take<detail::WinnerRecord>(c + 16);
  s.recent = arena.take<std::uint16_t>(detail::recent_size(lanes, dp));
  const std::size_t ring = detail::cost_ring_size(lanes, feat_size, radius, cols, dp);
  s.ring = arena.take<std::uint8_t>(ring);
  if (ring == 0) s.ring = nullptr;
  return s;
}

}  // namespace

int pixel_cost_max(MatchCost cost) {
  return cost == MatchCost::kCensus ? kCensusCostMax : kSadCostMax;
}

int max_block_size(MatchCost cost) {
  // The largest odd size whose block sum stays below 0xFFFF (the kernels' "no cost" value).
  int b = 3;
  while ((b + 2) * (b + 2) * pixel_cost_max(cost) < 0xFFFF) b += 2;
  return b;
}

void validate(const BlockMatchParams& p) {
  if (p.cost != MatchCost::kCensus && p.cost != MatchCost::kSad) {
    fail("cost must be census or sad", static_cast<int>(p.cost));
  }
  if (p.num_disparities < 1 || p.num_disparities > kMaxNumDisparities) {
    fail("num_disparities must be an integer in [1, " + std::to_string(kMaxNumDisparities) + "]",
         p.num_disparities);
  }
  if (p.min_disparity < -kMaxAbsMinDisparity || p.min_disparity > kMaxAbsMinDisparity) {
    fail("min_disparity must be an integer in [-" + std::to_string(kMaxAbsMinDisparity) + ", " +
             std::to_string(kMaxAbsMinDisparity) + "]",
         p.min_disparity);
  }
  const int bmax = max_block_size(p.cost);
  if (p.block_size < 3 || p.block_size % 2 == 0 || p.block_size > bmax) {
    fail("block_size must be an odd integer in [3, " + std::to_string(bmax) + "] for cost " +
             cost_name(p.cost) + " (block costs are summed in 16 bits)",
         p.block_size);
  }
  if (p.subpixel != SubpixelFit::kNone && p.subpixel != SubpixelFit::kParabola &&
      p.subpixel != SubpixelFit::kEquiangular) {
    fail("subpixel must be none, parabola or equiangular", static_cast<int>(p.subpixel));
  }
  if (!(std::isfinite(p.uniqueness_ratio) && p.uniqueness_ratio >= 0)) {
    fail("uniqueness_ratio must be a finite number >= 0", p.uniqueness_ratio);
  }
  if (!(std::isfinite(p.texture_threshold) && p.texture_threshold >= 0)) {
    fail("texture_threshold must be a finite number >= 0", p.texture_threshold);
  }
  if (std::isnan(p.lr_max_diff) || std::isinf(p.lr_max_diff)) {
    fail("lr_max_diff must be a finite number (negative: off)", p.lr_max_diff);
  }
  if (p.speckle_window < 0) fail("speckle_window must be an integer >= 0", p.speckle_window);
  if (!(std::isfinite(p.speckle_range) && p.speckle_range >= 0)) {
    fail("speckle_range must be a finite number >= 0", p.speckle_range);
  }
}

struct BlockMatcher::Workspace {
  ~Workspace() {
    for (auto& w : workers) STEREODEPTH_UNPOISON(w.bytes.get(), w.size);
  }

  std::vector<ByteBuffer> workers;                // per worker: scratch, grey, feature rows
  std::vector<std::vector<SpeckleBand>> speckle;  // speckle labellings, per worker
  detail::SpeckleJoin speckle_join;

  std::size_t bytes() const {
    std::size_t n = 0;
    for (const auto& w : workers) n += w.size;
    return n;
  }

  // Workspaces outlive their matchers: a matcher made for one call (block_match) takes one
  // that an earlier matcher released, rather than allocating its buffers and faulting them
  // in again. Up to kPooled released workspaces of at most kPooledBytes each are kept.
  static constexpr std::size_t kPooled = 4;
  static constexpr std::size_t kPooledBytes = std::size_t{64} << 20;
  // Never destroyed, so a matcher released during static destruction still finds them.
  static std::mutex& pool_mutex() {
    static auto* m = new std::mutex;
    return *m;
  }
  static std::vector<std::unique_ptr<Workspace>>& pool() {
    static auto* p = new std::vector<std::unique_ptr<Workspace>>;
    return *p;
  }
  static std::unique_ptr<Workspace> acquire() {
    {
      std::lock_guard<std::mutex> lock(pool_mutex());
      auto& p = pool();
      if (!p.empty()) {
        std::unique_ptr<Workspace> ws = std::move(p.back());
        p.pop_back();
        return ws;
      }
    }
    return std::make_unique<Workspace>();
  }
  static void release(std::unique_ptr<Workspace> ws) {
    if (!ws || ws->bytes() > kPooledBytes) return;
    std::lock_guard<std::mutex> lock(pool_mutex());
    auto& p = pool();
    if (p.size() < kPooled) p.push_back(std::move(ws));
  }
};

BlockMatcher::BlockMatcher(const BlockMatchParams& params, int threads, Isa isa)
    : params_(params), threads_(resolve_threads(threads)), isa_(isa),
      workspace_(Workspace::acquire()) {
  validate(params_);
  if (params_.uniqueness_ratio > 0) {
    // The uniqueness check, second * 100 > best * (100 + ratio), as a table of the least
    // passing second-best cost per winning cost (the same double arithmetic), capped at
    // 0xFFFF, above every block cost.
    uniqueness_factor_ = 100.0 + params_.uniqueness_ratio;
    const int max_cost = params_.block_size * params_.block_size * pixel_cost_max(params_.cost);
    // Then the same thresholds as the AVX2 first pass compares them with costs << 4.
    const auto n = static_cast<std::size_t>(max_cost) + 1;
    unique_min_.resize(2 * n);
    for (int b = 0; b <= max_cost; ++b) {
      const double bound = static_cast<double>(b) * uniqueness_factor_;
      double s = 65535.0;  // the cap: no second-best cost passes (s * 100 > bound needs more)
      if (bound < 65535.0 * 100.0) {
        // Here s < 2^16, so s + 1 != s: the loops end. Beyond, s += 1.0 could not change a
        // large s (a ratio of 1e20 hung the constructor).
        s = std::floor(bound / 100.0);
        while (s > 0 && s * 100.0 > bound) s -= 1.0;
        while (!(s * 100.0 > bound)) s += 1.0;
      }
      const auto t = static_cast<std::uint32_t>(std::min(s, 65535.0));
      unique_min_[static_cast<std::size_t>(b)] = t | (t << 16);  // twice: see the kernels
      // Capped at 0x7FFF when every block cost << 4 is below it: the census kernels then
      // compare with signed 16-bit lanes (winners_avx2, low_signed).
      const std::uint32_t cap = max_cost * 16 < 0x7FFF ? 0x7FFFu : 0xFFFFu;
      const std::uint32_t t4 = std::min<std::uint32_t>(t << 4, cap);
      unique_min_[n + static_cast<std::size_t>(b)] = t4 | (t4 << 16);
    }
  }
}

BlockMatcher::~BlockMatcher() { Workspace::release(std::move(workspace_)); }

void BlockMatcher::compute(const StereoImage& left, const StereoImage& right,
                           const ImageView<float>& disparity, const ImageView<float>& confidence) {
  const BlockMatchParams& p = params_;
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
  if (cols > (std::numeric_limits<std::int32_t>::max() >> 2) ||
      rows > (std::numeric_limits<std::int32_t>::max() >> 2) ||
      static_cast<double>(rows) * static_cast<double>(cols) >= 2147483647.0) {
    throw std::invalid_argument("the images must have fewer than 2^31 pixels");
  }

  const detail::BlockMatchKernels& k = kernels_for(isa_);
  const int dp = (p.num_disparities + k.lanes - 1) / k.lanes * k.lanes;
  // The width limit rounds num_disparities up to the widest kernels' 16 lanes on every ISA,
  // so that a pair the AVX2 and AVX-512 builds refuse is refused by the baseline too (it
  // rounded up to its own 8 lanes; stereodepth.matching states the rule and checks it first).
  constexpr int kLimitLanes = 16;
  static_assert(kLimitLanes % 8 == 0, "a multiple of every kernel's lanes");
  const std::int64_t dp16 = (p.num_disparities + kLimitLanes - 1) / kLimitLanes * kLimitLanes;
  if (static_cast<std::int64_t>(cols) * dp16 >= (std::int64_t{1} << 30)) {
    throw std::invalid_argument(
        "the image width times num_disparities must be below 2^30 with num_disparities rounded "
        "up to a multiple of 16, got " +
        std::to_string(cols) + " x " + std::to_string(p.num_disparities) + " (" +
        std::to_string(cols) + " x " + std::to_string(dp16) + " = " +
        std::to_string(static_cast<std::int64_t>(cols) * dp16) + ")");
  }

  std::lock_guard<std::mutex> lock(mutex_);
  Workspace& ws = *workspace_;
  const int r = p.block_size / 2;
  const bool sixteen = left.format == PixelFormat::kGrey16;
  const bool colour = is_colour(left.format);
  const bool bgr = left.format == PixelFormat::kBgr8;
  const bool census = p.cost == MatchCost::kCensus;
  const bool texture_on = p.texture_threshold > 0;
  const std::size_t feat_size = census ? 4 : 1;

  // Workers: one per thread, but not more than the rows can feed (a band's set-up reads the
  // block's rows above and below it).
  const std::ptrdiff_t min_band = std::max<std::ptrdiff_t>(16, 2 * p.block_size);
  const auto nw = static_cast<std::size_t>(
      std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(threads_, rows / min_band)));
  auto first_row = [&](std::size_t w) { return rows * static_cast<std::ptrdiff_t>(w) /
                                               static_cast<std::ptrdiff_t>(nw); };

  // Each worker starts with an equal band of rows: it computes the feature rows the band
  // needs (the band and the block's reach above and below) into its own memory, then matches.
  struct Worker {
    std::ptrdiff_t y0, y1;  // its band
    std::ptrdiff_t f0, f1;  // feature rows: the band and the block's reach
    std::ptrdiff_t g0, g1;  // grey rows: the feature rows and the census window's reach
    detail::BandScratch scratch;
    std::uint8_t* grey[2];  // colour only: grey rows g0..g1
    std::uint8_t* feat[2];  // feature rows f0..f1, left and right
    std::uint8_t* texture;  // texture rows f0..f1, or null
  };
  std::vector<Worker> workers(nw);
  if (ws.workers.size() < nw) ws.workers.resize(nw);
  for (std::size_t w = 0; w < nw; ++w) {
    Worker& wk = workers[w];
    wk.y0 = first_row(w);
    wk.y1 = first_row(w + 1);
    wk.f0 = std::max<std::ptrdiff_t>(0, wk.y0 - r);
    wk.f1 = std::min<std::ptrdiff_t>(rows, wk.y1 + r);
    wk.g0 = std::max<std::ptrdiff_t>(0, wk.f0 - 2);
    wk.g1 = std::min<std::ptrdiff_t>(rows, wk.f1 + 2);
    const auto fpix = static_cast<std::size_t>((wk.f1 - wk.f0) * cols);
    const auto gpix = static_cast<std::size_t>((wk.g1 - wk.g0) * cols);
    Arena arena(&ws.workers[w]);
    for (int pass = 0; pass < 2; ++pass) {
      wk.scratch = carve_band(arena, cols, dp, feat_size, k.lanes, p.block_size / 2);
      wk.grey[0] = arena.take<std::uint8_t>(colour ? gpix : 0);
      wk.grey[1] = arena.take<std::uint8_t>(colour ? gpix : 0);
      wk.feat[0] = arena.take<std::uint8_t>(fpix * feat_size);
      wk.feat[1] = arena.take<std::uint8_t>(fpix * feat_size);
      wk.texture = arena.take<std::uint8_t>(texture_on ? fpix : 0);
      if (pass == 0) arena.reserve();
    }
    if (!texture_on) wk.texture = nullptr;
  }

  // 1. A band's features: census codes or prefiltered pixels, and the texture; colour rows are
  //    turned into grey first.
  const StereoImage* images[2] = {&left, &right};
  auto band_features = [&](Worker& wk) {
    for (int im = 0; im < 2; ++im) {
      const StereoImage& src = *images[im];
      const void* base = src.data;
      std::ptrdiff_t stride = sixteen ? src.row_stride / 2 : src.row_stride, row0 = 0;
      if (colour) {
        for (std::ptrdiff_t y = wk.g0; y < wk.g1; ++y) {
          k.rgb_to_grey(static_cast<const std::uint8_t*>(src.data) + y * src.row_stride,
                        wk.grey[im] + (y - wk.g0) * cols, cols, bgr);
        }
        base = wk.grey[im];
        stride = cols;
        row0 = wk.g0;
      }
      auto grey_row = [&](std::ptrdiff_t y) -> const void* {
        const std::ptrdiff_t off = (std::clamp<std::ptrdiff_t>(y, 0, rows - 1) - row0) * stride;
        if (sixteen) return static_cast<const std::uint16_t*>(base) + off;
        return static_cast<const std::uint8_t*>(base) + off;
      };
      for (std::ptrdiff_t y = wk.f0; y < wk.f1; ++y) {
        const std::ptrdiff_t at = (y - wk.f0) * cols;
        if (census) {
          const void* r5[5];
          for (int i = 0; i < 5; ++i) r5[i] = grey_row(y + i - 2);
          auto* out = reinterpret_cast<std::uint32_t*>(wk.feat[im]) + at;
          if (sixteen) {
            k.census_row16(reinterpret_cast<const std::uint16_t* const*>(r5), out, cols);
          } else {
            k.census_row8(reinterpret_cast<const std::uint8_t* const*>(r5), out, cols);
          }
        }
        std::uint8_t* pre = census ? nullptr : wk.feat[im] + at;
        std::uint8_t* tex = im == 0 && wk.texture ? wk.texture + at : nullptr;
        if (pre || tex) {
          const void* r3[3];
          for (int i = 0; i < 3; ++i) r3[i] = grey_row(y + i - 1);
          if (sixteen) {
            k.sobel_row16(reinterpret_cast<const std::uint16_t* const*>(r3), pre, tex, cols);
          } else {
            k.sobel_row8(reinterpret_cast<const std::uint8_t* const*>(r3), pre, tex, cols);
          }
        }
      }
    }
  };

  detail::MatchArgs common{};
  common.cost = p.cost;
  common.feat_stride = cols;
  common.texture_stride = cols;
  common.rows = rows;
  common.cols = cols;
  common.min_d = p.min_disparity;
  common.num_d = p.num_disparities;
  common.dp = dp;
  common.radius = r;
  common.subpixel = p.subpixel;
  common.uniqueness_factor = uniqueness_factor_;
  common.unique_min = unique_min_.empty() ? nullptr : unique_min_.data();
  common.unique_min_shifted =
      unique_min_.empty() ? nullptr : unique_min_.data() + unique_min_.size() / 2;
  common.texture_sum_min = p.texture_threshold * static_cast<double>(p.block_size * p.block_size);
  common.lr_max_diff = p.lr_max_diff;
  common.clip_border = p.clip_border;
  common.disp = disparity.data;
  common.disp_stride = disparity.row_stride;
  common.conf = confidence.data;
  common.conf_stride = confidence.row_stride;

  // 2. Matching, with work stealing. A worker takes its band's rows a few at a time from the
  //    front of its range; once its range is empty it takes the back half of the largest
  //    remaining range among the workers whose features are ready, reading the rows'
  //    features from the band that computed them. A range is one atomic word
  //    (first row << 32 | end row), so a row is matched exactly once; rows come out the same
  //    however they are shared, only the set-up of a stolen piece costs extra.
  //    Each contiguous piece a worker matches is a segment, labelled for the speckle filter.
  const bool speckle = p.speckle_window > 0;
  const float speckle_rf = speckle_range_f(p.speckle_range);
  // Rows claimed at a time, and the least a thief takes. A stolen piece starts with the
  // block-column sums of block_size rows of pixel costs, each about a third of a row's work,
  // so taking half of R rows pays once R / 2 exceeds block_size / 3 rows. The rows a worker
  // cannot give away (its claimed chunk, and a remainder below twice min_steal) are what one
  // thread may still be matching while the other waits at the end: with 4-row chunks and
  // min_steal max(8, 2 * block_size) that wait was 5-13 % of a call on 2 threads (Art,
  // Cones, KITTI, Intel), with 2 and block_size / 3 it was 1.5-5 %.
  constexpr std::ptrdiff_t kChunk = 2;
  const std::ptrdiff_t min_steal = std::max<std::ptrdiff_t>(2, (p.block_size + 2) / 3);
  std::vector<std::atomic<std::uint64_t>> ranges(nw);
  std::vector<std::atomic<std::size_t>> owner(nw);  // whose features a range's rows use
  std::vector<std::atomic<bool>> ready(nw);          // a band's features are complete
  auto pack = [](std::ptrdiff_t begin, std::ptrdiff_t end) {
    return (static_cast<std::uint64_t>(begin) << 32) | static_cast<std::uint64_t>(end);
  };
  for (std::size_t w = 0; w < nw; ++w) {
    ranges[w].store(pack(workers[w].y0, workers[w].y1));
    owner[w].store(w);
    ready[w].store(false);
  }
  struct Segment {
    std::ptrdiff_t y0, y1;
    std::size_t worker, label;  // the worker's speckle labelling, index in its pool
  };
  std::vector<std::vector<Segment>> segments(nw);
  if (ws.speckle.size() < nw) ws.speckle.resize(nw);
  auto run_worker = [&](std::size_t w) {
    band_features(workers[w]);
    ready[w].store(true);
    std::ptrdiff_t seg0 = -1, seg1 = -1;  // the current segment
    // The current segment's speckle labelling: its rows are labelled as they are matched
    // (still in the cache), and closing the segment only sizes its regions. Labelled whole at
    // the close, a worker's last segment was work left after its last rows, while the other
    // worker could only wait: at 1280 x 720 on two threads the workers ended 0.3-0.7 ms
    // apart in a 12 ms call, 0.1-0.2 ms now (bench/README, twenty-sixth round).
    auto labelling = [&]() -> SpeckleBand& {
      auto& pool = ws.speckle[w];
      const std::size_t label = segments[w].size();
      if (pool.size() <= label) pool.resize(label + 1);
      return pool[label];
    };
    auto close_segment = [&] {
      if (seg0 < 0) return;
      const std::size_t label = segments[w].size();
      if (speckle) detail::speckle_end(p.speckle_window, labelling());
      segments[w].push_back({seg0, seg1, w, label});
      seg0 = seg1 = -1;
    };
    std::atomic<std::uint64_t>& mine = ranges[w];
    detail::MatchArgs a = common;
    for (;;) {
      throw_if_stopped();  // Ctrl-C: every worker stops at its next rows
      // Claim the next rows of this worker's range.
      std::uint64_t cur = mine.load();
      std::ptrdiff_t y0 = 0, y1 = 0;
      for (;;) {
        y0 = static_cast<std::ptrdiff_t>(cur >> 32);
        const auto end = static_cast<std::ptrdiff_t>(cur & 0xFFFFFFFFu);
        if (y0 >= end) {
          y1 = y0;
          break;
        }
        y1 = std::min(end, y0 + kChunk);
        if (mine.compare_exchange_weak(cur, pack(y1, end))) break;
      }
      if (y1 > y0) {
        const bool fresh = y0 != seg1;
        if (fresh) {
          close_segment();
          seg0 = y0;
          const Worker& src = workers[owner[w].load()];
          a.left_feat = src.feat[0];
          a.right_feat = src.feat[1];
          a.texture = src.texture;
          a.feat_row0 = src.f0;
        }
        k.match_band(a, workers[w].scratch, y0, y1, fresh);
        if (speckle) {
          SpeckleBand& b = labelling();
          if (fresh) detail::speckle_begin(y0, disparity.cols, b);
          detail::speckle_rows(k, disparity, y1, speckle_rf, b);
        }
        seg1 = y1;
        continue;
      }
      close_segment();
      // Steal the back half of the largest remaining range, if it is worth a set-up.
      bool stole = false;
      for (int attempt = 0; attempt < 8 && !stole; ++attempt) {
        std::size_t victim = nw;
        std::ptrdiff_t most = 0;
        std::uint64_t seen = 0;
        for (std::size_t v = 0; v < nw; ++v) {
          if (v == w || !ready[v].load()) continue;
          const std::uint64_t rv = ranges[v].load();
          const auto left_rows = static_cast<std::ptrdiff_t>(rv & 0xFFFFFFFFu) -
                                 static_cast<std::ptrdiff_t>(rv >> 32);
          if (left_rows > most) {
            most = left_rows;
            victim = v;
            seen = rv;
          }
        }
        if (victim == nw || most < 2 * min_steal) break;
        // A worker changes its owner only while its range is empty, so the owner read while
        // the range holds `seen` belongs to those rows; the exchange below checks that.
        const std::size_t feat_owner = owner[victim].load();
        const auto begin = static_cast<std::ptrdiff_t>(seen >> 32);
        const auto end = static_cast<std::ptrdiff_t>(seen & 0xFFFFFFFFu);
        const std::ptrdiff_t mid = begin + (end - begin) / 2;
        if (ranges[victim].compare_exchange_strong(seen, pack(begin, mid))) {
          owner[w].store(feat_owner);
          mine.store(pack(mid, end));
          stole = true;
        }
      }
      if (!stole) return;
    }
  };
  // A thread runs its own worker, then any worker that no thread has started: on a busy
  // machine a thread that starts late finds its band done rather than holding the call up.
  std::vector<std::atomic<bool>> started(nw);
  for (auto& f : started) f.store(false);
  parallel_for_rows(static_cast<std::ptrdiff_t>(nw), static_cast<int>(nw), 1,
                    [&](std::ptrdiff_t b, std::ptrdiff_t e) {
                      for (std::ptrdiff_t first = b; first < e; ++first) {
                        for (std::size_t k = 0; k < nw; ++k) {
                          const std::size_t w = (static_cast<std::size_t>(first) + k) % nw;
                          if (!started[w].exchange(true)) run_worker(w);
                        }
                      }
                    });

  // 3. The speckle filter: join the segments, clear the small regions.
  if (speckle) {
    std::vector<Segment> all;
    for (const auto& list : segments) all.insert(all.end(), list.begin(), list.end());
    std::sort(all.begin(), all.end(),
              [](const Segment& x, const Segment& y) { return x.y0 < y.y0; });
    std::vector<SpeckleBand*> labels;
    std::vector<std::ptrdiff_t> starts;
    for (const Segment& seg : all) {
      labels.push_back(&ws.speckle[seg.worker][seg.label]);
      starts.push_back(seg.y0);
    }
    starts.push_back(rows);
    speckle_finish(k, disparity, confidence, p.speckle_window, speckle_rf, labels, starts,
                   ws.speckle_join, static_cast<int>(nw));
  }
}

void rgb_to_grey(const StereoImage& rgb, std::uint8_t* grey, Isa isa) {
  if (!is_colour(rgb.format)) throw std::invalid_argument("rgb must be a colour image");
  const detail::BlockMatchKernels& k = kernels_for(isa);
  for (std::ptrdiff_t y = 0; y < rgb.rows; ++y) {
    k.rgb_to_grey(static_cast<const std::uint8_t*>(rgb.data) + y * rgb.row_stride,
                  grey + y * rgb.cols, rgb.cols, rgb.format == PixelFormat::kBgr8);
  }
}

void block_match(const StereoImage& left, const StereoImage& right,
                 const ImageView<float>& disparity, const ImageView<float>& confidence,
                 const BlockMatchParams& params, int threads, Isa isa) {
  BlockMatcher matcher(params, threads, isa);
  matcher.compute(left, right, disparity, confidence);
}

std::vector<std::pair<std::string, double>> BlockMatcher::stage_times(
    const StereoImage& left, const StereoImage& right, const ImageView<float>& disparity,
    int repeats) {
  const BlockMatchParams& p = params_;
  if (left.format == PixelFormat::kGrey16 || left.format != right.format ||
      left.rows != right.rows || left.cols != right.cols || left.rows < 1 || left.cols < 1 ||
      disparity.rows != left.rows || disparity.cols != left.cols) {
    throw std::invalid_argument(
        "stage_times takes two 8-bit images of one shape and their disparity");
  }
  if (repeats < 1) throw std::invalid_argument("repeats must be >= 1");
  std::lock_guard<std::mutex> lock(mutex_);
  const detail::BlockMatchKernels& k = kernels_for(isa_);
  const std::ptrdiff_t rows = left.rows, cols = left.cols;
  const int dp = (p.num_disparities + k.lanes - 1) / k.lanes * k.lanes;
  const bool colour = is_colour(left.format);
  const bool bgr = left.format == PixelFormat::kBgr8;
  const bool census = p.cost == MatchCost::kCensus;
  const bool texture_on = p.texture_threshold > 0;
  const std::size_t feat_size = census ? 4 : 1;
  const auto pix = static_cast<std::size_t>(rows * cols);

  ByteBuffer storage;
  Arena arena(&storage);
  detail::BandScratch scratch{};
  std::uint8_t *grey[2] = {}, *feat[2] = {}, *texture = nullptr;
  float* copy = nullptr;
  for (int pass = 0; pass < 2; ++pass) {
    scratch = carve_band(arena, cols, dp, feat_size, k.lanes, p.block_size / 2);
    grey[0] = arena.take<std::uint8_t>(pix);
    grey[1] = arena.take<std::uint8_t>(pix);
    feat[0] = arena.take<std::uint8_t>(pix * feat_size);
    feat[1] = arena.take<std::uint8_t>(pix * feat_size);
    texture = arena.take<std::uint8_t>(pix);
    copy = arena.take<float>(pix);
    if (pass == 0) arena.reserve();
  }

  std::vector<std::pair<std::string, double>> out;
  auto timed = [&](const char* name, auto&& fn, auto&& before) {
    double best = 0;
    for (int i = 0; i < repeats; ++i) {
      before();
      const auto t0 = std::chrono::steady_clock::now();
      fn();
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (i == 0 || s < best) best = s;
    }
    out.emplace_back(name, best);
  };
  auto nothing = [] {};

  const StereoImage* images[2] = {&left, &right};
  const std::uint8_t* base[2];
  for (int im = 0; im < 2; ++im) base[im] = static_cast<const std::uint8_t*>(images[im]->data);
  std::ptrdiff_t stride = left.row_stride;
  if (colour) {
    timed("grey", [&] {
      for (int im = 0; im < 2; ++im) {
        for (std::ptrdiff_t y = 0; y < rows; ++y) {
          k.rgb_to_grey(base[im] + y * images[im]->row_stride, grey[im] + y * cols, cols, bgr);
        }
      }
    }, nothing);
    base[0] = grey[0];
    base[1] = grey[1];
    stride = cols;
  }
  auto grey_row = [&](int im, std::ptrdiff_t y) {
    return base[im] + std::clamp<std::ptrdiff_t>(y, 0, rows - 1) * stride;
  };
  timed("features", [&] {
    for (int im = 0; im < 2; ++im) {
      for (std::ptrdiff_t y = 0; y < rows; ++y) {
        if (census) {
          const std::uint8_t* r5[5];
          for (int i = 0; i < 5; ++i) r5[i] = grey_row(im, y + i - 2);
          k.census_row8(r5, reinterpret_cast<std::uint32_t*>(feat[im]) + y * cols, cols);
        } else {
          const std::uint8_t* r3[3];
          for (int i = 0; i < 3; ++i) r3[i] = grey_row(im, y + i - 1);
          k.sobel_row8(r3, feat[im] + y * cols, nullptr, cols);
        }
      }
    }
  }, nothing);
  if (texture_on) {
    timed("texture", [&] {
      for (std::ptrdiff_t y = 0; y < rows; ++y) {
        const std::uint8_t* r3[3];
        for (int i = 0; i < 3; ++i) r3[i] = grey_row(0, y + i - 1);
        k.sobel_row8(r3, nullptr, texture + y * cols, cols);
      }
    }, nothing);
  }

  detail::MatchArgs a{};
  a.cost = p.cost;
  a.left_feat = feat[0];
  a.right_feat = feat[1];
  a.feat_stride = cols;
  a.feat_row0 = 0;
  a.texture = texture_on ? texture : nullptr;
  a.texture_stride = cols;
  a.rows = rows;
  a.cols = cols;
  a.min_d = p.min_disparity;
  a.num_d = p.num_disparities;
  a.dp = dp;
  a.radius = p.block_size / 2;
  a.subpixel = p.subpixel;
  a.uniqueness_factor = uniqueness_factor_;
  a.unique_min = unique_min_.empty() ? nullptr : unique_min_.data();
  a.unique_min_shifted =
      unique_min_.empty() ? nullptr : unique_min_.data() + unique_min_.size() / 2;
  a.texture_sum_min = p.texture_threshold * static_cast<double>(p.block_size * p.block_size);
  a.lr_max_diff = p.lr_max_diff;
  a.clip_border = p.clip_border;
  a.disp = disparity.data;
  a.disp_stride = disparity.row_stride;
  a.conf = nullptr;
  a.conf_stride = 0;
  // The second pass needs the first's records of its row: it is timed as both passes less
  // the first, the two runs taking turns so that a change of load hits both.
  double first = 0, both = 0;
  for (int i = 0; i < repeats; ++i) {
    for (int pass = 0; pass < 2; ++pass) {
      a.first_pass_only = pass == 0;
      const auto t0 = std::chrono::steady_clock::now();
      k.match_band(a, scratch, 0, rows, true);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      double& best = pass == 0 ? first : both;
      if (i == 0 || s < best) best = s;
    }
  }
  out.emplace_back("first pass", first);
  out.emplace_back("second pass", std::max(0.0, both - first));

  if (p.speckle_window > 0) {
    const float rf = speckle_range_f(p.speckle_range);
    const ImageView<float> view{copy, rows, cols, cols};
    SpeckleBand band;
    detail::SpeckleJoin join;
    const std::vector<SpeckleBand*> bands = {&band};
    const std::vector<std::ptrdiff_t> starts = {0, rows};
    timed("speckle", [&] {
      speckle_band(k, view, 0, rows, rf, p.speckle_window, band);
      speckle_finish(k, view, ImageView<float>{}, p.speckle_window, rf, bands, starts, join, 1);
    }, [&] {
      for (std::ptrdiff_t y = 0; y < rows; ++y) {
        std::memcpy(copy + y * cols, disparity.row(y),
                    sizeof(float) * static_cast<std::size_t>(cols));
      }
    });
  }
  STEREODEPTH_UNPOISON(storage.bytes.get(), storage.size);
  return out;
}

}  // namespace stereodepth
