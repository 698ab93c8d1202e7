#include "stereodepth/block_match.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "block_match_kernels.hpp"
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

const detail::BlockMatchKernels& kernels_for(Isa isa) {
  switch (isa) {
#if defined(STEREODEPTH_HAVE_X86_ISAS)
    case Isa::kAvx512:
      return detail::avx512::block_match_kernels();
    case Isa::kAvx2:
      return detail::avx2::block_match_kernels();
#endif
    default:
      return detail::baseline::block_match_kernels();
  }
}

template <typename T>
[[noreturn]] void fail(const std::string& rule, T got) {
  std::ostringstream msg;
  msg << rule << ", got " << got;
  throw std::invalid_argument(msg.str());
}

const char* cost_name(MatchCost cost) { return cost == MatchCost::kCensus ? "census" : "sad"; }

// 64-byte aligned pieces carved out of one byte buffer, with a 64-byte gap after each piece
// that AddressSanitizer builds poison, so an overrun of any piece is caught.
class Arena {
 public:
  explicit Arena(std::vector<std::uint8_t>* storage) : storage_(storage) {}
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
    STEREODEPTH_UNPOISON(storage_->data(), storage_->size());
    if (storage_->size() < used_ + 64) storage_->resize(used_ + 64);
    const auto addr = reinterpret_cast<std::uintptr_t>(storage_->data());
    base_ = storage_->data() + ((64 - addr % 64) % 64);
    used_ = 0;
  }

 private:
  std::vector<std::uint8_t>* storage_;
  std::uint8_t* base_ = nullptr;
  std::size_t used_ = 0;
};

detail::BandScratch carve_band(Arena& arena, std::ptrdiff_t cols, int dp, std::size_t feat_size,
                               int lanes) {
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
  return s;
}

// The speckle filter, in two steps: each band of rows labels its own pixels (in the band's
// thread, right after matching it), then one pass joins the bands and clears small regions.
//
// Two 4-neighbours are linked when both are valid and differ by at most `range` (as OpenCV's
// filterSpeckles). Each row is cut into runs of horizontally linked pixels; vertical links
// unite runs (union-find, the lower index becoming the root). Rows are handled as bit masks
// (the kernels' speckle_links): a run starts at every valid pixel not linked to its left
// neighbour, and the run holding column i is found by counting the starts up to i.

struct SpeckleRun {
  std::int32_t parent;  // union-find link; a root links to itself
  std::int32_t y, x0, x1;
};

// A row's run starts, as bits, with the count of starts before each word and the index of
// the row's first run: the run holding column i is base + (starts up to and including i) - 1.
struct RowStarts {
  std::vector<std::uint64_t> bits;
  std::vector<std::int32_t> before;
  std::int32_t base = 0;

  void set(const std::uint64_t* valid, const std::uint64_t* left, std::size_t words,
           std::int32_t first_run) {
    bits.resize(words);
    before.resize(words);
    base = first_run;
    std::int32_t n = 0;
    for (std::size_t w = 0; w < words; ++w) {
      bits[w] = valid[w] & ~left[w];
      before[w] = n;
      n += __builtin_popcountll(bits[w]);
    }
  }
  std::int32_t run_at(std::ptrdiff_t i) const {
    const auto w = static_cast<std::size_t>(i >> 6);
    const int b = static_cast<int>(i & 63);
    const std::uint64_t upto = b == 63 ? ~std::uint64_t{0} : (std::uint64_t{2} << b) - 1;
    return base + before[w] + __builtin_popcountll(bits[w] & upto) - 1;
  }
};

// One band's labelling.
struct SpeckleBand {
  std::vector<SpeckleRun> runs;  // parents are indices into this vector
  std::vector<std::uint64_t> valid, left, up;
  RowStarts cur, prev;  // after labelling, prev holds the band's last row
  RowStarts first;      // the band's first row
};

// |a - b| <= range for a float difference is |a - b| <= the largest float not above range.
float speckle_range_f(double range) {
  float rf = static_cast<float>(range);
  if (static_cast<double>(rf) > range) rf = std::nextafter(rf, 0.0f);
  return rf;
}

