// Binds stereodepth/block_match.hpp: check and convert with the GIL held, then release it.
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bind_common.hpp"
#include "stereodepth/block_match.hpp"
#include "stereodepth/stretch.hpp"

namespace stereodepth::bindings {

// Shared with bind_semi_global.cpp (declared in bind_common.hpp).
SubpixelFit parse_subpixel(const std::string& name) {
  if (name == "none") return SubpixelFit::kNone;
  if (name == "parabola") return SubpixelFit::kParabola;
  if (name == "equiangular") return SubpixelFit::kEquiangular;
  throw py::value_error("subpixel must be 'none', 'parabola' or 'equiangular', got '" + name +
                        "'");
}

bool parse_bgr(const std::string& channel_order) {
  if (channel_order == "rgb") return false;
  if (channel_order == "bgr") return true;
  throw py::value_error("channel_order must be 'rgb' or 'bgr', got '" + channel_order + "'");
}

StereoImage image_view(const py::array& a, const char* name, bool bgr) {
  StereoImage im;
  const bool u8 = a.dtype().equal(py::dtype::of<std::uint8_t>());
  const bool u16 = a.dtype().equal(py::dtype::of<std::uint16_t>());
  if (!u8 && !u16) {
    throw py::type_error(std::string(name) + " must have dtype uint8 or uint16, got " +
                         dtype_str(a));
  }
  if (a.ndim() == 2) {
    im.format = u8 ? PixelFormat::kGrey8 : PixelFormat::kGrey16;
  } else if (a.ndim() == 3 && a.shape(2) == 3 && u8) {
    im.format = bgr ? PixelFormat::kBgr8 : PixelFormat::kRgb8;
  } else {
    throw py::value_error(std::string(name) +
                          " must be (H, W) uint8/uint16 or (H, W, 3) uint8, got shape " +
                          shape_str(a) + " " + dtype_str(a));
  }
  if (!(a.flags() & py::array::c_style)) {
    throw py::type_error(std::string(name) + " must be C-contiguous");
  }
  im.data = a.data();
  im.rows = a.shape(0);
  im.cols = a.shape(1);
  im.row_stride = a.strides(0);
  return im;
}

ImageView<float> output_view(py::array& a, const char* name) {
  if (!a.dtype().equal(py::dtype::of<float>())) {
    throw py::type_error(std::string(name) + " must have dtype float32, got " + dtype_str(a));
  }
  if (a.ndim() != 2) {
    throw py::value_error(std::string(name) + " must be 2-D, got shape " + shape_str(a));
  }
  if (!a.writeable()) throw py::value_error(std::string(name) + " must be writeable");
  if (!(a.flags() & py::array::c_style)) {
    throw py::type_error(std::string(name) + " must be C-contiguous");
  }
  return ImageView<float>{static_cast<float*>(a.mutable_data()), a.shape(0), a.shape(1),
                          a.shape(1)};
}

namespace {

MatchCost parse_cost(const std::string& name) {
  if (name == "census") return MatchCost::kCensus;
  if (name == "sad") return MatchCost::kSad;
  throw py::value_error("cost must be 'census' or 'sad', got '" + name + "'");
}

void compute_py(BlockMatcher& self, const py::array& left, const py::array& right,
                py::array& disparity, const py::object& confidence,
                const std::string& channel_order) {
  const bool bgr = parse_bgr(channel_order);
  const StereoImage l = image_view(left, "left", bgr);
  const StereoImage r = image_view(right, "right", bgr);
  const ImageView<float> d = output_view(disparity, "disparity");
  ImageView<float> c{};
  py::array conf_arr;
  if (!confidence.is_none()) {
    conf_arr = py::reinterpret_borrow<py::array>(confidence);
    c = output_view(conf_arr, "confidence");
  }
  StopOnCtrlC stop(static_cast<double>(l.rows) * static_cast<double>(l.cols) *
                   self.params().num_disparities);
  ReleaseGil release;
  self.compute(l, r, d, c);
}

// Diagnostics (bench/): BlockMatcher::stage_times as a dict of stage name -> seconds.
py::dict stage_times_py(BlockMatcher& self, const py::array& left, const py::array& right,
                        py::array& disparity, int repeats) {
  const StereoImage l = image_view(left, "left");
  const StereoImage r = image_view(right, "right");
  const ImageView<float> d = output_view(disparity, "disparity");
  std::vector<std::pair<std::string, double>> times;
  {
    ReleaseGil release;
    times = self.stage_times(l, r, d, repeats);
  }
  py::dict out;
  for (const auto& [name, seconds] : times) out[py::str(name)] = seconds;
  return out;
}

// Diagnostics (tests): rgb_to_grey of an (H, W, 3) uint8 array with one instruction set.
py::array_t<std::uint8_t> rgb_to_grey_py(const py::array& rgb, const std::string& isa,
                                         const std::string& channel_order) {
  const std::string got = ", got shape " + shape_str(rgb) + " " + dtype_str(rgb);
  if (!rgb.dtype().equal(py::dtype::of<std::uint8_t>())) {
    throw py::type_error("rgb must be (H, W, 3) uint8" + got);
  }
  if (rgb.ndim() != 3 || rgb.shape(2) != 3 || rgb.shape(0) < 1 || rgb.shape(1) < 1) {
    throw py::value_error("rgb must be (H, W, 3) uint8 with H, W >= 1" + got);
  }
  const StereoImage im = image_view(rgb, "rgb", parse_bgr(channel_order));
  const Isa chosen = resolve_isa(isa);
  py::array_t<std::uint8_t> grey({im.rows, im.cols});
  std::uint8_t* out = grey.mutable_data();
  {
    ReleaseGil release;
    rgb_to_grey(im, out, chosen);
  }
  return grey;
}

// A Python or numpy integer (not a bool) as a long long; TypeError naming `name` (with
// `rule`) for anything else, ValueError when it does not fit.
long long integer_of(py::handle v, const std::string& name, const std::string& rule) {
  const bool integral = (py::isinstance<py::int_>(v) && !PyBool_Check(v.ptr())) ||
                        py::isinstance(v, py::module_::import("numpy").attr("integer"));
  if (!integral) {
    throw py::type_error(name + " must be " + rule + ", got " +
                         py::str(py::type::of(v).attr("__name__")).cast<std::string>() + " " +
                         py::repr(v).cast<std::string>());
  }
  int overflow = 0;
  const py::object as_int = py::reinterpret_steal<py::object>(PyNumber_Index(v.ptr()));
  if (!as_int) throw py::error_already_set();
  const long long value = PyLong_AsLongLongAndOverflow(as_int.ptr(), &overflow);
  if (overflow != 0) {
    throw py::value_error(name + " must be " + rule + ", got " + py::repr(v).cast<std::string>());
  }
  return value;
}

// A 2-D C-contiguous uint16 array as a Uint16Image; TypeError / ValueError naming `name`
// (a masked array too: its mask would be ignored).
Uint16Image uint16_view(const py::array& a, const char* name) {
  if (py::isinstance(a, py::module_::import("numpy.ma").attr("MaskedArray"))) {
    throw py::type_error(std::string(name) + " must not be a masked array (its mask would be "
                         "ignored), got MaskedArray");
  }
  const std::string got = ", got shape " + shape_str(a) + " " + dtype_str(a);
  if (!a.dtype().equal(py::dtype::of<std::uint16_t>())) {
    throw py::type_error(std::string(name) + " must be a 2-D uint16 array" + got);
  }
  if (a.ndim() != 2 || a.shape(0) < 1 || a.shape(1) < 1) {
    throw py::value_error(std::string(name) + " must be a 2-D uint16 array with H, W >= 1" +
                          got);
  }
  if (!(a.flags() & py::array::c_style)) {
    throw py::type_error(std::string(name) + " must be C-contiguous");
  }
  return Uint16Image{static_cast<const std::uint16_t*>(a.data()), a.shape(0), a.shape(1),
                     a.shape(1)};
}

// The min-max stretch of a uint16 pair (stretch.hpp) over (lo, hi), or over the pair's joint
// range when intensity_range is None, into new arrays; a constant pair without a range
// returns the inputs themselves (matching.py's stretch_uint16_pair, step 1 of its rules).
py::tuple stretch_uint16_pair_py(const py::array& left, const py::array& right,
                                 const py::object& intensity_range,
                                 const py::object& threads_obj, const std::string& isa) {
  const Isa chosen = resolve_isa(isa);
  const Uint16Image l = uint16_view(left, "left");
  const Uint16Image r = uint16_view(right, "right");
  if (l.rows != r.rows || l.cols != r.cols) {
    throw py::value_error("left and right must have the same shape, got " + shape_str(left) +
                          " and " + shape_str(right));
  }
  const std::string threads_rule = "an int in [0, 2147483647] (0: one per CPU)";
  const long long threads_ll = integer_of(threads_obj, "threads", threads_rule);
  if (threads_ll < 0 || threads_ll > 2147483647LL) {
    throw py::value_error("threads must be " + threads_rule + ", got " +
                          std::to_string(threads_ll));
  }
  const int threads = static_cast<int>(threads_ll);
  // intensity_range: matching.check_intensity_range's rule.
  const std::string range_rule = "None or two integers (lo, hi) with 0 <= lo < hi <= 65535";
  int lo = 0, hi = 0;
  const bool fixed = !intensity_range.is_none();
  if (fixed) {
    const bool pair = (py::isinstance<py::tuple>(intensity_range) ||
                       py::isinstance<py::list>(intensity_range)) &&
                      py::len(intensity_range) == 2;
    if (!pair) {
      throw py::type_error("intensity_range must be " + range_rule + ", got " +
                           py::repr(intensity_range).cast<std::string>());
    }
    const py::sequence seq = intensity_range.cast<py::sequence>();
    long long ends[2];
    for (int i = 0; i < 2; ++i) ends[i] = integer_of(seq[i], "intensity_range", range_rule);
    if (!(0 <= ends[0] && ends[0] < ends[1] && ends[1] <= 65535)) {
      throw py::value_error("intensity_range must be " + range_rule + ", got " +
                            py::repr(intensity_range).cast<std::string>());
    }
    lo = static_cast<int>(ends[0]);
    hi = static_cast<int>(ends[1]);
  }
  py::array_t<std::uint16_t> out_l({l.rows, l.cols}), out_r({r.rows, r.cols});
  std::uint16_t* pl = out_l.mutable_data();
  std::uint16_t* pr = out_r.mutable_data();
  {
    StopOnCtrlC stop(static_cast<double>(l.rows) * static_cast<double>(l.cols));
    ReleaseGil release;
    if (!fixed) joint_range(l, r, threads, chosen, lo, hi);
    if (lo < hi) stretch_uint16_pair(l, r, lo, hi, pl, pr, threads, chosen);
  }
  if (lo == hi) return py::make_tuple(left, right);
  return py::make_tuple(out_l, out_r);
}

}  // namespace

void bind_block_match(py::module_& m) {
  m.def("_stretch_uint16_pair", &stretch_uint16_pair_py, py::arg("left"), py::arg("right"),
        py::arg("intensity_range") = py::none(), py::arg("threads") = 0,
        py::arg("isa") = "auto",
        "The min-max stretch of a uint16 pair, 2-D C-contiguous arrays of one shape, onto "
        "0 .. 65280 (stereodepth.matching.stretch_uint16_pair's rule, the same values): new "
        "arrays, or the inputs themselves for a constant pair without intensity_range. "
        "threads: 0 for one per CPU; isa: one instruction set's kernel (diagnostics).");
  m.def("_rgb_to_grey", &rgb_to_grey_py, py::arg("rgb"), py::arg("isa") = "auto",
        py::arg("channel_order") = "rgb",
        "Diagnostics for the tests: the grey levels the matchers use for an (H, W, 3) uint8 "
        "colour image (R, G, B, or B, G, R with channel_order='bgr'), computed with one "
        "instruction set's kernel.");
  py::class_<BlockMatcher>(m, "BlockMatcher",
                           "Low-level matcher behind stereodepth.StereoMatcher.")
      .def(py::init([](int num_disparities, int min_disparity, int block_size,
                       const std::string& cost, const std::string& subpixel,
                       double uniqueness_ratio, double texture_threshold, double lr_max_diff,
                       int speckle_window, double speckle_range, int threads,
                       const std::string& isa, bool clip_border) {
             BlockMatchParams p;
             p.num_disparities = num_disparities;
             p.min_disparity = min_disparity;
             p.block_size = block_size;
             p.cost = parse_cost(cost);
             p.subpixel = parse_subpixel(subpixel);
             p.uniqueness_ratio = uniqueness_ratio;
             p.texture_threshold = texture_threshold;
             p.lr_max_diff = lr_max_diff;
             p.speckle_window = speckle_window;
             p.speckle_range = speckle_range;
             p.clip_border = clip_border;
             return std::make_unique<BlockMatcher>(p, threads, resolve_isa(isa));
           }),
           py::arg("num_disparities"), py::arg("min_disparity"), py::arg("block_size"),
           py::arg("cost"), py::arg("subpixel"), py::arg("uniqueness_ratio"),
           py::arg("texture_threshold"), py::arg("lr_max_diff"), py::arg("speckle_window"),
           py::arg("speckle_range"), py::arg("threads"), py::arg("isa") = "auto",
           py::arg("clip_border") = true)
      .def("compute", &compute_py, py::arg("left"), py::arg("right"), py::arg("disparity"),
           py::arg("confidence") = py::none(), py::arg("channel_order") = "rgb",
           "Writes the disparity (and the confidence, unless None) of left; (H, W, 3) images "
           "are R, G, B, or B, G, R with channel_order='bgr'.")
      .def("_stage_times", &stage_times_py, py::arg("left"), py::arg("right"),
           py::arg("disparity"), py::arg("repeats") = 5,
           "Diagnostics for bench/: each stage timed alone on one thread (seconds, the least "
           "of `repeats` runs); see BlockMatcher::stage_times in block_match.hpp.")
      .def_property_readonly("threads", &BlockMatcher::threads)
      .def_property_readonly("isa", [](const BlockMatcher& self) { return isa_name(self.isa()); });
}

}  // namespace stereodepth::bindings
