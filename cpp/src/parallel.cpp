#include "stereodepth/parallel.hpp"

#include <algorithm>
#include <exception>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#if defined(__linux__)
#include <sched.h>
#endif

namespace stereodepth {

int default_threads() {
#if defined(__linux__)
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) {
    const int n = CPU_COUNT(&set);
    if (n > 0) return n;
  }
#endif
  const unsigned n = std::thread::hardware_concurrency();
  return n > 0 ? static_cast<int>(n) : 1;
}

int resolve_threads(int requested) {
  if (requested < 0) {
    throw std::invalid_argument("threads must be >= 0 (0 = all cores), got " +
                                std::to_string(requested));
  }
  return requested == 0 ? default_threads() : requested;
}

void parallel_for_rows(std::ptrdiff_t rows, int threads, std::ptrdiff_t min_rows_per_band,
                       const std::function<void(std::ptrdiff_t, std::ptrdiff_t)>& fn) {
  if (rows <= 0) return;
  min_rows_per_band = std::max<std::ptrdiff_t>(min_rows_per_band, 1);
  std::ptrdiff_t bands = std::max(1, threads);
  bands = std::min(bands, std::max<std::ptrdiff_t>(1, rows / min_rows_per_band));
  if (bands == 1) {
    fn(0, rows);
    return;
  }
  auto band_begin = [&](std::ptrdiff_t b) { return rows * b / bands; };
  std::vector<std::exception_ptr> errors(static_cast<std::size_t>(bands));
  std::vector<std::thread> workers;
  workers.reserve(static_cast<std::size_t>(bands - 1));
  for (std::ptrdiff_t b = 1; b < bands; ++b) {
    workers.emplace_back([&, b] {
      try {
        fn(band_begin(b), band_begin(b + 1));
      } catch (...) {
        errors[static_cast<std::size_t>(b)] = std::current_exception();
      }
    });
  }
  try {
    fn(band_begin(0), band_begin(1));
  } catch (...) {
    errors[0] = std::current_exception();
  }
  for (auto& w : workers) w.join();
  for (auto& e : errors) {
    if (e) std::rethrow_exception(e);
  }
}

}  // namespace stereodepth
