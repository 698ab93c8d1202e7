// Binds stereodepth/rectify.hpp and stereodepth/remap.hpp: check and convert with the GIL
// held, then release it for the per-pixel work.
#include <memory>
#include <string>

#include <pybind11/stl.h>

#include "bind_common.hpp"
#include "stereodepth/parallel.hpp"
#include "stereodepth/rectify.hpp"
#include "stereodepth/remap.hpp"

namespace stereodepth::bindings {

namespace {

using Doubles = py::array_t<double, py::array::c_style | py::array::forcecast>;
using Floats = py::array_t<float, py::array::c_style>;

DistortionModel parse_model(const std::string& name) {
  if (name == "none") return DistortionModel::kNone;
  if (name == "plumb_bob") return DistortionModel::kPlumbBob;
  if (name == "equidistant") return DistortionModel::kEquidistant;
  throw py::value_error("distortion model must be 'none', 'plumb_bob' or 'equidistant', got '" +
                        name + "'");
}

Eigen::Matrix3d mat3(const Doubles& a, const char* name) {
  if (a.ndim() != 2 || a.shape(0) != 3 || a.shape(1) != 3) {
    throw py::value_error(std::string(name) + " must have shape (3, 3), got " + shape_str(a));
  }
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m(r, c) = a.at(r, c);
  }
  return m;
}

CameraModel camera(const Doubles& K, const Doubles& D, const std::string& model,
                   const char* name) {
  CameraModel cam;
  cam.K = mat3(K, name);
  cam.model = parse_model(model);
  if (D.ndim() != 1 || D.shape(0) > 8) {
    throw py::value_error(std::string(name) +
                          " distortion must be 1-D with at most 8 entries, got " + shape_str(D));
  }
  for (py::ssize_t i = 0; i < D.shape(0); ++i) cam.d[static_cast<std::size_t>(i)] = D.at(i);
  return cam;
}

template <typename M>
py::array_t<double> to_numpy(const M& m) {
  py::array_t<double> out({static_cast<py::ssize_t>(m.rows()), static_cast<py::ssize_t>(m.cols())});
  auto v = out.mutable_unchecked<2>();
  for (py::ssize_t r = 0; r < m.rows(); ++r) {
    for (py::ssize_t c = 0; c < m.cols(); ++c) v(r, c) = m(r, c);
  }
  return out;
}

py::tuple rect_tuple(const Rect& r) { return py::make_tuple(r.x, r.y, r.width, r.height); }

// T as a 3-vector; ValueError naming it otherwise.
Eigen::Vector3d vec3(const Doubles& v, const char* name) {
  if (v.size() != 3) {
    throw py::value_error(std::string(name) + " must have 3 entries, got " + shape_str(v));
  }
  return Eigen::Vector3d(v.data()[0], v.data()[1], v.data()[2]);
}

// R1, R2, P1, P2, Q and the ROIs as numpy arrays and tuples, for the Python side.
py::dict rectification_dict(const StereoRectification& r, bool vertical) {
  py::dict out;
  out["R1"] = to_numpy(r.R1);
  out["R2"] = to_numpy(r.R2);
  out["P1"] = to_numpy(r.P1);
  out["P2"] = to_numpy(r.P2);
  out["Q"] = to_numpy(r.Q);
  out["roi1"] = rect_tuple(r.roi1);
  out["roi2"] = rect_tuple(r.roi2);
  out["vertical"] = vertical;
  return out;
}

py::dict stereo_rectify_py(const Doubles& K1, const Doubles& D1, const Doubles& K2,
                           const Doubles& D2, const std::string& model, int width, int height,
                           const Doubles& R, const Doubles& T, double alpha, int new_width,
                           int new_height, bool zero_disparity) {
  const CameraModel c1 = camera(K1, D1, model, "K1");
  const CameraModel c2 = camera(K2, D2, model, "K2");
  const Eigen::Matrix3d Rm = mat3(R, "R");
  const Eigen::Vector3d Tv = vec3(T, "T");
  StereoRectifyParams p;
  p.alpha = alpha;
  p.new_width = new_width;
  p.new_height = new_height;
  p.zero_disparity = zero_disparity;
  StereoRectification r;
  {
    ReleaseGil release;
    r = stereo_rectify(c1, c2, width, height, Rm, Tv, p);
  }
  return rectification_dict(r, r.vertical);
}

py::dict fisheye_stereo_rectify_py(const Doubles& K1, const Doubles& D1, const Doubles& K2,
                                   const Doubles& D2, int width, int height, const Doubles& R,
                                   const Doubles& T, double balance, double fov_scale,
                                   int new_width, int new_height, bool zero_disparity) {
  const CameraModel c1 = camera(K1, D1, "equidistant", "K1");
  const CameraModel c2 = camera(K2, D2, "equidistant", "K2");
  const Eigen::Matrix3d Rm = mat3(R, "R");
  const Eigen::Vector3d Tv = vec3(T, "T");
  FisheyeRectifyParams p;
  p.balance = balance;
  p.fov_scale = fov_scale;
  p.new_width = new_width;
  p.new_height = new_height;
  p.zero_disparity = zero_disparity;
  StereoRectification r;
  {
    ReleaseGil release;
    r = fisheye_stereo_rectify(c1, c2, width, height, Rm, Tv, p);
  }
  return rectification_dict(r, false);
}

py::array_t<double> undistort_points_py(const Doubles& K, const Doubles& D,
                                        const std::string& model, const Doubles& points) {
  const CameraModel cam = camera(K, D, model, "K");
  if (points.ndim() != 2 || points.shape(1) != 2) {
    throw py::value_error("points must have shape (N, 2), got " + shape_str(points));
  }
  validate(cam, "K");
  py::array_t<double> out({points.shape(0), py::ssize_t{2}});
  auto in = points.unchecked<2>();
  auto o = out.mutable_unchecked<2>();
  for (py::ssize_t i = 0; i < points.shape(0); ++i) {
    const Eigen::Vector2d p = undistort_point(cam, in(i, 0), in(i, 1));
    o(i, 0) = p.x();
    o(i, 1) = p.y();
  }
  return out;
}

ImageView<float> float_view(Floats& a, const char* name) {
  if (a.ndim() != 2) {
    throw py::value_error(std::string(name) + " must be 2-D, got shape " + shape_str(a));
  }
  if (!a.writeable()) throw py::value_error(std::string(name) + " must be writeable");
  return ImageView<float>{a.mutable_data(), a.shape(0), a.shape(1), a.shape(1)};
}

void init_undistort_rectify_map_py(const Doubles& K, const Doubles& D, const std::string& model,
                                   const Doubles& R, const Doubles& P, Floats& map_x,
                                   Floats& map_y, int threads) {
  const CameraModel cam = camera(K, D, model, "K");
  const Eigen::Matrix3d Rm = mat3(R, "R");
  const Eigen::Matrix3d Pm = mat3(P, "P");
  const ImageView<float> mx = float_view(map_x, "map_x");
  const ImageView<float> my = float_view(map_y, "map_y");
  const int n = resolve_threads(threads);
  ReleaseGil release;
  init_undistort_rectify_map(cam, Rm, Pm, mx, my, n);
}

void apply_py(const RemapTable& self, const py::array& src, py::array& out, int threads,
              const std::string& isa) {
  const StereoImage s = image_view(src, "image");
  const StereoImage o = image_view(out, "out");
  if (o.format != s.format || o.rows != self.rows() || o.cols != self.cols()) {
    throw py::value_error("out must have the maps' shape and the image's dtype, got " +
                          shape_str(out) + " " + dtype_str(out));
  }
  if (!out.writeable()) throw py::value_error("out must be writeable");
  const Isa chosen = resolve_isa(isa);
  const int n = resolve_threads(threads);
  void* dst = out.mutable_data();
  ReleaseGil release;
  self.apply(s, dst, o.row_stride, n, chosen);
}

}  // namespace

