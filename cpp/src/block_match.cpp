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

// 64-byte aligned pieces carved out of one byte buffer.
class Arena {
 public:
  explicit Arena(std::vector<std::uint8_t>* storage) : storage_(storage) {}
  // First pass: count; second pass (after reserve()): hand out pointers.
  template <typename T>
  T* take(std::size_t count) {
    const std::size_t bytes = (count * sizeof(T) + 63) & ~std::size_t{63};
    T* p = base_ ? reinterpret_cast<T*>(base_ + used_) : nullptr;
    used_ += bytes;
    return p;
  }
  void reserve() {
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
  std::vector<std::uint8_t> grey_left, grey_right;  // RGB input only
  std::vector<std::uint8_t> features;               // both feature images and the texture
  std::vector<std::vector<std::uint8_t>> bands;     // per-band scratch
  std::vector<std::int32_t> labels;                 // speckle filter
  std::vector<std::int64_t> stack;
  std::vector<std::uint8_t> remove;
  std::vector<std::uint32_t> unique_min;  // uniqueness thresholds per winning cost
};

BlockMatcher::BlockMatcher(const BlockMatchParams& params, int threads, Isa isa)
    : params_(params), threads_(resolve_threads(threads)), isa_(isa),
      workspace_(std::make_unique<Workspace>()) {
  validate(params_);
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

  std::lock_guard<std::mutex> lock(mutex_);
  Workspace& ws = *workspace_;
  const detail::BlockMatchKernels& k = kernels_for(isa_);
  const int threads = threads_;
  const std::ptrdiff_t min_band = std::max<std::ptrdiff_t>(16, 2 * p.block_size);

  // 1. Grey: RGB is converted; grey images are read in place.
  const bool sixteen = left.format == PixelFormat::kGrey16;
  const void* gl = left.data;
  const void* gr = right.data;
  std::ptrdiff_t gstride = sixteen ? left.row_stride / 2 : left.row_stride;  // elements
  std::ptrdiff_t gstride_r = sixteen ? right.row_stride / 2 : right.row_stride;
  if (left.format == PixelFormat::kRgb8) {
    const auto n = static_cast<std::size_t>(rows * cols);
    ws.grey_left.resize(n);
    ws.grey_right.resize(n);
    parallel_for_rows(rows, threads, (1 << 15) / cols + 1, [&](std::ptrdiff_t b, std::ptrdiff_t e) {
      for (std::ptrdiff_t y = b; y < e; ++y) {
        k.rgb_to_grey(static_cast<const std::uint8_t*>(left.data) + y * left.row_stride,
                      ws.grey_left.data() + y * cols, cols);
        k.rgb_to_grey(static_cast<const std::uint8_t*>(right.data) + y * right.row_stride,
                      ws.grey_right.data() + y * cols, cols);
      }
    });
    gl = ws.grey_left.data();
    gr = ws.grey_right.data();
    gstride = gstride_r = cols;
  }

  // 2. Feature images (census codes or prefiltered pixels) and the texture map.
  const bool census = p.cost == MatchCost::kCensus;
  const bool texture_on = p.texture_threshold > 0;
  const std::size_t feat_size = census ? 4 : 1;
  const auto npix = static_cast<std::size_t>(rows * cols);
  ws.features.resize(2 * npix * feat_size + (texture_on ? npix : 0) + 64);
  std::uint8_t* fbase = ws.features.data();
  std::uint8_t* feat_l = fbase;
  std::uint8_t* feat_r = fbase + npix * feat_size;
  std::uint8_t* texture = texture_on ? fbase + 2 * npix * feat_size : nullptr;
  auto grey_row = [&](const void* base, std::ptrdiff_t stride, std::ptrdiff_t y) -> const void* {
    y = std::clamp<std::ptrdiff_t>(y, 0, rows - 1);
    return sixteen ? static_cast<const void*>(static_cast<const std::uint16_t*>(base) + y * stride)
                   : static_cast<const void*>(static_cast<const std::uint8_t*>(base) + y * stride);
  };
  auto feature_rows = [&](const void* base, std::ptrdiff_t stride, std::uint8_t* feat,
                          std::uint8_t* tex, std::ptrdiff_t y) {
    if (census) {
      const void* r5[5];
      for (int i = 0; i < 5; ++i) r5[i] = grey_row(base, stride, y + i - 2);
      auto* out = reinterpret_cast<std::uint32_t*>(feat) + y * cols;
      if (sixteen) {
        k.census_row16(reinterpret_cast<const std::uint16_t* const*>(r5), out, cols);
      } else {
        k.census_row8(reinterpret_cast<const std::uint8_t* const*>(r5), out, cols);
      }
    }
    std::uint8_t* pre = census ? nullptr : feat + y * cols;
    std::uint8_t* t = tex ? tex + y * cols : nullptr;
    if (pre || t) {
      const void* r3[3];
      for (int i = 0; i < 3; ++i) r3[i] = grey_row(base, stride, y + i - 1);
      if (sixteen) {
        k.sobel_row16(reinterpret_cast<const std::uint16_t* const*>(r3), pre, t, cols);
      } else {
        k.sobel_row8(reinterpret_cast<const std::uint8_t* const*>(r3), pre, t, cols);
      }
    }
  };
  parallel_for_rows(rows, threads, (1 << 13) / cols + 1, [&](std::ptrdiff_t b, std::ptrdiff_t e) {
    for (std::ptrdiff_t y = b; y < e; ++y) {
      feature_rows(gl, gstride, feat_l, texture, y);
      feature_rows(gr, gstride_r, feat_r, nullptr, y);
    }
  });

  // 3. Matching, in bands of rows.
  const int dp = (p.num_disparities + k.lanes - 1) / k.lanes * k.lanes;
  if (static_cast<double>(cols) * dp >= 1073741824.0) {
    throw std::invalid_argument("the image width times num_disparities must be below 2^30, got " +
                                std::to_string(cols) + " x " + std::to_string(p.num_disparities));
  }
  const std::ptrdiff_t nbands =
      std::max<std::ptrdiff_t>(1, std::min<std::ptrdiff_t>(threads, rows / min_band));
  if (static_cast<std::ptrdiff_t>(ws.bands.size()) < nbands) ws.bands.resize(nbands);
  std::vector<detail::BandScratch> scratch(static_cast<std::size_t>(nbands));
  for (std::ptrdiff_t b = 0; b < nbands; ++b) {
    Arena arena(&ws.bands[static_cast<std::size_t>(b)]);
    carve_band(arena, cols, dp, feat_size);
    arena.reserve();
    scratch[static_cast<std::size_t>(b)] = carve_band(arena, cols, dp, feat_size);
  }
  detail::MatchArgs a{};
  a.cost = p.cost;
  a.left_feat = feat_l;
  a.right_feat = feat_r;
  a.feat_stride = cols;
  a.texture = texture;
  a.texture_stride = cols;
  a.rows = rows;
  a.cols = cols;
  a.min_d = p.min_disparity;
  a.num_d = p.num_disparities;
  a.dp = dp;
  a.radius = p.block_size / 2;
  a.subpixel = p.subpixel;
  a.uniqueness_factor = p.uniqueness_ratio > 0 ? 100.0 + p.uniqueness_ratio : 0.0;
  a.unique_min = nullptr;
  if (p.uniqueness_ratio > 0) {
    // unique_min[b]: the least cost s with s * 100 > b * (100 + ratio), in the same double
    // arithmetic as the check itself; capped at 0xFFFF, above every block cost.
    const double factor = a.uniqueness_factor;
    const int max_cost = p.block_size * p.block_size * pixel_cost_max(p.cost);
    ws.unique_min.resize(static_cast<std::size_t>(max_cost) + 1);
    for (int b = 0; b <= max_cost; ++b) {
      const double bound = static_cast<double>(b) * factor;
      double s = std::floor(bound / 100.0);
      while (s > 0 && s * 100.0 > bound) s -= 1.0;
      while (!(s * 100.0 > bound)) s += 1.0;
      ws.unique_min[static_cast<std::size_t>(b)] =
          static_cast<std::uint32_t>(std::min(s, 65535.0));
    }
    a.unique_min = ws.unique_min.data();
  }
  a.lr_max_diff = p.lr_max_diff;
  a.disp = disparity.data;
  a.disp_stride = disparity.row_stride;
  a.conf = confidence.data;
  a.conf_stride = confidence.row_stride;
  parallel_for_rows(nbands, static_cast<int>(nbands), 1, [&](std::ptrdiff_t b, std::ptrdiff_t e) {
    for (std::ptrdiff_t band = b; band < e; ++band) {
      k.match_band(a, scratch[static_cast<std::size_t>(band)], rows * band / nbands,
                   rows * (band + 1) / nbands);
    }
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
