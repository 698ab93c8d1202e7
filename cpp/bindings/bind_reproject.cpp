// Binds stereodepth/reproject.hpp: check and convert with the GIL held, then release it.
#include <algorithm>
#include <optional>
#include <string>

#include <pybind11/stl.h>

#include "bind_common.hpp"
#include "stereodepth/parallel.hpp"
#include "stereodepth/reproject.hpp"

namespace stereodepth::bindings {

namespace {

// dtype::equal, not dtype::is: an array that went through pickle (multiprocessing, Dask)
// carries an equal dtype object that is not numpy's canonical instance.
DisparityType reproject_input_type(const py::array& a) {
  const auto dt = a.dtype();
  if (dt.equal(py::dtype::of<float>())) return DisparityType::kFloat32;
  if (dt.equal(py::dtype::of<double>())) return DisparityType::kFloat64;
  if (dt.equal(py::dtype::of<std::int16_t>())) return DisparityType::kInt16;
  if (dt.equal(py::dtype::of<std::uint16_t>())) return DisparityType::kUint16;
  throw py::type_error("disparity must have dtype float32, float64, int16 or uint16, got " +
                       dtype_str(a));
}

void reproject_py(const py::array& disparity, py::array& out, const py::array& q, double scale,
                  double min_depth, double max_depth, std::optional<double> invalid_value,
                  std::optional<double> invalid_below, int threads, const std::string& isa) {
  ReprojectParams p;
  if (!q.dtype().equal(py::dtype::of<double>()) || q.ndim() != 2 || q.shape(0) != 4 ||
      q.shape(1) != 4) {
    throw py::value_error("Q must be a 4x4 float64 array, got " + shape_str(q) + " " +
                          dtype_str(q));
  }
  auto qv = q.unchecked<double, 2>();
  for (py::ssize_t r = 0; r < 4; ++r) {
    for (py::ssize_t c = 0; c < 4; ++c) p.q[r * 4 + c] = qv(r, c);
  }
  p.scale = scale;
  p.min_depth = min_depth;
  p.max_depth = max_depth;
  p.has_invalid_value = invalid_value.has_value();
  p.invalid_value = invalid_value.value_or(0.0);
  p.has_invalid_below = invalid_below.has_value();
  p.invalid_below = invalid_below.value_or(0.0);

  const Strides s = row_strides(disparity, "disparity");
  const DisparityStack in{disparity.data(), reproject_input_type(disparity), s.frames, s.rows,
                          s.cols,           s.frame_stride,                  s.row_stride};
  const bool shape_ok =
      out.ndim() == disparity.ndim() + 1 && out.shape(out.ndim() - 1) == 3 &&
      std::equal(disparity.shape(), disparity.shape() + disparity.ndim(), out.shape());
  if (!shape_ok) {
    throw py::value_error("out must have shape " + shape_str(disparity) + " + (3,), got " +
                          shape_str(out));
  }
  if (!out.dtype().equal(py::dtype::of<float>())) {
    throw py::type_error("out must have dtype float32, got " + dtype_str(out));
  }
  if (!out.writeable()) throw py::value_error("out must be writeable");
  if (!(out.flags() & py::array::c_style)) throw py::type_error("out must be C-contiguous");
  const StackView<float> view{static_cast<float*>(out.mutable_data()), s.frames, s.rows,
                              3 * s.cols, s.rows * 3 * s.cols, 3 * s.cols};
  const Isa chosen = resolve_isa(isa);
  const int nthreads = resolve_threads(threads);
  ReleaseGil release;
  reproject(in, view, p, nthreads, chosen);
}

}  // namespace

void bind_reproject(py::module_& m) {
  m.def("reproject", &reproject_py, py::arg("disparity"), py::arg("out"), py::arg("q"),
        py::arg("scale"), py::arg("min_depth"), py::arg("max_depth"), py::arg("invalid_value"),
        py::arg("invalid_below"), py::arg("threads"), py::arg("isa") = "auto",
        "Low-level kernel behind stereodepth.reproject; writes into `out`.");
}

}  // namespace stereodepth::bindings
