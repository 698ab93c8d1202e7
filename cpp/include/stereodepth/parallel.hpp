// Row-band parallelism.
//
// Work is split into contiguous bands of rows, one per thread, each writing its own rows, so
// results never depend on the number of threads.
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <exception>
#include <functional>
#include <string>
#include <thread>

#if defined(__x86_64__) || defined(__i386__) || defined(_M_X64)
#include <immintrin.h>
#endif

namespace stereodepth {

// The number of CPUs this process may use, at least 1: its affinity mask, lowered to its
// control group's CPU quota when one is set (cgroup_cpu_limit), as a container's
// `--cpus 2` on a 64-core host gives 2, not 64.
int default_threads();

// The CPU quota of this process's control groups, rounded up to whole CPUs, or 0 when none
// is set: cgroup v2 `cpu.max` ("quota period") and cgroup v1 `cpu.cfs_quota_us` over
// `cpu.cfs_period_us`, of the process's group (from /proc/self/cgroup) and each group above
// it, the smallest. The files are read below `root` ("/" for this system; tests give a
// folder laid out the same way). Sources: the kernel's cgroup-v2.rst ("cpu.max") and
// sched-bwc.rst (CFS bandwidth control).
int cgroup_cpu_limit(const std::string& root);

// 0 means default_threads(); a negative count throws std::invalid_argument.
int resolve_threads(int requested);

// Calls fn(begin, end) on disjoint bands covering [0, rows), on up to `threads` threads (the
// calling thread takes the first band). Fewer threads are used when a band would have fewer
// than `min_rows_per_band` rows. An exception thrown by any band is rethrown here after all
// bands have finished.
void parallel_for_rows(std::ptrdiff_t rows, int threads, std::ptrdiff_t min_rows_per_band,
                       const std::function<void(std::ptrdiff_t, std::ptrdiff_t)>& fn);

// Calls fn(b) for b in [0, n), every band on its own thread and all of them at once (the
// calling thread runs band 0), for bands that wait for each other (a barrier at every row):
// parallel_for_rows may run two bands one after the other on one thread, which would never
// return then. Throws std::system_error when the threads cannot be started, and rethrows a
// band's exception like parallel_for_rows.
void run_bands_together(std::ptrdiff_t n, const std::function<void(std::ptrdiff_t)>& fn);

// Spins until done() or `budget` has passed, yielding the CPU every 64 checks (a few
// microseconds), so that a thread with work on the same CPU (more threads than CPUs, or two
// threads the kernel put on one CPU) is not kept waiting for the spin to end. Returns whether
// done() held. Waking a thread that blocked costs tens of microseconds on the virtual
// machines measured, more than many waits inside a call last: the pool's idle workers and the
// semi-global matcher's row barrier spin first, then block.
template <class Done>
bool spin_until(const Done& done, std::chrono::microseconds budget) {
  const auto until = std::chrono::steady_clock::now() + budget;
  for (;;) {
    for (int i = 0; i < 64; ++i) {
      if (done()) return true;
#if defined(__x86_64__) || defined(__i386__) || defined(_M_X64)
      _mm_pause();
#endif
    }
    if (std::chrono::steady_clock::now() >= until) return false;
    std::this_thread::yield();
  }
}

// Stopping a call early (Ctrl-C). A caller that may be interrupted gives its thread a stop
// flag (StopScope); parallel_for_rows and run_bands_together hand the caller's flag to the
// threads that run its bands, and the kernels call throw_if_stopped() between rows, which
// throws Stopped once the flag is set. A call that is not stopped gives the same results.
struct Stopped : std::exception {
  const char* what() const noexcept override { return "stopped: the caller asked it to stop"; }
};

// Sets this thread's stop flag (null: none) for the scope's lifetime.
class StopScope {
 public:
  explicit StopScope(const std::atomic<bool>* flag);
  ~StopScope();
  StopScope(const StopScope&) = delete;
  StopScope& operator=(const StopScope&) = delete;

 private:
  const std::atomic<bool>* saved_;
};

// Whether the call this thread works for was asked to stop.
bool stop_requested();

inline void throw_if_stopped() {
  if (stop_requested()) throw Stopped();
}

}  // namespace stereodepth
