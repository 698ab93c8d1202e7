#include "stereodepth/parallel.hpp"

#include <algorithm>
#include <exception>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#if defined(__linux__)
#include <sched.h>
#endif

namespace stereodepth {

namespace {

// The first line of a small file, or "" when it cannot be read.
std::string first_line(const std::string& path) {
  std::ifstream f(path);
  std::string line;
  if (f) std::getline(f, line);
  return line;
}

// ceil(quota / period) for positive numbers, else 0 (no limit, or nothing readable).
int quota_cpus(long long quota, long long period) {
  if (quota <= 0 || period <= 0) return 0;
  const long long n = (quota + period - 1) / period;
  return static_cast<int>(std::min<long long>(n, 1 << 20));
}

long long parse_ll(const std::string& text) {
  try {
    std::size_t used = 0;
    const long long v = std::stoll(text, &used);
    return used == text.size() ? v : -1;
  } catch (const std::exception&) {
    return -1;
  }
}

// The group's folder and each folder above it, up to and including `mount`.
std::vector<std::string> group_and_parents(const std::string& mount, std::string path) {
  std::vector<std::string> out;
  while (!path.empty() && path.back() == '/') path.pop_back();
  for (;;) {
    out.push_back(mount + path);
    if (path.empty()) break;
    path.erase(path.rfind('/'));
  }
  return out;
}

// Keeps the smallest positive limit.
void lower(int& limit, int cpus) {
  if (cpus > 0 && (limit == 0 || cpus < limit)) limit = cpus;
}

}  // namespace

int cgroup_cpu_limit(const std::string& root) {
  const std::string base = (!root.empty() && root.back() == '/') ? root.substr(0, root.size() - 1)
                                                                 : root;
  std::ifstream groups(base + "/proc/self/cgroup");
  int limit = 0;
  std::string line;
  while (std::getline(groups, line)) {
    // "hierarchy-id:controllers:path"; cgroup v2 is "0::path".
    const auto a = line.find(':');
    const auto b = a == std::string::npos ? a : line.find(':', a + 1);
    if (b == std::string::npos) continue;
    const std::string id = line.substr(0, a), controllers = line.substr(a + 1, b - a - 1);
    const std::string path = line.substr(b + 1);
    if (path.empty() || path.front() != '/') continue;
    if (id == "0" && controllers.empty()) {
      for (const std::string& dir : group_and_parents(base + "/sys/fs/cgroup", path)) {
        std::istringstream words(first_line(dir + "/cpu.max"));
        std::string quota, period;
        if (words >> quota >> period && quota != "max") {
          lower(limit, quota_cpus(parse_ll(quota), parse_ll(period)));
        }
      }
      continue;
    }
    bool cpu = false;
    std::istringstream names(controllers);
    for (std::string name; std::getline(names, name, ',');) cpu = cpu || name == "cpu";
    if (!cpu) continue;
    for (const char* mount : {"/sys/fs/cgroup/cpu", "/sys/fs/cgroup/cpu,cpuacct",
                              "/sys/fs/cgroup/cpuacct,cpu"}) {
      for (const std::string& dir : group_and_parents(base + mount, path)) {
        lower(limit, quota_cpus(parse_ll(first_line(dir + "/cpu.cfs_quota_us")),
                                parse_ll(first_line(dir + "/cpu.cfs_period_us"))));
      }
    }
  }
  return limit;
}

int default_threads() {
  int n = 0;
#if defined(__linux__)
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) n = CPU_COUNT(&set);
#endif
  if (n <= 0) n = static_cast<int>(std::thread::hardware_concurrency());
  if (n <= 0) n = 1;
#if defined(__linux__)
  // Read once: the quota of a running process seldom changes, and the files cost ~50 us.
  static const int quota = cgroup_cpu_limit("/");
  if (quota > 0) n = std::min(n, quota);
#endif
  return n;
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
