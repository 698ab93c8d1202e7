// Dense semi-global matching (Hirschmüller 2005/2008) on census costs, sharing the block
// matcher's stages (grey, census, checks, speckle filter, threads, dispatch). The steps and
// rules are documented in python/stereodepth/semi_global.py; the numpy oracle
// (stereodepth.reference.semi_global_match) follows them one by one.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>

#include "stereodepth/block_match.hpp"
#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth {

struct SemiGlobalParams {
  int num_disparities = 64;  // [1, kMaxNumDisparities]
  int min_disparity = 0;     // [-kMaxAbsMinDisparity, kMaxAbsMinDisparity]
  int block_size = 3;        // 1 or 3: the box the census costs are summed over
  int p1 = 40;               // penalty of a one-disparity change along a path, >= 0
  int p2 = 500;  // penalty of a jump, p1 <= p2 <= min(65535 / paths, 16383) - 16 * block_size^2
  int p2_step = 16;          // grey step that halves p2; 0 = no adaptation
  int paths = 3;             // 3 (one pass), 4 or 8
  SubpixelFit subpixel = SubpixelFit::kParabola;
  double uniqueness_ratio = 2.0;  // percent; 0 turns the check off
  double lr_max_diff = 2.0;       // pixels; negative turns the check off
  bool median = true;             // 3x3 median of the valid disparities
  int speckle_window = 100;       // 0 = off
  double speckle_range = 1.0;
  bool clip_border = true;        // false: OpenCV's NaN band on the left
  double max_memory_mb = 2048.0;  // refuse above this estimate
};

// Throws std::invalid_argument naming the parameter, the rule and the value received.
void validate(const SemiGlobalParams& params);

// Bytes SemiGlobalMatcher::compute allocates for a rows x cols RGB pair (grey pairs: a
// little less) with the kernels of `isa`, the median on, the speckle filter's runs (which
// depend on the disparities) left out. paths 3: per thread a few rows of cols x
// num_disparities, nothing image-sized; paths 4 and 8: 3 bytes per pixel and disparity and 7
// per pixel, beside the rows.
std::size_t semi_global_memory(std::ptrdiff_t rows, std::ptrdiff_t cols, int num_disparities,
                               int paths, int threads, Isa isa = default_isa(),
                               int block_size = 3);

// The matcher for per-frame use: parameters validated once, buffers kept between frames.
// compute() may be called from several threads; the calls take turns.
// Tests only: with `on`, paths 4 and 8 on two threads split the columns into bands (as three
// or more threads do) instead of running the downward and upward passes at once; a machine
// with two CPUs otherwise never runs the bands. Not for concurrent use with matching calls.
void set_column_bands_for_tests(bool on);

class SemiGlobalMatcher {
 public:
  explicit SemiGlobalMatcher(const SemiGlobalParams& params, int threads = 0,
                             Isa isa = default_isa());
  ~SemiGlobalMatcher();
  SemiGlobalMatcher(const SemiGlobalMatcher&) = delete;
  SemiGlobalMatcher& operator=(const SemiGlobalMatcher&) = delete;

  // Writes the disparity of `left` (NaN where invalid) and, when confidence.data is not null,
  // the confidence in [0, 1]. Throws std::invalid_argument when the match would need more
  // than params.max_memory_mb.
  void compute(const StereoImage& left, const StereoImage& right,
               const ImageView<float>& disparity, const ImageView<float>& confidence);

  // Throws std::invalid_argument (the estimate, the limit and how to lower the need) when a
  // rows x cols pair would need more than params.max_memory_mb; compute() checks the same,
  // and callers that copy or convert a pair first check it before they do.
  void check_memory(std::ptrdiff_t rows, std::ptrdiff_t cols) const;

  const SemiGlobalParams& params() const { return params_; }
  int threads() const { return threads_; }
  Isa isa() const { return isa_; }

 private:
  struct Workspace;
  SemiGlobalParams params_;
  int threads_;
  Isa isa_;
  std::unique_ptr<Workspace> workspace_;
  std::mutex mutex_;
};

}  // namespace stereodepth
