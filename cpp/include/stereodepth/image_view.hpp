// Non-owning views of image memory: a pointer, a shape and strides in elements.
//
// The core never allocates the images it is given nor the outputs it writes: callers (the
// Python bindings, or C++ users) own the memory and describe it with these views.
#pragma once

#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

namespace stereodepth {

// A 2-D image: `rows` x `cols` elements, element (r, c) at data[r * row_stride + c].
template <typename T>
struct ImageView {
  T* data = nullptr;
  std::ptrdiff_t rows = 0;
  std::ptrdiff_t cols = 0;
  std::ptrdiff_t row_stride = 0;  // in elements, >= cols

  T* row(std::ptrdiff_t r) const { return data + r * row_stride; }

  // The same memory as an Eigen row-major map, for code that wants Eigen's expressions.
  using Matrix = Eigen::Matrix<std::remove_const_t<T>, Eigen::Dynamic, Eigen::Dynamic,
                               Eigen::RowMajor>;
  using MapType = Eigen::Map<std::conditional_t<std::is_const_v<T>, const Matrix, Matrix>, 0,
                             Eigen::OuterStride<>>;
  MapType as_eigen() const { return MapType(data, rows, cols, Eigen::OuterStride<>(row_stride)); }
};

// A stack of `frames` images of equal shape, frame f at data[f * frame_stride].
template <typename T>
struct StackView {
  T* data = nullptr;
  std::ptrdiff_t frames = 1;
  std::ptrdiff_t rows = 0;
  std::ptrdiff_t cols = 0;
  std::ptrdiff_t frame_stride = 0;  // in elements
  std::ptrdiff_t row_stride = 0;    // in elements

  // Row `i` of the stack seen as frames * rows rows.
  T* row(std::ptrdiff_t i) const {
    return data + (i / rows) * frame_stride + (i % rows) * row_stride;
  }
  std::ptrdiff_t total_rows() const { return frames * rows; }
  ImageView<T> frame(std::ptrdiff_t f) const {
    return ImageView<T>{data + f * frame_stride, rows, cols, row_stride};
  }
};

}  // namespace stereodepth
