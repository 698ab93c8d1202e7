// Binds stereodepth/semi_global.hpp: check and convert with the GIL held, then release it.
#include <memory>
#include <string>

#include "bind_common.hpp"
#include "stereodepth/semi_global.hpp"

namespace stereodepth::bindings {

namespace {

void compute_py(SemiGlobalMatcher& self, const py::array& left, const py::array& right,
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

}  // namespace

void bind_semi_global(py::module_& m) {
  py::class_<SemiGlobalMatcher>(m, "SemiGlobalMatcher",
                                "Low-level matcher behind stereodepth.SemiGlobalMatcher.")
      .def(py::init([](int num_disparities, int min_disparity, int block_size, int p1, int p2,
                       int p2_step, int paths, const std::string& subpixel,
                       double uniqueness_ratio, double lr_max_diff, bool median,
                       int speckle_window, double speckle_range, bool clip_border,
                       double max_memory_mb, int threads, const std::string& isa) {
             SemiGlobalParams p;
             p.num_disparities = num_disparities;
             p.min_disparity = min_disparity;
             p.block_size = block_size;
             p.p1 = p1;
             p.p2 = p2;
             p.p2_step = p2_step;
             p.paths = paths;
             p.subpixel = parse_subpixel(subpixel);
             p.uniqueness_ratio = uniqueness_ratio;
             p.lr_max_diff = lr_max_diff;
             p.median = median;
             p.speckle_window = speckle_window;
             p.speckle_range = speckle_range;
             p.clip_border = clip_border;
             p.max_memory_mb = max_memory_mb;
             return std::make_unique<SemiGlobalMatcher>(p, threads, resolve_isa(isa));
           }),
           py::arg("num_disparities"), py::arg("min_disparity"), py::arg("block_size"),
           py::arg("p1"), py::arg("p2"), py::arg("p2_step"), py::arg("paths"),
           py::arg("subpixel"), py::arg("uniqueness_ratio"), py::arg("lr_max_diff"),
           py::arg("median"), py::arg("speckle_window"), py::arg("speckle_range"),
           py::arg("clip_border"), py::arg("max_memory_mb"), py::arg("threads"),
           py::arg("isa") = "auto")
      .def("compute", &compute_py, py::arg("left"), py::arg("right"), py::arg("disparity"),
           py::arg("confidence") = py::none(), py::arg("channel_order") = "rgb",
           "Writes the disparity (and the confidence, unless None) of left; (H, W, 3) images "
           "are R, G, B, or B, G, R with channel_order='bgr'.")
      .def(
          "check_size",
          [](const SemiGlobalMatcher& self, std::ptrdiff_t rows, std::ptrdiff_t cols) {
            self.check_memory(rows, cols);
          },
          py::arg("rows"), py::arg("cols"),
          "Raises ValueError when a rows x cols pair would need more than max_memory_mb.")
      .def_property_readonly("threads", &SemiGlobalMatcher::threads)
      .def_property_readonly("isa",
                             [](const SemiGlobalMatcher& self) { return isa_name(self.isa()); });
  m.def("_sgm_column_bands_for_tests", &set_column_bands_for_tests, py::arg("on"),
        "Tests only: paths 4 and 8 on two threads split the columns (as 3+ threads do).");
  m.def(
      "semi_global_memory",
      [](std::ptrdiff_t rows, std::ptrdiff_t cols, int num_disparities, int paths, int threads,
         const std::string& isa, int block_size) {
        return semi_global_memory(rows, cols, num_disparities, paths, threads, resolve_isa(isa),
                                  block_size);
      },
      py::arg("rows"), py::arg("cols"), py::arg("num_disparities"), py::arg("paths"),
      py::arg("threads"), py::arg("isa") = "auto", py::arg("block_size") = 3,
      "Bytes a semi-global match of a rows x cols pair allocates with the kernels of isa.");
}

}  // namespace stereodepth::bindings