void bind_rectify(py::module_& m) {
  m.def("stereo_rectify", &stereo_rectify_py, py::arg("K1"), py::arg("D1"), py::arg("K2"),
        py::arg("D2"), py::arg("model"), py::arg("width"), py::arg("height"), py::arg("R"),
        py::arg("T"), py::arg("alpha"), py::arg("new_width"), py::arg("new_height"),
        py::arg("zero_disparity"), "Low-level kernel behind stereodepth.stereo_rectify.");
  m.def("fisheye_stereo_rectify", &fisheye_stereo_rectify_py, py::arg("K1"), py::arg("D1"),
        py::arg("K2"), py::arg("D2"), py::arg("width"), py::arg("height"), py::arg("R"),
        py::arg("T"), py::arg("balance"), py::arg("fov_scale"), py::arg("new_width"),
        py::arg("new_height"), py::arg("zero_disparity"),
        "Low-level kernel behind stereodepth.stereo_rectify for equidistant cameras.");
  m.def("undistort_points", &undistort_points_py, py::arg("K"), py::arg("D"), py::arg("model"),
        py::arg("points"), "Distorted pixels (N, 2) to ideal normalized coordinates (N, 2).");
  m.def("init_undistort_rectify_map", &init_undistort_rectify_map_py, py::arg("K"), py::arg("D"),
        py::arg("model"), py::arg("R"), py::arg("P"), py::arg("map_x"), py::arg("map_y"),
        py::arg("threads"),
        "Low-level kernel behind stereodepth.init_undistort_rectify_map; writes the maps.");
  py::class_<RemapTable>(m, "RemapTable", "Low-level remap table behind stereodepth.remap.")
      .def(py::init([](const Floats& map_x, const Floats& map_y, py::ssize_t src_rows,
                       py::ssize_t src_cols, const std::string& precision, int threads) {
             RemapPrecision prec;
             if (precision == "fixed") {
               prec = RemapPrecision::kFixed;
             } else if (precision == "float") {
               prec = RemapPrecision::kFloat;
             } else {
               throw py::value_error("precision must be 'fixed' (8-bit images) or 'float' "
                                     "(16-bit), got '" + precision + "'");
             }
             if (map_x.ndim() != 2 || map_y.ndim() != 2) {
               throw py::value_error("map_x and map_y must be 2-D");
             }
             const ImageView<const float> mx{map_x.data(), map_x.shape(0), map_x.shape(1),
                                             map_x.shape(1)};
             const ImageView<const float> my{map_y.data(), map_y.shape(0), map_y.shape(1),
                                             map_y.shape(1)};
             const int n = resolve_threads(threads);
             ReleaseGil release;
             return std::make_unique<RemapTable>(mx, my, src_rows, src_cols, prec, n);
           }),
           py::arg("map_x"), py::arg("map_y"), py::arg("src_rows"), py::arg("src_cols"),
           py::arg("precision"), py::arg("threads"))
      .def("apply", &apply_py, py::arg("image"), py::arg("out"), py::arg("threads"),
           py::arg("isa") = "auto", "Samples image into out (the maps' shape, image's dtype).")
      .def_property_readonly("shape",
                             [](const RemapTable& t) { return py::make_tuple(t.rows(), t.cols()); })
      .def_property_readonly("source_shape",
                             [](const RemapTable& t) {
                               return py::make_tuple(t.src_rows(), t.src_cols());
                             })
      .def_property_readonly("precision", [](const RemapTable& t) {
        return t.precision() == RemapPrecision::kFixed ? "fixed" : "float";
      });
}

}  // namespace stereodepth::bindings
