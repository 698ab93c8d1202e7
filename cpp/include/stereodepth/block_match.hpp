// Dense block-matching disparity with census or SAD costs, validity checks and sub-pixel
// refinement. The steps and rules are documented in python/stereodepth/matching.py; the numpy
// oracle (stereodepth.reference.block_match) follows them one by one.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth {

// Pixel cost: census (the 16 pixels on the border of the 5x5 window, Hamming distance, 0..16)
// or SAD of the x-Sobel-prefiltered images (clip(sobel, -31, 31) + 31, 0..62).
enum class MatchCost { kCensus = 0, kSad = 1 };

// How the winning disparity is refined from the costs at d - 1, d, d + 1.
enum class SubpixelFit { kNone = 0, kParabola = 1, kEquiangular = 2 };

// Limits. Block costs are summed in 16 bits: block_size^2 * pixel_cost_max(cost) <= 65535.
inline constexpr int kMaxNumDisparities = 4096;
inline constexpr int kMaxAbsMinDisparity = 32768;
inline constexpr int kCensusCostMax = 16;
inline constexpr int kSadCostMax = 62;
inline constexpr int kPrefilterCap = 31;

int pixel_cost_max(MatchCost cost);
int max_block_size(MatchCost cost);  // 63 for census, 31 for SAD

struct BlockMatchParams {
  int num_disparities = 64;   // [1, kMaxNumDisparities]
  int min_disparity = 0;      // [-kMaxAbsMinDisparity, kMaxAbsMinDisparity]
  int block_size = 9;         // odd, [3, max_block_size(cost)]
  MatchCost cost = MatchCost::kCensus;
  SubpixelFit subpixel = SubpixelFit::kEquiangular;
  double uniqueness_ratio = 10.0;  // percent; 0 turns the check off
  double texture_threshold = 0.0;  // least mean min(|sobel_x|, 31) per block pixel; 0 = off
  double lr_max_diff = 1.0;        // pixels; negative turns the check off
  int speckle_window = 0;          // largest region removed, in pixels; 0 = off
  double speckle_range = 1.0;      // largest step between neighbours within a region, pixels
  // Pixels whose search range leaves the right image are matched over the disparities that
  // stay inside it (true), or NaN as OpenCV's (false).
  bool clip_border = true;
};

// Throws std::invalid_argument naming the parameter, the rule and the value received.
void validate(const BlockMatchParams& params);

// An input image: 8-bit grey, 16-bit grey, or 8-bit colour (3 interleaved channels: R, G, B,
// or B, G, R as OpenCV stores them). Colour is matched as its grey, OpenCV's COLOR_RGB2GRAY
// or COLOR_BGR2GRAY.
enum class PixelFormat { kGrey8 = 0, kGrey16 = 1, kRgb8 = 2, kBgr8 = 3 };

inline bool is_colour(PixelFormat f) { return f == PixelFormat::kRgb8 || f == PixelFormat::kBgr8; }

struct StereoImage {
  const void* data = nullptr;
  PixelFormat format = PixelFormat::kGrey8;
  std::ptrdiff_t rows = 0;
  std::ptrdiff_t cols = 0;
  std::ptrdiff_t row_stride = 0;  // in bytes
};

// The matcher for per-frame use: parameters validated once, buffers kept between frames.
// compute() may be called from several threads; the calls take turns.
class BlockMatcher {
 public:
  explicit BlockMatcher(const BlockMatchParams& params, int threads = 0,
                        Isa isa = default_isa());
  ~BlockMatcher();
  BlockMatcher(const BlockMatcher&) = delete;
  BlockMatcher& operator=(const BlockMatcher&) = delete;

  // Writes the disparity of `left` (NaN where invalid) and, when confidence.data is not null,
  // the confidence in [0, 1]. Both outputs have the images' shape.
  void compute(const StereoImage& left, const StereoImage& right,
               const ImageView<float>& disparity, const ImageView<float>& confidence);

  // Diagnostics for the benchmarks: each stage of compute() timed on its own, on one thread,
  // over the whole image, in seconds (the least of `repeats` runs): "grey" (colour images only),
  // "features" (census codes or the SAD prefilter, both images), "texture" (when the check
  // is on), "first pass" (block-column and block sums, winners, the right image's winners),
  // "second pass" (the checks and the sub-pixel step) and "speckle" (when on). Writes the
  // disparity (without the speckle filter). 8-bit grey or colour images only.
  std::vector<std::pair<std::string, double>> stage_times(const StereoImage& left,
                                                          const StereoImage& right,
                                                          const ImageView<float>& disparity,
                                                          int repeats);

  const BlockMatchParams& params() const { return params_; }
  int threads() const { return threads_; }
  Isa isa() const { return isa_; }

 private:
  struct Workspace;
  BlockMatchParams params_;
  int threads_;
  Isa isa_;
  double uniqueness_factor_ = 0.0;        // 100 + ratio, or 0 when the check is off
  // The same check as a table (see the kernels): the thresholds, then min(t << 4, 0xFFFF)
  // for each (the form the AVX2 first pass compares in).
  std::vector<std::uint32_t> unique_min_;
  std::unique_ptr<Workspace> workspace_;
  std::mutex mutex_;
};

// Diagnostics (tests): the grey levels the matchers match an 8-bit colour image by (OpenCV's
// COLOR_RGB2GRAY or COLOR_BGR2GRAY, bit for bit), computed row by row with `isa`'s kernel
// into `grey` (rgb.rows x rgb.cols bytes, rows rgb.cols apart). Throws std::invalid_argument
// when rgb is not colour.
void rgb_to_grey(const StereoImage& rgb, std::uint8_t* grey, Isa isa);

// One-shot form of BlockMatcher::compute.
void block_match(const StereoImage& left, const StereoImage& right,
                 const ImageView<float>& disparity, const ImageView<float>& confidence,
                 const BlockMatchParams& params, int threads = 0, Isa isa = default_isa());

}  // namespace stereodepth
