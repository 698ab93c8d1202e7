#include "speckle.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

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

}  // namespace

// |a - b| <= range for a float difference is |a - b| <= the largest float not above range.
float speckle_range_f(double range) {
  float rf = static_cast<float>(range);
  if (static_cast<double>(rf) > range) rf = std::nextafter(rf, 0.0f);
  return rf;
}

// Labels rows y0 .. y1 - 1 (runs, and unions inside the band).
void speckle_band(const BlockMatchKernels& k, const ImageView<float>& disp,
                  std::ptrdiff_t y0, std::ptrdiff_t y1, float rf, SpeckleBand& b) {
  const std::ptrdiff_t cols = disp.cols;
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  b.runs.clear();
  b.valid.resize(words);
  b.left.resize(words);
  b.up.resize(words);
  for (std::ptrdiff_t y = y0; y < y1; ++y) {
    k.speckle_links(disp.row(y), y > y0 ? disp.row(y - 1) : nullptr, cols, rf, b.valid.data(),
                    b.left.data(), b.up.data());
    b.cur.set(b.valid.data(), b.left.data(), words, static_cast<std::int32_t>(b.runs.size()));
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
        b.runs.push_back({id, static_cast<std::int32_t>(y), static_cast<std::int32_t>(x0),
                          static_cast<std::int32_t>(x1)});
      }
    }
    if (y > y0) {
      each_new_link(b.up.data(), b.cur, b.prev, words, [&](std::ptrdiff_t i) {
        unite(b.runs, b.cur.run_at(i), b.prev.run_at(i));
      });
    } else {
      b.first = b.cur;
    }
    std::swap(b.cur, b.prev);
  }
}

// Joins the labellings (bands[i]: rows starts[i] .. starts[i + 1] - 1) and clears the
// regions of at most `window` pixels.
void speckle_finish(const BlockMatchKernels& k, const ImageView<float>& disp,
                    const ImageView<float>& conf, int window, float rf,
                    const std::vector<SpeckleBand*>& bands,
                    const std::vector<std::ptrdiff_t>& starts, std::vector<SpeckleRun>& all,
                    std::vector<std::int64_t>& sizes) {
  const std::ptrdiff_t cols = disp.cols;
  const auto words = static_cast<std::size_t>((cols + 63) / 64);
  const std::size_t nb = starts.size() - 1;
  std::vector<std::int32_t> offset(nb + 1, 0);
  for (std::size_t i = 0; i < nb; ++i) {
    offset[i + 1] = offset[i] + static_cast<std::int32_t>(bands[i]->runs.size());
  }
  all.resize(static_cast<std::size_t>(offset[nb]));
  for (std::size_t i = 0; i < nb; ++i) {
    for (std::size_t j = 0; j < bands[i]->runs.size(); ++j) {
      SpeckleRun r = bands[i]->runs[j];
      r.parent += offset[i];
      all[static_cast<std::size_t>(offset[i]) + j] = r;
    }
  }
  for (std::size_t i = 1; i < nb; ++i) {
    SpeckleBand& b = *bands[i];
    const std::ptrdiff_t y = starts[i];
    k.speckle_links(disp.row(y), disp.row(y - 1), cols, rf, b.valid.data(), b.left.data(),
                    b.up.data());
    const RowStarts& below = b.first;
    const RowStarts& above = bands[i - 1]->prev;
    each_new_link(b.up.data(), below, above, words, [&](std::ptrdiff_t x) {
      unite(all, offset[i] + below.run_at(x), offset[i - 1] + above.run_at(x));
    });
  }
  sizes.assign(all.size(), 0);
  for (std::size_t i = 0; i < all.size(); ++i) {
    const std::int32_t root = find_root(all, static_cast<std::int32_t>(i));
    all[i].parent = root;  // now every run links to its root directly
    sizes[static_cast<std::size_t>(root)] += all[i].x1 - all[i].x0;
  }
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const SpeckleRun& run : all) {
    if (sizes[static_cast<std::size_t>(run.parent)] > window) continue;
    std::fill(disp.row(run.y) + run.x0, disp.row(run.y) + run.x1, nan);
    if (conf.data) std::fill(conf.row(run.y) + run.x0, conf.row(run.y) + run.x1, 0.0f);
  }
}


}  // namespace stereodepth::detail
