// Binds stereodepth/depth.hpp: check and convert with the GIL held, then release it.
#include <algorithm>
#include <optional>
#include <string>

#include <pybind11/stl.h>

#include "bind_common.hpp"
#include "stereodepth/depth.hpp"
#include "stereodepth/parallel.hpp"

namespace stereodepth::bindings {

namespace {

DisparityType disparity_type(const py::array& a) {
  const auto dt = a.dtype();
  if (dt.equal(py::dtype::of<float>())) return DisparityType::kFloat32;
  if (dt.equal(py::dtype::of<double>())) return DisparityType::kFloat64;
  if (dt.equal(py::dtype::of<std::int16_t>())) return DisparityType::kInt16;
  if (dt.equal(py::dtype::of<std::uint16_t>())) return DisparityType::kUint16;
  if (dt.equal(py::dtype("float16"))) return DisparityType::kFloat16;
  throw py::type_error(
      "disparity must have dtype float16, float32, float64, int16 or uint16, got " +
      dtype_str(a));
}

void disparity_to_depth_py(const py::array& disparity, py::array& out, double focal_px,
                           double baseline_m, double doffs_px, double scale, double min_depth_m,
                           double max_depth_m, std::optional<double> invalid_value,
                           std::optional<double> invalid_below, int threads,
                           const std::string& isa) {
  DepthParams p;
  p.focal_px = focal_px;
  p.baseline_m = baseline_m;
  p.doffs_px = doffs_px;
  p.scale = scale;
  p.min_depth_m = min_depth_m;
  p.max_depth_m = max_depth_m;
  p.has_invalid_value = invalid_value.has_value();
  p.invalid_value = invalid_value.value_or(0.0);
  p.has_invalid_below = invalid_below.has_value();
  p.invalid_below = invalid_below.value_or(0.0);

  const Strides s = row_strides(disparity, "disparity");
  DisparityStack in{disparity.data(), disparity_type(disparity), s.frames, s.rows,
                    s.cols,           s.frame_stride,            s.row_stride};
  if (out.ndim() != disparity.ndim() ||
      !std::equal(out.shape(), out.shape() + out.ndim(), disparity.shape())) {
    throw py::value_error("out must have the shape of disparity " + shape_str(disparity) +
                          ", got " + shape_str(out));
  }
  const Isa chosen = resolve_isa(isa);
  const int nthreads = resolve_threads(threads);
  if (out.dtype().equal(py::dtype::of<float>())) {
    auto view = writable_stack<float>(out, "out");
    ReleaseGil release;
    disparity_to_depth(in, view, p, nthreads, chosen);
  } else if (out.dtype().equal(py::dtype::of<std::uint16_t>())) {
    auto view = writable_stack<std::uint16_t>(out, "out");
    ReleaseGil release;
    disparity_to_depth(in, view, p, nthreads, chosen);
  } else {
    throw py::type_error("out must have dtype float32 or uint16, got " + dtype_str(out));
  }
}

}  // namespace

void bind_depth(py::module_& m) {
  m.def("disparity_to_depth", &disparity_to_depth_py, py::arg("disparity"), py::arg("out"),
        py::arg("focal_px"), py::arg("baseline_m"), py::arg("doffs_px"), py::arg("scale"),
        py::arg("min_depth_m"), py::arg("max_depth_m"), py::arg("invalid_value"),
        py::arg("invalid_below"), py::arg("threads"), py::arg("isa") = "auto",
        "Low-level kernel behind stereodepth.disparity_to_depth; writes into `out`.");
}

}  // namespace stereodepth::bindings