std::int32_t find_root(std::vector<SpeckleRun>& runs, std::int32_t i) {
  while (runs[static_cast<std::size_t>(i)].parent != i) {
    SpeckleRun& r = runs[static_cast<std::size_t>(i)];
    r.parent = runs[static_cast<std::size_t>(r.parent)].parent;  // path halving
    i = r.parent;
  }
  return i;
}

void unite(std::vector<SpeckleRun>& runs, std::int32_t a, std::int32_t b) {
  const std::int32_t ra = find_root(runs, a), rb = find_root(runs, b);
  if (ra < rb) {
    runs[static_cast<std::size_t>(rb)].parent = ra;
  } else if (rb < ra) {
    runs[static_cast<std::size_t>(ra)].parent = rb;
  }
}

// Calls fn(i) for each column i with a vertical link whose pair of runs (below, above)
// differs from column i - 1's: the link begins there, or a run begins in either row.
template <typename Fn>
void each_new_link(const std::uint64_t* up, const RowStarts& below, const RowStarts& above,
                   std::size_t words, Fn fn) {
  std::uint64_t carry = 0;  // up bit 63 of the previous word
  for (std::size_t w = 0; w < words; ++w) {
    const std::uint64_t shifted = (up[w] << 1) | carry;
    carry = up[w] >> 63;
    std::uint64_t marks = up[w] & (~shifted | below.bits[w] | above.bits[w]);
    while (marks) {
      fn(static_cast<std::ptrdiff_t>(w * 64) + __builtin_ctzll(marks));
      marks &= marks - 1;
    }
  }
}

// Labels rows y0 .. y1 - 1 (runs, and unions inside the band).
void speckle_band(const detail::BlockMatchKernels& k, const ImageView<float>& disp,
                  std::ptrdiff_t y0, std::ptrdiff_t y1, float rf, SpeckleBand& b) {
  const std::ptrdiff_t cols = disp.cols;
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  b.runs.clear();
  b.valid.resize(words);
  b.left.resize(words);
  b.up.resize(words);
  for (std::ptrdiff_t y = y0; y < y1; ++y) {
    k.speckle_links(disp.row(y), y > y0 ? disp.row(y - 1) : nullptr, cols, rf, b.valid.data(),
                    b.left.data(), b.up.data());
    b.cur.set(b.valid.data(), b.left.data(), words, static_cast<std::int32_t>(b.runs.size()));
    for (std::size_t w = 0; w < words; ++w) {
      std::uint64_t starts = b.cur.bits[w];
      while (starts) {
        const std::ptrdiff_t x0 = static_cast<std::ptrdiff_t>(w * 64) + __builtin_ctzll(starts);
        starts &= starts - 1;
        // The run ends at the first column after x0 not linked to its left neighbour.
        std::ptrdiff_t x1 = x0 + 1;
        std::size_t ww = static_cast<std::size_t>(x1 >> 6);
        if (ww < words) {
          std::uint64_t open = ~b.left[ww] & (~std::uint64_t{0} << (x1 & 63));
          while (!open && ++ww < words) open = ~b.left[ww];
          x1 = ww < words ? static_cast<std::ptrdiff_t>(ww * 64) + __builtin_ctzll(open) : cols;
        }
        x1 = std::min(x1, cols);
        const auto id = static_cast<std::int32_t>(b.runs.size());
        b.runs.push_back({id, static_cast<std::int32_t>(y), static_cast<std::int32_t>(x0),
                          static_cast<std::int32_t>(x1)});
      }
    }
    if (y > y0) {
      each_new_link(b.up.data(), b.cur, b.prev, words, [&](std::ptrdiff_t i) {
        unite(b.runs, b.cur.run_at(i), b.prev.run_at(i));
      });
    } else {
      b.first = b.cur;
    }
    std::swap(b.cur, b.prev);
  }
}

