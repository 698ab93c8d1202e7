// Row-band parallelism.
//
// Work is split into contiguous bands of rows, one per thread, each writing its own rows, so
// results never depend on the number of threads.
#pragma once

#include <cstddef>
#include <functional>

namespace stereodepth {

// The number of CPUs this process may run on (its affinity mask), at least 1.
int default_threads();

// 0 means default_threads(); a negative count throws std::invalid_argument.
int resolve_threads(int requested);

// Calls fn(begin, end) on disjoint bands covering [0, rows), on up to `threads` threads (the
// calling thread takes the first band). Fewer threads are used when a band would have fewer
// than `min_rows_per_band` rows. An exception thrown by any band is rethrown here after all
// bands have finished.
void parallel_for_rows(std::ptrdiff_t rows, int threads, std::ptrdiff_t min_rows_per_band,
                       const std::function<void(std::ptrdiff_t, std::ptrdiff_t)>& fn);

}  // namespace stereodepth
