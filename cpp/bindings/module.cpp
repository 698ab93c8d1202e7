// The module's table of contents: one bind_<area>() per header of the core.
#include <pybind11/stl.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "bind_common.hpp"
#include "stereodepth/dispatch.hpp"
#include "stereodepth/parallel.hpp"

#ifndef STEREODEPTH_VERSION
#define STEREODEPTH_VERSION "0.0.0"
#endif

namespace stereodepth::bindings {
void bind_depth(py::module_& m);
void bind_block_match(py::module_& m);
void bind_semi_global(py::module_& m);
void bind_reproject(py::module_& m);
void bind_rectify(py::module_& m);
}  // namespace stereodepth::bindings

namespace {

std::string compiler() {
#if defined(__clang__)
  return std::string("clang ") + __clang_version__;
#elif defined(__GNUC__)
  return std::string("gcc ") + __VERSION__;
#elif defined(_MSC_VER)
  return "msvc " + std::to_string(_MSC_VER);
#else
  return "unknown";
#endif
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  namespace py = pybind11;
  using namespace stereodepth;
  m.doc() = "stereodepth's compiled core. Use the functions of the stereodepth package instead.";
  m.attr("__version__") = STEREODEPTH_VERSION;

  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const std::invalid_argument& e) {
      PyErr_SetString(PyExc_ValueError, e.what());
    } catch (const stereodepth::Stopped&) {
      // Ctrl-C stopped the kernel (StopOnCtrlC): Python's handler, run now, raises
      // KeyboardInterrupt; should it not raise, KeyboardInterrupt all the same, as the
      // call has no result.
      if (PyErr_CheckSignals() == 0 && !PyErr_Occurred()) PyErr_SetNone(PyExc_KeyboardInterrupt);
    }
  });

  m.def("build_info", [] {
    py::dict info;
    info["version"] = STEREODEPTH_VERSION;
    info["compiler"] = compiler();
    info["isa"] = isa_name(default_isa());
    std::vector<std::string> isas;
    for (Isa isa : supported_isas()) isas.emplace_back(isa_name(isa));
    info["supported_isas"] = isas;
    info["default_threads"] = default_threads();
    info["eigen"] = std::to_string(EIGEN_WORLD_VERSION) + "." +
                    std::to_string(EIGEN_MAJOR_VERSION) + "." +
                    std::to_string(EIGEN_MINOR_VERSION);
    info["pybind11"] = std::to_string(PYBIND11_VERSION_MAJOR) + "." +
                       std::to_string(PYBIND11_VERSION_MINOR) + "." +
                       std::to_string(PYBIND11_VERSION_PATCH);
#if defined(__SANITIZE_ADDRESS__)
    info["sanitizers"] = true;
#else
    info["sanitizers"] = false;
#endif
    return info;
  });

  m.def("_cgroup_cpu_limit", &cgroup_cpu_limit, py::arg("root"),
        "The control groups' CPU quota read below root, in whole CPUs; 0 for none (tests).");

  bindings::bind_depth(m);
  bindings::bind_block_match(m);
  bindings::bind_semi_global(m);
  bindings::bind_reproject(m);
  bindings::bind_rectify(m);
}