// Joins the labellings (bands[i]: rows starts[i] .. starts[i + 1] - 1) and clears the
// regions of at most `window` pixels.
void speckle_finish(const detail::BlockMatchKernels& k, const ImageView<float>& disp,
                    const ImageView<float>& conf, int window, float rf,
                    const std::vector<SpeckleBand*>& bands,
                    const std::vector<std::ptrdiff_t>& starts, std::vector<SpeckleRun>& all,
                    std::vector<std::int64_t>& sizes) {
  const std::ptrdiff_t cols = disp.cols;
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  const std::size_t nb = starts.size() - 1;
  std::vector<std::int32_t> offset(nb + 1, 0);
  for (std::size_t i = 0; i < nb; ++i) {
    offset[i + 1] = offset[i] + static_cast<std::int32_t>(bands[i]->runs.size());
  }
  all.resize(static_cast<std::size_t>(offset[nb]));
  for (std::size_t i = 0; i < nb; ++i) {
    for (std::size_t j = 0; j < bands[i]->runs.size(); ++j) {
      SpeckleRun r = bands[i]->runs[j];
      r.parent += offset[i];
      all[static_cast<std::size_t>(offset[i]) + j] = r;
    }
  }
  for (std::size_t i = 1; i < nb; ++i) {
    SpeckleBand& b = *bands[i];
    const std::ptrdiff_t y = starts[i];
    k.speckle_links(disp.row(y), disp.row(y - 1), cols, rf, b.valid.data(), b.left.data(),
                    b.up.data());
    const RowStarts& below = b.first;
    const RowStarts& above = bands[i - 1]->prev;
    each_new_link(b.up.data(), below, above, words, [&](std::ptrdiff_t x) {
      unite(all, offset[i] + below.run_at(x), offset[i - 1] + above.run_at(x));
    });
  }
  sizes.assign(all.size(), 0);
  for (std::size_t i = 0; i < all.size(); ++i) {
    const std::int32_t root = find_root(all, static_cast<std::int32_t>(i));
    all[i].parent = root;  // now every run links to its root directly
    sizes[static_cast<std::size_t>(root)] += all[i].x1 - all[i].x0;
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const SpeckleRun& run : all) {
    if (sizes[static_cast<std::size_t>(run.parent)] > window) continue;
    std::fill(disp.row(run.y) + run.x0, disp.row(run.y) + run.x1, nan);
    if (conf.data) std::fill(conf.row(run.y) + run.x0, conf.row(run.y) + run.x1, 0.0f);
  }
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
    for (auto& w : workers) STEREODEPTH_UNPOISON(w.data(), w.size());
  }

  std::vector<std::vector<std::uint8_t>> workers;  // per worker: scratch, grey, feature rows
  std::vector<std::vector<SpeckleBand>> speckle;  // speckle labellings, per worker
  std::vector<SpeckleRun> speckle_runs;
  std::vector<std::int64_t> speckle_sizes;
};

BlockMatcher::BlockMatcher(const BlockMatchParams& params, int threads, Isa isa)
    : params_(params), threads_(resolve_threads(threads)), isa_(isa),
      workspace_(std::make_unique<Workspace>()) {
  validate(params_);
  if (params_.uniqueness_ratio > 0) {
    // The uniqueness check, second * 100 > best * (100 + ratio), as a table of the least
    // passing second-best cost per winning cost (the same double arithmetic), capped at
    // 0xFFFF, above every block cost.
    uniqueness_factor_ = 100.0 + params_.uniqueness_ratio;
    const int max_cost = params_.block_size * params_.block_size * pixel_cost_max(params_.cost);
    unique_min_.resize(static_cast<std::size_t>(max_cost) + 1);
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
    }
  }
}

