// Shared helpers of the binding files: array checks with messages that name the parameter.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <string>

#include "stereodepth/block_match.hpp"
#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth::bindings {

namespace py = pybind11;

// Releases the GIL for a kernel call, like py::gil_scoped_release, but takes it back in a
// destructor that may throw. At interpreter exit CPython 3.11 ends a daemon thread that asks
// for the GIL back with pthread_exit, which unwinds the thread's stack (abi::__forced_unwind,
// which pybind11 lets through); begun in gil_scoped_release's noexcept destructor, that
// unwinding called std::terminate and the whole process aborted ("terminate called without an
// active exception") whenever a daemon thread was inside a kernel at exit.
class ReleaseGil {
 public:
  ReleaseGil() : state_(PyEval_SaveThread()) {}
  ReleaseGil(const ReleaseGil&) = delete;
  ReleaseGil& operator=(const ReleaseGil&) = delete;
  ~ReleaseGil() noexcept(false) { PyEval_RestoreThread(state_); }

 private:
  PyThreadState* state_;
};

inline std::string shape_str(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) {
    if (i) s += ", ";
    s += std::to_string(a.shape(i));
  }
  if (a.ndim() == 1) s += ",";
  return s + ")";
}

inline std::string dtype_str(const py::array& a) {
  return py::str(a.dtype()).cast<std::string>();
}

// Element strides of a 2-D or 3-D array whose last axis is contiguous; TypeError otherwise.
struct Strides {
  py::ssize_t frames = 1, rows = 0, cols = 0, frame_stride = 0, row_stride = 0;
};

inline Strides row_strides(const py::array& a, const char* name) {
  const py::ssize_t item = a.itemsize();
  if (a.ndim() != 2 && a.ndim() != 3) {
    throw py::value_error(std::string(name) + " must have shape (H, W) or (N, H, W), got " +
                          shape_str(a));
  }
  const int r = a.ndim() - 2;
  Strides s;
  s.frames = a.ndim() == 3 ? a.shape(0) : 1;
  s.rows = a.shape(r);
  s.cols = a.shape(r + 1);
  const bool inner_ok = s.cols <= 1 || a.strides(r + 1) == item;
  const bool outer_ok = a.strides(r) % item == 0 && (a.ndim() == 2 || a.strides(0) % item == 0);
  if (!inner_ok || !outer_ok) {
    throw py::type_error(std::string(name) +
                         " must have contiguous rows (last-axis stride == itemsize)");
  }
  s.row_stride = a.strides(r) / item;
  s.frame_stride = a.ndim() == 3 ? a.strides(0) / item : 0;
  return s;
}

template <typename T>
StackView<T> writable_stack(py::array& out, const char* name) {
  if (!out.writeable()) throw py::value_error(std::string(name) + " must be writeable");
  if (!(out.flags() & py::array::c_style)) {
    throw py::type_error(std::string(name) + " must be C-contiguous");
  }
  const Strides s = row_strides(out, name);
  return StackView<T>{static_cast<T*>(out.mutable_data()), s.frames, s.rows, s.cols,
                      s.frame_stride, s.row_stride};
}

// The matchers' shared checks (bind_block_match.cpp): an input image as a StereoImage, a
// float32 output as a view, the sub-pixel fit by name.
StereoImage image_view(const py::array& a, const char* name);
ImageView<float> output_view(py::array& a, const char* name);
SubpixelFit parse_subpixel(const std::string& name);

}  // namespace stereodepth::bindings
