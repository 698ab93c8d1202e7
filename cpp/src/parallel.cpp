#include "stereodepth/parallel.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <fstream>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <system_error>
#include <string>
#include <thread>
#include <vector>

#if defined(__linux__)
#include <sched.h>
#endif
#if defined(__unix__)
#include <pthread.h>
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

namespace {

// The stop flag of the call this thread works for (StopScope).
thread_local const std::atomic<bool>* t_stop = nullptr;

}  // namespace

StopScope::StopScope(const std::atomic<bool>* flag) : saved_(t_stop) { t_stop = flag; }

StopScope::~StopScope() { t_stop = saved_; }

bool stop_requested() {
  const std::atomic<bool>* f = t_stop;
  return f != nullptr && f->load(std::memory_order_relaxed);
}

namespace {

// How long an idle thread of the pool (and a caller waiting for its bands) spins before it
// sleeps on a condition variable (spin_until): waking a sleeping thread costs 10 to 40 us on
// the virtual machines measured (the host puts an idle vCPU to sleep). With 2 threads, a call
// paid that at every parallel step, and a 10 us pause before a call (Python's own work, as in
// the one-shot functions) made it 17 us slower, 20 us made it 40 us slower (AMD EPYC guest,
// block matching Tsukuba, a 0.5 ms call; bench/README, twentieth round). OpenMP runtimes spin
// for the same reason, for far longer (GOMP_SPINCOUNT, KMP_BLOCKTIME's 200 ms).
constexpr std::chrono::microseconds kSpin{200};

// Threads running bands or spinning, of every call, may not exceed the CPUs this process may
// use: a thread spins only on a CPU no band needs (with more bands than CPUs, as with several
// calls at once, nobody spins).
int cpu_count() {
  static const int n = default_threads();
  return n;
}

// Spins for kSpin at most (spin_until) when `active` leaves a CPU free for it, counting itself
// in `active` meanwhile.
template <class Done>
void spin_if_idle(std::atomic<int>& active, const Done& done) {
  if (active.fetch_add(1) < cpu_count()) spin_until(done, kSpin);
  active.fetch_sub(1);
}

// The bands of one parallel_for_rows call. Bands are claimed in order through `next`, by the
// pool's workers and by the calling thread alike, so that the caller runs every band no worker
// has started: a call never waits for a band to be picked up, only for bands already running
// (hence no deadlock when a band itself calls parallel_for_rows, or when every worker is busy
// with other callers' bands).
struct Job {
  const std::function<void(std::ptrdiff_t, std::ptrdiff_t)>* fn = nullptr;
  const std::atomic<bool>* stop = nullptr;  // the caller's stop flag, for every band
  std::atomic<int>* active = nullptr;       // the pool's count of busy threads
  std::ptrdiff_t rows = 0, bands = 0;
  std::atomic<std::ptrdiff_t> next{1};  // band 0 is the caller's
  std::atomic<std::ptrdiff_t> done{0};  // bands 1 .. bands - 1 finished
  int users = 0;                        // workers inside run_claimed (under the pool's mutex)
  std::vector<std::exception_ptr> errors;

  std::ptrdiff_t begin(std::ptrdiff_t b) const { return rows * b / bands; }
  void run(std::ptrdiff_t b) {
    active->fetch_add(1);
    try {
      StopScope scope(stop);
      (*fn)(begin(b), begin(b + 1));
    } catch (...) {
      errors[static_cast<std::size_t>(b)] = std::current_exception();
    }
    active->fetch_sub(1);
  }
  void run_claimed() {
    for (std::ptrdiff_t b = next.fetch_add(1); b < bands; b = next.fetch_add(1)) {
      run(b);
      done.fetch_add(1);
    }
  }
  bool open() const { return next.load() < bands; }
};

// Worker threads kept between calls: starting and joining a std::thread per call cost 30 to
// 75 us on the virtual machines measured, and the semi-global matcher has three parallel
// steps per call (paths 4 and 8 more). Workers are started on demand, up to the most bands
// any call asked for less one, but at most max_workers() (more threads than CPUs gain nothing;
// a call with more bands runs the rest on its own thread, with the same results; bands that
// must run at once, run_bands_together, get a thread each whatever their number), and, when
// there is no work, spin for kSpin on a CPU no band needs, then wait on a condition variable.
// They are detached and never stopped; the pool is never destroyed (a static destructor
// joining threads at interpreter exit could wait forever).
struct Pool {
  std::mutex m;
  std::condition_variable work;  // a job was queued
  std::condition_variable left;  // a worker left a job
  std::deque<Job*> jobs;         // jobs that may still have unclaimed bands
  int workers = 0;
  std::atomic<std::uint64_t> queued{0};  // jobs queued so far (changed under m)
  std::atomic<int> active{0};            // threads running a band or spinning

