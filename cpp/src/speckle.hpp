// Internal: the speckle filter shared by the matchers (block matching, semi-global matching).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "block_match_kernels.hpp"
#include "stereodepth/image_view.hpp"

namespace stereodepth::detail {

// The speckle filter, in two steps: each band of rows labels its own pixels and sizes its
// regions (in the band's thread, right after matching it), then a join across the bands'
// boundaries and a pass, on the matcher's threads, that clears the small regions.
//
// Two 4-neighbours are linked when both are valid and differ by at most `range` (as OpenCV's
// filterSpeckles). Each row is cut into runs of horizontally linked pixels; vertical links
// unite runs (union-find, the lower index becoming the root). Rows are handled as bit masks
// (the kernels' speckle_links): a run starts at every valid pixel not linked to its left
// neighbour, and the run holding column i is found by counting the starts up to i.

struct SpeckleRun {
  std::int32_t parent;  // union-find link; a root links to itself
  std::int32_t x0, x1;  // columns x0 .. x1 - 1 (the row: SpeckleBand::row_first)
};

// A row's run starts, as bits, with the count of starts before each word and the index of
// the row's first run: the run holding column i is base + (starts up to and including i) - 1.
struct RowStarts {
  std::vector<std::uint64_t> bits;
  std::vector<std::int32_t> before;
  std::int32_t base = 0;

  void set(const std::uint64_t* valid, const std::uint64_t* left, std::size_t words,
           std::int32_t first_run) {
    bits.resize(words);
    before.resize(words);
    base = first_run;
    std::int32_t n = 0;
    for (std::size_t w = 0; w < words; ++w) {
      bits[w] = valid[w] & ~left[w];
      before[w] = n;
      n += __builtin_popcountll(bits[w]);
    }
  }
  std::int32_t run_at(std::ptrdiff_t i) const {
    const auto w = static_cast<std::size_t>(i >> 6);
    const int b = static_cast<int>(i & 63);
    const std::uint64_t upto = b == 63 ? ~std::uint64_t{0} : (std::uint64_t{2} << b) - 1;
    return base + before[w] + __builtin_popcountll(bits[w] & upto) - 1;
  }
};

// One band's labelling.
struct SpeckleBand {
  std::vector<SpeckleRun> runs;  // parents are indices into this vector
  std::ptrdiff_t y0 = 0;                // the band's first row
  std::ptrdiff_t y1 = 0;                // the row after the last one labelled
  std::vector<std::int32_t> row_first;  // row y0 + i: runs row_first[i] .. row_first[i + 1] - 1
  std::vector<std::uint64_t> valid, left, up;
  RowStarts cur, prev;  // after labelling, prev holds the band's last row
  RowStarts first;      // the band's first row
};

// The join's scratch, kept between calls: the pairs of regions linked across band boundaries
// and a small union-find over those regions (O(W) per boundary, nothing per run).
struct SpeckleJoin {
  std::vector<std::int32_t> pairs;   // global run ids of two linked roots, two per link
  std::vector<std::int32_t> ids;     // the roots that touch a boundary, sorted
  std::vector<std::int32_t> parent;  // union-find over ids
  std::vector<std::int64_t> size;    // region sizes (pixels) by ids index
};

// |a - b| <= range for a float difference is |a - b| <= the largest float not above range.
float speckle_range_f(double range);

// Labels rows y0 .. y1 - 1 (runs, and unions inside the band) and sizes the band's regions
// (up to window + 1 pixels), for speckle_finish.
void speckle_band(const BlockMatchKernels& k, const ImageView<float>& disp, std::ptrdiff_t y0,
                  std::ptrdiff_t y1, float rf, int window, SpeckleBand& b);

// speckle_band in steps, for a band whose rows are matched a few at a time: speckle_begin
// starts a band at row y0, each speckle_rows labels the rows from the last one labelled up to
// y1 - 1 (their disparities final), and speckle_end sizes the regions. The band is the same as
// speckle_band's for the same rows, however they were handed in.
void speckle_begin(std::ptrdiff_t y0, std::ptrdiff_t cols, SpeckleBand& b);
void speckle_rows(const BlockMatchKernels& k, const ImageView<float>& disp, std::ptrdiff_t y1,
                  float rf, SpeckleBand& b);
void speckle_end(int window, SpeckleBand& b);

// Joins the labellings (bands[i]: rows starts[i] .. starts[i + 1] - 1, each from
// speckle_band with the same window) and clears the regions of at most `window` pixels (NaN,
// and 0 in conf when conf.data is not null), the clearing on up to `threads` threads. Works
// in place in the bands' runs (their parents are then overwritten): each band's regions are
// sized in the band, and only the regions linked across a boundary are joined, so no copy
// of the runs and no size per run.
void speckle_finish(const BlockMatchKernels& k, const ImageView<float>& disp,
                    const ImageView<float>& conf, int window, float rf,
                    const std::vector<SpeckleBand*>& bands,
                    const std::vector<std::ptrdiff_t>& starts, SpeckleJoin& join, int threads);

}  // namespace stereodepth::detail