BlockMatcher::~BlockMatcher() = default;

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
  if (static_cast<double>(cols) * dp >= 1073741824.0) {
    throw std::invalid_argument("the image width times num_disparities must be below 2^30, got " +
                                std::to_string(cols) + " x " + std::to_string(p.num_disparities));
  }

  std::lock_guard<std::mutex> lock(mutex_);
  Workspace& ws = *workspace_;
  const int r = p.block_size / 2;
  const bool sixteen = left.format == PixelFormat::kGrey16;
  const bool rgb = left.format == PixelFormat::kRgb8;
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
    std::uint8_t* grey[2];  // RGB only: grey rows g0..g1
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
      wk.scratch = carve_band(arena, cols, dp, feat_size, k.lanes);
      wk.grey[0] = arena.take<std::uint8_t>(rgb ? gpix : 0);
      wk.grey[1] = arena.take<std::uint8_t>(rgb ? gpix : 0);
      wk.feat[0] = arena.take<std::uint8_t>(fpix * feat_size);
      wk.feat[1] = arena.take<std::uint8_t>(fpix * feat_size);
      wk.texture = arena.take<std::uint8_t>(texture_on ? fpix : 0);
      if (pass == 0) arena.reserve();
    }
    if (!texture_on) wk.texture = nullptr;
  }

  // 1. A band's features: census codes or prefiltered pixels, and the texture; RGB rows are
  //    turned into grey first.
  const StereoImage* images[2] = {&left, &right};
  auto band_features = [&](Worker& wk) {
    for (int im = 0; im < 2; ++im) {
      const StereoImage& src = *images[im];
      const void* base = src.data;
      std::ptrdiff_t stride = sixteen ? src.row_stride / 2 : src.row_stride, row0 = 0;
      if (rgb) {
        for (std::ptrdiff_t y = wk.g0; y < wk.g1; ++y) {
          k.rgb_to_grey(static_cast<const std::uint8_t*>(src.data) + y * src.row_stride,
                        wk.grey[im] + (y - wk.g0) * cols, cols);
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
  common.texture_sum_min = p.texture_threshold * static_cast<double>(p.block_size * p.block_size);
  common.lr_max_diff = p.lr_max_diff;
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
  constexpr std::ptrdiff_t kChunk = 4;  // rows claimed at a time
  const std::ptrdiff_t min_steal = std::max<std::ptrdiff_t>(8, 2 * p.block_size);
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
    auto close_segment = [&] {
      if (seg0 < 0) return;
      std::size_t label = 0;
      if (speckle) {
        auto& pool = ws.speckle[w];
        label = segments[w].size();
        if (pool.size() <= label) pool.resize(label + 1);
        speckle_band(k, disparity, seg0, seg1, speckle_rf, pool[label]);
      }
      segments[w].push_back({seg0, seg1, w, label});
      seg0 = seg1 = -1;
    };
    std::atomic<std::uint64_t>& mine = ranges[w];
    detail::MatchArgs a = common;
    for (;;) {
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
  parallel_for_rows(static_cast<std::ptrdiff_t>(nw), static_cast<int>(nw), 1,
                    [&](std::ptrdiff_t b, std::ptrdiff_t e) {
                      for (std::ptrdiff_t w = b; w < e; ++w) run_worker(static_cast<std::size_t>(w));
                    });

  // 3. The speckle filter: join the segments, clear the small regions.
  if (speckle) {
    std::vector<Segment> all;
    for (const auto& list : segments) all.insert(all.end(), list.begin(), list.end());
    std::sort(all.begin(), all.end(), [](const Segment& x, const Segment& y) { return x.y0 < y.y0; });
    std::vector<SpeckleBand*> labels;
    std::vector<std::ptrdiff_t> starts;
    for (const Segment& seg : all) {
      labels.push_back(&ws.speckle[seg.worker][seg.label]);
      starts.push_back(seg.y0);
    }
    starts.push_back(rows);
    speckle_finish(k, disparity, confidence, p.speckle_window, speckle_rf, labels, starts,
                   ws.speckle_runs, ws.speckle_sizes);
  }
}

void block_match(const StereoImage& left, const StereoImage& right,
                 const ImageView<float>& disparity, const ImageView<float>& confidence,
                 const BlockMatchParams& params, int threads, Isa isa) {
  BlockMatcher matcher(params, threads, isa);
  matcher.compute(left, right, disparity, confidence);
}

}  // namespace stereodepth