  Job* open_job() {
    for (Job* j : jobs) {
      if (j->open()) return j;
    }
    return nullptr;
  }
  void worker() {
    std::unique_lock<std::mutex> lock(m);
    for (;;) {
      Job* j = open_job();
      if (j == nullptr) {
        // Spin a little before sleeping, so that the next step of a call (or the next call)
        // finds this thread awake.
        const std::uint64_t seen = queued.load(std::memory_order_relaxed);
        lock.unlock();
        spin_if_idle(active, [&] { return queued.load(std::memory_order_acquire) != seen; });
        lock.lock();
        work.wait(lock, [&] { return (j = open_job()) != nullptr; });
      }
      ++j->users;
      lock.unlock();
      j->run_claimed();
      lock.lock();
      --j->users;
      left.notify_all();
    }
  }
  // Up to n workers (fewer if the system refuses threads: the callers then run more bands);
  // whether there are n.
  bool grow(std::ptrdiff_t n) {
    while (workers < n) {
      try {
        std::thread([this] { worker(); }).detach();
      } catch (const std::system_error&) {
        return false;
      }
      ++workers;
    }
    return true;
  }
};

// Twice the CPUs, at least 8.
int max_workers() {
  static const int n = std::max(8, 2 * static_cast<int>(std::thread::hardware_concurrency()));
  return n;
}

Pool* g_pool = nullptr;
std::once_flag g_pool_once;

Pool& pool() {
  std::call_once(g_pool_once, [] {
    g_pool = new Pool;
#if defined(__unix__)
    // fork(): the child has none of the workers (only the forking thread is copied), and the
    // pool's mutex must not be copied while another thread holds it. The parent holds it
    // across the fork; the child starts a new, empty pool and abandons the old one.
    pthread_atfork([] { g_pool->m.lock(); }, [] { g_pool->m.unlock(); },
                   [] { g_pool = new Pool; });
#endif
  });
  return *g_pool;
}

void run_job(std::ptrdiff_t rows, std::ptrdiff_t bands, bool together,
             const std::function<void(std::ptrdiff_t, std::ptrdiff_t)>& fn) {
  Job job;
  job.fn = &fn;
  job.stop = t_stop;
  job.rows = rows;
  job.bands = bands;
  job.errors.resize(static_cast<std::size_t>(bands));
  Pool& p = pool();
  job.active = &p.active;
  {
    std::lock_guard<std::mutex> lock(p.m);
    // A `together` job's bands wait for each other, so each needs a thread of its own: with
    // fewer than bands - 1 workers (the system refused threads) the caller's band would wait
    // for a band no thread can take, forever. With enough, every band gets one: an idle
    // worker takes the first job in the queue with an unclaimed band, so a worker runs a
    // later job's band only once every earlier job's bands are all claimed, and those finish
    // (no band of a job waits for a later job).
    if (!p.grow(together ? bands - 1 : std::min<std::ptrdiff_t>(bands - 1, max_workers())) &&
        together) {
      throw std::system_error(std::make_error_code(std::errc::resource_unavailable_try_again),
                              "cannot start a thread for each of the " + std::to_string(bands) +
                                  " bands that must run at once");
    }
    p.jobs.push_back(&job);
    p.queued.fetch_add(1, std::memory_order_release);
  }
  for (std::ptrdiff_t b = 1; b < bands; ++b) p.work.notify_one();
  job.run(0);
  job.run_claimed();
  // The bands still running mostly end within microseconds of the caller's: spin for them
  // rather than sleep at once (a woken thread starts late, above).
  spin_if_idle(p.active, [&] { return job.done.load(std::memory_order_acquire) == bands - 1; });
  {
    // Every band is claimed now; wait for those still running, and for every worker to have
    // left the job (none may touch it once this call returns).
    std::unique_lock<std::mutex> lock(p.m);
    p.jobs.erase(std::find(p.jobs.begin(), p.jobs.end(), &job));
    p.left.wait(lock, [&] { return job.done.load() == bands - 1 && job.users == 0; });
  }
  for (auto& e : job.errors) {
    if (e) std::rethrow_exception(e);
  }
}

}  // namespace

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
  run_job(rows, bands, false, fn);
}

void run_bands_together(std::ptrdiff_t n, const std::function<void(std::ptrdiff_t)>& fn) {
  if (n <= 0) return;
  if (n == 1) {
    fn(0);
    return;
  }
  run_job(n, n, true, [&](std::ptrdiff_t b0, std::ptrdiff_t b1) {
    for (std::ptrdiff_t b = b0; b < b1; ++b) fn(b);
  });
}

}  // namespace stereodepth
