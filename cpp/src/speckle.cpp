#include "speckle.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "stereodepth/parallel.hpp"

namespace stereodepth::detail {
namespace {

std::int32_t find_root(std::vector<SpeckleRun>& runs, std::int32_t i) {
  while (runs[static_cast<std::size_t>(i)].parent != i) {
    SpeckleRun& r = runs[static_cast<std::size_t>(i)];
    r.parent = runs[static_cast<std::size_t>(r.parent)].parent;  // path halving
    i = r.parent;
  }
  return i;
}

void unite(std::vector<SpeckleRun>& runs, std::int32_t a, std::int32_t b) {
  const std::int32_t ra = find_root(runs, a), rb = find_root(runs, b);
  if (ra < rb) {
    runs[static_cast<std::size_t>(rb)].parent = ra;
  } else if (rb < ra) {
    runs[static_cast<std::size_t>(ra)].parent = rb;
  }
}

// Calls fn(i) for each column i with a vertical link whose pair of runs (below, above)
// differs from column i - 1's: the link begins there, or a run begins in either row.
template <typename Fn>
void each_new_link(const std::uint64_t* up, const RowStarts& below, const RowStarts& above,
                   std::size_t words, Fn fn) {
  std::uint64_t carry = 0;  // up bit 63 of the previous word
  for (std::size_t w = 0; w < words; ++w) {
    const std::uint64_t shifted = (up[w] << 1) | carry;
    carry = up[w] >> 63;
    std::uint64_t marks = up[w] & (~shifted | below.bits[w] | above.bits[w]);
    while (marks) {
      fn(static_cast<std::ptrdiff_t>(w * 64) + __builtin_ctzll(marks));
      marks &= marks - 1;
    }
  }
}

// Region sizes are kept up to window + 1 (see speckle_band).
std::int64_t speckle_size_cap(int window) {
  return std::min<std::int64_t>(static_cast<std::int64_t>(window) + 1,
                                std::numeric_limits<std::int32_t>::max());
}

}  // namespace

// |a - b| <= range for a float difference is |a - b| <= the largest float not above range.
float speckle_range_f(double range) {
  float rf = static_cast<float>(range);
  if (static_cast<double>(rf) > range) rf = std::nextafter(rf, 0.0f);
  return rf;
}

void speckle_begin(std::ptrdiff_t y0, std::ptrdiff_t cols, SpeckleBand& b) {
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  b.runs.clear();
  b.y0 = y0;
  b.y1 = y0;
  b.row_first.clear();
  b.valid.resize(words);
  b.left.resize(words);
  b.up.resize(words);
}

// Labels rows b.y1 .. y1 - 1 (runs, and unions with the row above inside the band).
void speckle_rows(const BlockMatchKernels& k, const ImageView<float>& disp, std::ptrdiff_t y1,
                  float rf, SpeckleBand& b) {
  const std::ptrdiff_t cols = disp.cols;
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  for (std::ptrdiff_t y = b.y1; y < y1; ++y) {
    const bool below_first = y > b.y0;
    k.speckle_links(disp.row(y), below_first ? disp.row(y - 1) : nullptr, cols, rf,
                    b.valid.data(), b.left.data(), b.up.data());
    b.cur.set(b.valid.data(), b.left.data(), words, static_cast<std::int32_t>(b.runs.size()));
    b.row_first.push_back(static_cast<std::int32_t>(b.runs.size()));
    for (std::size_t w = 0; w < words; ++w) {
      std::uint64_t starts = b.cur.bits[w];
      while (starts) {
        const std::ptrdiff_t x0 = static_cast<std::ptrdiff_t>(w * 64) + __builtin_ctzll(starts);
        starts &= starts - 1;
        // The run ends at the first column after x0 not linked to its left neighbour.
        std::ptrdiff_t x1 = x0 + 1;
        std::size_t ww = static_cast<std::size_t>(x1 >> 6);
        if (ww < words) {
          std::uint64_t open = ~b.left[ww] & (~std::uint64_t{0} << (x1 & 63));
          while (!open && ++ww < words) open = ~b.left[ww];
          x1 = ww < words ? static_cast<std::ptrdiff_t>(ww * 64) + __builtin_ctzll(open) : cols;
        }
        x1 = std::min(x1, cols);
        const auto id = static_cast<std::int32_t>(b.runs.size());
        b.runs.push_back({id, static_cast<std::int32_t>(x0), static_cast<std::int32_t>(x1)});
      }
    }
    if (below_first) {
      each_new_link(b.up.data(), b.cur, b.prev, words, [&](std::ptrdiff_t i) {
        unite(b.runs, b.cur.run_at(i), b.prev.run_at(i));
      });
    } else {
      b.first = b.cur;
    }
    std::swap(b.cur, b.prev);
  }
  b.y1 = std::max(b.y1, y1);
}

// Sizes the band's regions (speckle_finish's step 1, here so that each band does it in its
// own thread): every run links to its root (the band's lowest index in its region, as
// unite() keeps the lower root and path halving only lowers a parent), and each root's parent
// becomes minus the region's size in the band, capped at window + 1 (only "size > window"
// matters, and the cap keeps it in 32 bits).
void speckle_end(int window, SpeckleBand& b) {
  b.row_first.push_back(static_cast<std::int32_t>(b.runs.size()));
  const std::int64_t cap = speckle_size_cap(window);
  auto capped = [&](std::int64_t n) { return static_cast<std::int32_t>(std::min(n, cap)); };
  // A parent is never above its run, so in increasing order each run's parent p has been
  // handled: p is a root (negative) or links to its root directly.
  std::vector<SpeckleRun>& runs = b.runs;
  const auto n = static_cast<std::int32_t>(runs.size());
  for (std::int32_t j = 0; j < n; ++j) {
    SpeckleRun& r = runs[static_cast<std::size_t>(j)];
    const std::int64_t len = r.x1 - r.x0;
    if (r.parent == j) {
      r.parent = -capped(len);
    } else {
      const std::int32_t q = runs[static_cast<std::size_t>(r.parent)].parent;
      if (q >= 0) r.parent = q;
      SpeckleRun& root = runs[static_cast<std::size_t>(r.parent)];
      root.parent = -capped(-static_cast<std::int64_t>(root.parent) + len);
    }
  }
}

// Labels rows y0 .. y1 - 1 and sizes the band's regions: speckle_begin, speckle_rows and
// speckle_end in one call.
void speckle_band(const BlockMatchKernels& k, const ImageView<float>& disp,
                  std::ptrdiff_t y0, std::ptrdiff_t y1, float rf, int window, SpeckleBand& b) {
  speckle_begin(y0, disp.cols, b);
  speckle_rows(k, disp, y1, rf, b);
  speckle_end(window, b);
}

// Joins the labellings (bands[i]: rows starts[i] .. starts[i + 1] - 1) and clears the
// regions of at most `window` pixels.
//
// 1. (Done by speckle_band: each band's regions sized in the band.)
// 2. The vertical links across each boundary between bands pair the two bands' roots; those
//    roots (O(W) per boundary) are united in a small union-find, their sizes summed (capped)
//    and written back to each of them.
// 3. Each run is cleared when its root's size is at most `window`, on up to `threads`
//    threads (bands of rows; each run is read, and each pixel written, by one thread).
void speckle_finish(const BlockMatchKernels& k, const ImageView<float>& disp,
                    const ImageView<float>& conf, int window, float rf,
                    const std::vector<SpeckleBand*>& bands,
                    const std::vector<std::ptrdiff_t>& starts, SpeckleJoin& join, int threads) {
  const std::ptrdiff_t cols = disp.cols;
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  const std::size_t nb = starts.size() - 1;
  const std::int64_t cap = speckle_size_cap(window);
  auto capped = [&](std::int64_t n) { return static_cast<std::int32_t>(std::min(n, cap)); };
  auto root_of = [](const std::vector<SpeckleRun>& runs, std::int32_t j) {
    const std::int32_t p = runs[static_cast<std::size_t>(j)].parent;
    return p < 0 ? j : p;
  };
  // 2.
  std::vector<std::int32_t> offset(nb + 1, 0);
  for (std::size_t i = 0; i < nb; ++i) {
    offset[i + 1] = offset[i] + static_cast<std::int32_t>(bands[i]->runs.size());
  }
  join.pairs.clear();
  for (std::size_t i = 1; i < nb; ++i) {
    SpeckleBand& b = *bands[i];
    const std::ptrdiff_t y = starts[i];
    k.speckle_links(disp.row(y), disp.row(y - 1), cols, rf, b.valid.data(), b.left.data(),
                    b.up.data());
    const RowStarts& below = b.first;
    const RowStarts& above = bands[i - 1]->prev;
    each_new_link(b.up.data(), below, above, words, [&](std::ptrdiff_t x) {
      join.pairs.push_back(offset[i] + root_of(b.runs, below.run_at(x)));
      join.pairs.push_back(offset[i - 1] + root_of(bands[i - 1]->runs, above.run_at(x)));
    });
  }
  if (!join.pairs.empty()) {
    join.ids.assign(join.pairs.begin(), join.pairs.end());
    std::sort(join.ids.begin(), join.ids.end());
    join.ids.erase(std::unique(join.ids.begin(), join.ids.end()), join.ids.end());
    const std::size_t n = join.ids.size();
    auto run = [&](std::int32_t id) -> SpeckleRun& {  // a global run id's run
      const auto band = static_cast<std::size_t>(
          std::upper_bound(offset.begin(), offset.end(), id) - offset.begin() - 1);
      return bands[band]->runs[static_cast<std::size_t>(id - offset[band])];
    };
    auto index = [&](std::int32_t id) {
      return static_cast<std::int32_t>(std::lower_bound(join.ids.begin(), join.ids.end(), id) -
                                       join.ids.begin());
    };
    auto find = [&](std::int32_t a) {
      while (join.parent[static_cast<std::size_t>(a)] != a) {
        std::int32_t& pa = join.parent[static_cast<std::size_t>(a)];
        pa = join.parent[static_cast<std::size_t>(pa)];
        a = pa;
      }
      return a;
    };
    join.parent.resize(n);
    join.size.assign(n, 0);
    for (std::size_t m = 0; m < n; ++m) join.parent[m] = static_cast<std::int32_t>(m);
    for (std::size_t q = 0; q < join.pairs.size(); q += 2) {
      const std::int32_t a = find(index(join.pairs[q])), b = find(index(join.pairs[q + 1]));
      if (a < b) join.parent[static_cast<std::size_t>(b)] = a;
      if (b < a) join.parent[static_cast<std::size_t>(a)] = b;
    }
    for (std::size_t m = 0; m < n; ++m) {
      const auto root = static_cast<std::size_t>(find(static_cast<std::int32_t>(m)));
      join.size[root] = std::min(join.size[root] - run(join.ids[m]).parent, cap);
    }
    for (std::size_t m = 0; m < n; ++m) {
      const auto root = static_cast<std::size_t>(find(static_cast<std::int32_t>(m)));
      run(join.ids[m]).parent = -capped(join.size[root]);
    }
  }
  // 3.
  const float nan = std::numeric_limits<float>::quiet_NaN();
  parallel_for_rows(starts[nb] - starts[0], threads, 64, [&](std::ptrdiff_t a, std::ptrdiff_t e) {
    const std::ptrdiff_t ya = starts[0] + a, ye = starts[0] + e;
    // The band holding row ya, then each row's band in turn.
    auto i = static_cast<std::size_t>(std::upper_bound(starts.begin(), starts.end(), ya) -
                                      starts.begin() - 1);
    for (std::ptrdiff_t y = ya; y < ye; ++y) {
      while (y >= starts[i + 1]) ++i;
      const std::vector<SpeckleRun>& runs = bands[i]->runs;
      const auto row = static_cast<std::size_t>(y - bands[i]->y0);
      const std::int32_t j1 = bands[i]->row_first[row + 1];
      for (std::int32_t j = bands[i]->row_first[row]; j < j1; ++j) {
        const SpeckleRun& r = runs[static_cast<std::size_t>(j)];
        const std::int32_t p =
            r.parent < 0 ? r.parent : runs[static_cast<std::size_t>(r.parent)].parent;
        if (-static_cast<std::int64_t>(p) > window) continue;
        std::fill(disp.row(y) + r.x0, disp.row(y) + r.x1, nan);
        if (conf.data) std::fill(conf.row(y) + r.x0, conf.row(y) + r.x1, 0.0f);
      }
    }
  });
}

}  // namespace stereodepth::detail
