#include "stereodepth/depth.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "depth_kernels.hpp"
#include "module_support.hpp"
#include "stereodepth/parallel.hpp"

namespace stereodepth {
namespace {

const detail::DepthKernels& kernels_for(Isa isa) {
  return STEREODEPTH_KERNELS_FOR(isa, depth_kernels);
}

using detail::fail;

detail::DepthRowParams row_params(const DepthParams& p) {
  detail::DepthRowParams r{};
  r.k = p.focal_px * p.baseline_m;
  r.scale = p.scale;
  r.doffs = p.doffs_px;
  r.min = p.min_depth_m;
  r.max = p.max_depth_m;
  r.invalid = p.invalid_value;
  r.k_f = static_cast<float>(r.k);
  r.scale_f = static_cast<float>(r.scale);
  r.doffs_f = static_cast<float>(r.doffs);
  r.min_f = static_cast<float>(r.min);
  r.max_f = static_cast<float>(r.max);
  r.below = p.invalid_below;
  r.invalid_f = static_cast<float>(r.invalid);
  r.below_f = static_cast<float>(r.below);
  r.has_invalid = p.has_invalid_value;
  r.has_below = p.has_invalid_below;
  return r;
}

template <typename Out>
void check_shapes(const DisparityStack& in, const StackView<Out>& out) {
  if (in.frames != out.frames || in.rows != out.rows || in.cols != out.cols) {
    throw std::invalid_argument("out must have the same shape as disparity");
  }
  if (in.frames < 0 || in.rows < 0 || in.cols < 0) {
    throw std::invalid_argument("disparity has a negative dimension");
  }
}

const char* in_row(const DisparityStack& in, std::ptrdiff_t i) {
  static constexpr std::ptrdiff_t kSize[] = {2, 4, 8, 2, 2};
  const std::ptrdiff_t elem = kSize[static_cast<int>(in.type)];
  const std::ptrdiff_t f = i / in.rows, r = i % in.rows;
  return static_cast<const char*>(in.data) + (f * in.frame_stride + r * in.row_stride) * elem;
}

// Rows per band: enough that starting a thread (tens of microseconds) is worth it.
std::ptrdiff_t min_rows(std::ptrdiff_t cols) {
  return std::max<std::ptrdiff_t>(1, (1 << 16) / std::max<std::ptrdiff_t>(cols, 1));
}

}  // namespace

void validate(const DepthParams& p) {
  if (!(std::isfinite(p.focal_px) && p.focal_px > 0)) {
    fail("focal_px must be finite and > 0", p.focal_px);
  }
  if (!(std::isfinite(p.baseline_m) && p.baseline_m > 0)) {
    fail("baseline_m must be finite and > 0", p.baseline_m);
  }
  if (!std::isfinite(p.doffs_px)) fail("doffs_px must be finite", p.doffs_px);
  if (!(std::isfinite(p.scale) && p.scale > 0)) fail("scale must be finite and > 0", p.scale);
  if (!(std::isfinite(p.min_depth_m) && p.min_depth_m >= 0)) {
    fail("min_depth_m must be finite and >= 0", p.min_depth_m);
  }
  if (!(p.max_depth_m > 0)) fail("max_depth_m must be > 0", p.max_depth_m);
  if (!(p.max_depth_m >= p.min_depth_m)) fail("max_depth_m must be >= min_depth_m", p.max_depth_m);
  if (p.has_invalid_below && std::isnan(p.invalid_below)) {
    fail("invalid_below must not be NaN", p.invalid_below);
  }
}

template <typename Out, typename RowFn>
void run_rows(const DisparityStack& in, const StackView<Out>& out, const DepthParams& params,
              int threads, RowFn fn) {
  validate(params);
  check_shapes(in, out);
  const auto rp = row_params(params);
  parallel_for_rows(in.frames * in.rows, resolve_threads(threads), min_rows(in.cols),
                    [&](std::ptrdiff_t begin, std::ptrdiff_t end) {
                      for (std::ptrdiff_t i = begin; i < end; ++i) {
                        fn(in_row(in, i), out.row(i), in.cols, rp);
                      }
                    });
}

void disparity_to_depth(const DisparityStack& in, const StackView<float>& out,
                        const DepthParams& params, int threads, Isa isa) {
  run_rows(in, out, params, threads, kernels_for(isa).to_f32[static_cast<int>(in.type)]);
}

void disparity_to_depth(const DisparityStack& in, const StackView<std::uint16_t>& out,
                        const DepthParams& params, int threads, Isa isa) {
  run_rows(in, out, params, threads, kernels_for(isa).to_u16[static_cast<int>(in.type)]);
}

}  // namespace stereodepth
