#include "stereodepth/block_match.hpp"

#include <algorithm>
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

detail::BandScratch carve_band(Arena& arena, std::ptrdiff_t cols, int dp, std::size_t feat_size) {
  const auto c = static_cast<std::size_t>(cols);
  const std::size_t row = c + static_cast<std::size_t>(dp) + detail::kRowPad;
  detail::BandScratch s{};
  s.colsum = arena.take<std::uint16_t>(c * static_cast<std::size_t>(dp));
  s.acc = arena.take<std::uint16_t>(static_cast<std::size_t>(dp));
  s.rpad_in = arena.take<std::uint8_t>(row * feat_size);
  s.rpad_out = arena.take<std::uint8_t>(row * feat_size);
  s.rmin = arena.take<std::uint16_t>(row);
  s.rarg = arena.take<std::uint16_t>(row);
  s.texcol = arena.take<std::uint32_t>(c);
  s.best = arena.take<std::uint16_t>(c + 16);
  s.kbest = arena.take<std::int32_t>(c + 16);
  s.second = arena.take<std::uint16_t>(c + 16);
  s.tsum = arena.take<std::uint32_t>(c + 16);
  s.arow = arena.take<std::uint16_t>(c * static_cast<std::size_t>(dp) + 32);
  return s;
}

// Removes 4-connected regions of at most `window` valid pixels (neighbours within `range`).
void speckle_filter(const ImageView<float>& disp, const ImageView<float>& conf, int window,
                    double range, std::vector<std::int32_t>& labels,
                    std::vector<std::int64_t>& stack, std::vector<std::uint8_t>& remove) {
  const std::ptrdiff_t rows = disp.rows, cols = disp.cols;
  labels.assign(static_cast<std::size_t>(rows * cols), 0);
  remove.assign(1, 0);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::int32_t next = 1;
  for (std::ptrdiff_t y = 0; y < rows; ++y) {
    for (std::ptrdiff_t x = 0; x < cols; ++x) {
      const std::ptrdiff_t p0 = y * cols + x;
      if (labels[p0] != 0 || std::isnan(disp.row(y)[x])) continue;
      const std::int32_t label = next++;
      labels[p0] = label;
      stack.clear();
      stack.push_back(p0);
      std::int64_t count = 0;
      while (!stack.empty()) {
        const std::int64_t p = stack.back();
        stack.pop_back();
        ++count;
        const std::ptrdiff_t py = p / cols, px = p % cols;
        const float d = disp.row(py)[px];
        auto visit = [&](std::ptrdiff_t ny, std::ptrdiff_t nx) {
          const std::ptrdiff_t n = ny * cols + nx;
          if (labels[n] != 0) return;
          const float dn = disp.row(ny)[nx];
          if (std::isnan(dn) || !(static_cast<double>(std::fabs(dn - d)) <= range)) return;
          labels[n] = label;
          stack.push_back(n);
        };
        if (px > 0) visit(py, px - 1);
        if (px + 1 < cols) visit(py, px + 1);
        if (py > 0) visit(py - 1, px);
        if (py + 1 < rows) visit(py + 1, px);
      }
      remove.push_back(count <= window ? 1 : 0);
    }
  }
  for (std::ptrdiff_t y = 0; y < rows; ++y) {
    float* d = disp.row(y);
    float* c = conf.data ? conf.row(y) : nullptr;
    for (std::ptrdiff_t x = 0; x < cols; ++x) {
      if (remove[static_cast<std::size_t>(labels[y * cols + x])]) {
        d[x] = nan;
        if (c) c[x] = 0.0f;
      }
    }
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
    for (auto& band : bands) STEREODEPTH_UNPOISON(band.data(), band.size());
  }

  std::vector<std::vector<std::uint8_t>> bands;  // per band: scratch, grey and feature rows
  std::vector<std::int32_t> labels;                 // speckle filter
  std::vector<std::int64_t> stack;
  std::vector<std::uint8_t> remove;
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
      double s = std::floor(bound / 100.0);
      while (s > 0 && s * 100.0 > bound) s -= 1.0;
      while (!(s * 100.0 > bound)) s += 1.0;
      unique_min_[static_cast<std::size_t>(b)] = static_cast<std::uint32_t>(std::min(s, 65535.0));
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

  // Bands of rows, one per thread, each with enough rows that its set-up (the block's rows
  // above and below) stays small.
  const std::ptrdiff_t min_band = std::max<std::ptrdiff_t>(16, 2 * p.block_size);
  const std::ptrdiff_t nbands =
      std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(threads_, rows / min_band));
  struct Band {
    std::ptrdiff_t y0, y1;  // output rows
    std::ptrdiff_t f0, f1;  // feature rows: the output rows and the block's reach
    std::ptrdiff_t g0, g1;  // grey rows: the feature rows and the census window's reach
    detail::BandScratch scratch;
    std::uint8_t* grey[2];  // RGB only: grey rows g0..g1
    std::uint8_t* feat[2];  // feature rows f0..f1, left and right
    std::uint8_t* texture;  // texture rows f0..f1, or null
  };
  std::vector<Band> bands(static_cast<std::size_t>(nbands));
  if (static_cast<std::ptrdiff_t>(ws.bands.size()) < nbands) ws.bands.resize(nbands);
  for (std::ptrdiff_t i = 0; i < nbands; ++i) {
    Band& band = bands[static_cast<std::size_t>(i)];
    band.y0 = rows * i / nbands;
    band.y1 = rows * (i + 1) / nbands;
    band.f0 = std::max<std::ptrdiff_t>(0, band.y0 - r);
    band.f1 = std::min<std::ptrdiff_t>(rows, band.y1 + r);
    band.g0 = std::max<std::ptrdiff_t>(0, band.f0 - 2);
    band.g1 = std::min<std::ptrdiff_t>(rows, band.f1 + 2);
    const auto fpix = static_cast<std::size_t>((band.f1 - band.f0) * cols);
    const auto gpix = static_cast<std::size_t>((band.g1 - band.g0) * cols);
    Arena arena(&ws.bands[static_cast<std::size_t>(i)]);
    for (int pass = 0; pass < 2; ++pass) {
      band.scratch = carve_band(arena, cols, dp, feat_size);
      band.grey[0] = arena.take<std::uint8_t>(rgb ? gpix : 0);
      band.grey[1] = arena.take<std::uint8_t>(rgb ? gpix : 0);
      band.feat[0] = arena.take<std::uint8_t>(fpix * feat_size);
      band.feat[1] = arena.take<std::uint8_t>(fpix * feat_size);
      band.texture = arena.take<std::uint8_t>(texture_on ? fpix : 0);
      if (pass == 0) arena.reserve();
    }
    if (!texture_on) band.texture = nullptr;
  }

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

  const StereoImage* images[2] = {&left, &right};
  auto run_band = [&](Band& band) {
    // 1. Grey rows: RGB is converted, grey images are read in place.
    const void* grey_base[2];
    std::ptrdiff_t grey_stride[2], grey_row0[2];
    for (int im = 0; im < 2; ++im) {
      const StereoImage& src = *images[im];
      if (rgb) {
        for (std::ptrdiff_t y = band.g0; y < band.g1; ++y) {
          k.rgb_to_grey(static_cast<const std::uint8_t*>(src.data) + y * src.row_stride,
                        band.grey[im] + (y - band.g0) * cols, cols);
        }
        grey_base[im] = band.grey[im];
        grey_stride[im] = cols;
        grey_row0[im] = band.g0;
      } else {
        grey_base[im] = src.data;
        grey_stride[im] = sixteen ? src.row_stride / 2 : src.row_stride;
        grey_row0[im] = 0;
      }
    }
    auto grey_row = [&](int im, std::ptrdiff_t y) -> const void* {
      const std::ptrdiff_t off = (std::clamp<std::ptrdiff_t>(y, 0, rows - 1) - grey_row0[im]) *
                                 grey_stride[im];
      return sixteen ? static_cast<const void*>(static_cast<const std::uint16_t*>(grey_base[im]) + off)
                     : static_cast<const void*>(static_cast<const std::uint8_t*>(grey_base[im]) + off);
    };
    // 2. Feature rows (census codes or prefiltered pixels) and the texture.
    for (int im = 0; im < 2; ++im) {
      for (std::ptrdiff_t y = band.f0; y < band.f1; ++y) {
        const std::ptrdiff_t at = (y - band.f0) * cols;
        if (census) {
          const void* r5[5];
          for (int i = 0; i < 5; ++i) r5[i] = grey_row(im, y + i - 2);
          auto* out = reinterpret_cast<std::uint32_t*>(band.feat[im]) + at;
          if (sixteen) {
            k.census_row16(reinterpret_cast<const std::uint16_t* const*>(r5), out, cols);
          } else {
            k.census_row8(reinterpret_cast<const std::uint8_t* const*>(r5), out, cols);
          }
        }
        std::uint8_t* pre = census ? nullptr : band.feat[im] + at;
        std::uint8_t* tex = im == 0 && band.texture ? band.texture + at : nullptr;
        if (pre || tex) {
          const void* r3[3];
          for (int i = 0; i < 3; ++i) r3[i] = grey_row(im, y + i - 1);
          if (sixteen) {
            k.sobel_row16(reinterpret_cast<const std::uint16_t* const*>(r3), pre, tex, cols);
          } else {
            k.sobel_row8(reinterpret_cast<const std::uint8_t* const*>(r3), pre, tex, cols);
          }
        }
      }
    }
    // 3. Matching.
    detail::MatchArgs a = common;
    a.left_feat = band.feat[0];
    a.right_feat = band.feat[1];
    a.feat_row0 = band.f0;
    a.texture = band.texture;
    k.match_band(a, band.scratch, band.y0, band.y1);
  };
  parallel_for_rows(nbands, static_cast<int>(nbands), 1, [&](std::ptrdiff_t b, std::ptrdiff_t e) {
    for (std::ptrdiff_t i = b; i < e; ++i) run_band(bands[static_cast<std::size_t>(i)]);
  });

  // 4. Speckle filter, on the whole map.
  if (p.speckle_window > 0) {
    speckle_filter(disparity, confidence, p.speckle_window, p.speckle_range, ws.labels, ws.stack,
                   ws.remove);
  }
}

void block_match(const StereoImage& left, const StereoImage& right,
                 const ImageView<float>& disparity, const ImageView<float>& confidence,
                 const BlockMatchParams& params, int threads, Isa isa) {
  BlockMatcher matcher(params, threads, isa);
  matcher.compute(left, right, disparity, confidence);
}

}  // namespace stereodepth
