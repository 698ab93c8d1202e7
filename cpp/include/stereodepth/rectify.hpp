// Stereo rectification: Bouguet's method as OpenCV's cv::stereoRectify computes it, the
// iterative undistortion of points it needs, and the undistort-rectify maps that
// cv::initUndistortRectifyMap builds (pinhole with Brown-Conrady distortion, and the
// Kannala-Brandt equidistant fisheye model).
//
// Sources: J.-Y. Bouguet, Camera Calibration Toolbox for Matlab (rect.m); OpenCV's
// calib3d/stereo modules (stereoRectify, undistortPoints, initUndistortRectifyMap);
// D. C. Brown, "Decentering distortion of lenses" (1966); J. Kannala and S. S. Brandt,
// "A generic camera model and calibration method for conventional, wide-angle, and fish-eye
// lenses", PAMI 2006.
//
// Conventions are OpenCV's: K is the 3x3 pixel camera matrix, R and T map points of the
// first (left) camera's frame into the second's (x2 = R x1 + T, as cv::stereoCalibrate),
// pixel coordinates have (0, 0) at the centre of the top-left pixel.
#pragma once

#include <array>
#include <cstddef>

#include <Eigen/Core>

#include "stereodepth/image_view.hpp"

namespace stereodepth {

enum class DistortionModel {
  kNone = 0,
  kPlumbBob = 1,    // Brown-Conrady: k1 k2 p1 p2 k3 k4 k5 k6 (OpenCV's order; absent = 0)
  kEquidistant = 2  // Kannala-Brandt fisheye: k1 k2 k3 k4
};

// One camera: intrinsics and lens distortion.
struct CameraModel {
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  DistortionModel model = DistortionModel::kNone;
  std::array<double, 8> d{};  // unused entries are 0
};

// Throws std::invalid_argument (naming `name`) unless K is finite with fx, fy > 0, a bottom
// row (0, 0, 1), and the coefficients are finite.
void validate(const CameraModel& camera, const char* name);

// Rotation matrix <-> rotation vector (axis * angle), as cv::Rodrigues: the matrix is first
// made orthogonal (U V^T of its SVD); rotations under about 2e-5 rad become the zero vector.
Eigen::Vector3d rotation_vector(const Eigen::Matrix3d& r);
Eigen::Matrix3d rotation_matrix(const Eigen::Vector3d& v);

// Distorted pixel (u, v) -> ideal normalized coordinates (x, y) on the z = 1 plane, as
// cv::undistortPoints (5 fixed-point iterations) or cv::fisheye::undistortPoints (Newton on
// theta, at most 10 steps, stops below 1e-8; points it cannot invert give -1e6).
Eigen::Vector2d undistort_point(const CameraModel& camera, double u, double v);

struct StereoRectifyParams {
  double alpha = -1.0;         // < 0: OpenCV's default scaling; 0: only valid pixels; 1: all
  int new_width = 0;           // 0: the input size
  int new_height = 0;
  bool zero_disparity = true;  // principal points equal (CALIB_ZERO_DISPARITY)
};

struct Rect {
  int x = 0, y = 0, width = 0, height = 0;
};

struct StereoRectification {
  Eigen::Matrix3d R1, R2;                // rectifying rotations (camera -> rectified frame)
  Eigen::Matrix<double, 3, 4> P1, P2;    // projections in the rectified frames
  Eigen::Matrix4d Q;                     // disparity-to-depth (cv::reprojectImageTo3D)
  Rect roi1, roi2;                       // rectangles of valid pixels in the rectified images
  bool vertical = false;                 // the rig is vertical (|T_y| >= |T_x| after rotation)
};

// Bouguet's rectification, step for step as cv::stereoRectify (OpenCV 5): rotate both cameras
// by half of R to a common orientation, then about the axis that aligns the baseline with x
// (or y for a vertical rig); common focal length; principal points from the undistorted
// image corners; scale from `alpha` through the inscribed and circumscribed rectangles of the
// undistorted image border. Throws std::invalid_argument for bad sizes or a zero baseline.
StereoRectification stereo_rectify(const CameraModel& cam1, const CameraModel& cam2, int width,
                                   int height, const Eigen::Matrix3d& R,
                                   const Eigen::Vector3d& T, const StereoRectifyParams& params);

struct FisheyeRectifyParams {
  double balance = 0.0;    // [0, 1]: 0 the largest focal length (crop), 1 the smallest
  double fov_scale = 1.0;  // the focal length is divided by it (when > 0)
  int new_width = 0;       // 0: the input size
  int new_height = 0;
  bool zero_disparity = true;
};

// The rectification of cv::fisheye::stereoRectify (OpenCV 5), for equidistant cameras: the
// same rotations as Bouguet's (always a horizontal rig), then each camera's new focal length
// and principal point from cv::fisheye::estimateNewCameraMatrixForUndistortRectify (the
// undistorted midpoints of the four image sides), the smaller focal length for both.
// roi1 and roi2 are the whole output image (OpenCV computes none).
StereoRectification fisheye_stereo_rectify(const CameraModel& cam1, const CameraModel& cam2,
                                           int width, int height, const Eigen::Matrix3d& R,
                                           const Eigen::Vector3d& T,
                                           const FisheyeRectifyParams& params);

// The maps of cv::initUndistortRectifyMap (CV_32FC1): for each pixel of the rectified image,
// where to sample the raw image. `P` is the new 3x3 camera matrix (or the left 3x3 of P1/P2),
// `R` the rectifying rotation. Computed in float64 per pixel (not incrementally), rounded
// once to float32; rows are split over threads and the result does not depend on them.
// Equidistant maps follow cv::fisheye::initUndistortRectifyMap.
void init_undistort_rectify_map(const CameraModel& camera, const Eigen::Matrix3d& R,
                                const Eigen::Matrix3d& P, const ImageView<float>& map_x,
                                const ImageView<float>& map_y, int threads = 0);

}  // namespace stereodepth
