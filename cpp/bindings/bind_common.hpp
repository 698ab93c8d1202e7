// Shared helpers of the binding files: array checks with messages that name the parameter.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <atomic>
#include <optional>
#include <string>

#if defined(__unix__)
#include <signal.h>
#include <unistd.h>
#endif

#include "stereodepth/block_match.hpp"
#include "stereodepth/dispatch.hpp"
#include "stereodepth/image_view.hpp"
#include "stereodepth/parallel.hpp"

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

// Ctrl-C during a long kernel call. Python runs its SIGINT handler (KeyboardInterrupt) only
// when the main thread is back in the interpreter, so a kernel that has released the GIL
// would otherwise finish its work first (seconds for a large semi-global match). For a call
// of at least kMinWork pixels x disparities on the main thread, while Python's handler is
// the default one (signal.default_int_handler), this installs a SIGINT handler that sets the
// call's stop flag (StopScope: the kernels stop within a few rows, throwing Stopped) and then
// calls Python's own C handler, so that KeyboardInterrupt is raised as usual when the call
// returns (the Stopped translator in module.cpp). The previous handler is restored when the
// call ends. Calls from other threads, short calls, and programs with their own SIGINT
// handler (or none) are not affected.
class StopOnCtrlC {
 public:
  static constexpr double kMinWork = 16.0 * 1024 * 1024;

  // With the GIL held.
  explicit StopOnCtrlC(double work) {
#if defined(__unix__)
    if (work < kMinWork || !wanted()) return;
    // Python's C handler, the same function whenever default_int_handler is the Python one.
    if (sigaction(SIGINT, nullptr, &previous()) != 0) return;
    struct sigaction ours {};
    ours.sa_handler = &on_sigint;
    ours.sa_mask = previous().sa_mask;
    ours.sa_flags = previous().sa_flags & SA_ONSTACK;
    stop().store(false, std::memory_order_relaxed);
    if (sigaction(SIGINT, &ours, nullptr) != 0) return;
    installed_ = true;
    scope_.emplace(&stop());
#else
    (void)work;
#endif
  }
  StopOnCtrlC(const StopOnCtrlC&) = delete;
  StopOnCtrlC& operator=(const StopOnCtrlC&) = delete;
  ~StopOnCtrlC() {
#if defined(__unix__)
    if (installed_) sigaction(SIGINT, &previous(), nullptr);
#endif
  }

 private:
#if defined(__unix__)
  // Main thread (threading.main_thread()) and Python's default SIGINT handler.
  static bool wanted() {
    try {
      py::module_ threading = py::module_::import("threading");
      const py::object main_ident = threading.attr("main_thread")().attr("ident");
      if (!main_ident.equal(threading.attr("get_ident")())) return false;
      py::module_ signal = py::module_::import("signal");
      const py::object handler = signal.attr("getsignal")(signal.attr("SIGINT"));
      return handler.is(signal.attr("default_int_handler"));
    } catch (const py::error_already_set&) {
      return false;  // at interpreter shutdown, say: no Ctrl-C handling then
    }
  }
  // Static, not the call's own: a handler running late on another thread must not touch a
  // finished call's memory. Only the main thread makes calls with the handler, one at a time.
  static std::atomic<bool>& stop() {
    static std::atomic<bool> s{false};
    return s;
  }
  static struct sigaction& previous() {
    static struct sigaction p {};
    return p;
  }
  static void on_sigint(int sig) {
    stop().store(true, std::memory_order_relaxed);
    const struct sigaction& prev = previous();
    if (prev.sa_flags & SA_SIGINFO) {
      if (prev.sa_sigaction != nullptr) prev.sa_sigaction(sig, nullptr, nullptr);
    } else if (prev.sa_handler != SIG_DFL && prev.sa_handler != SIG_IGN &&
               prev.sa_handler != nullptr) {
      prev.sa_handler(sig);
    }
  }

  bool installed_ = false;
#endif
  std::optional<StopScope> scope_;
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

// The matchers' shared checks (bind_block_match.cpp): an input image as a StereoImage (an
// (H, W, 3) uint8 one is B, G, R with bgr), channel_order "rgb" or "bgr" as that flag, a
// float32 output as a view, the sub-pixel fit by name.
StereoImage image_view(const py::array& a, const char* name, bool bgr = false);
bool parse_bgr(const std::string& channel_order);
ImageView<float> output_view(py::array& a, const char* name);
SubpixelFit parse_subpixel(const std::string& name);

}  // namespace stereodepth::bindings
