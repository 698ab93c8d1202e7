#include "stereodepth/rectify.hpp"

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include <Eigen/SVD>

#include "stereodepth/parallel.hpp"

namespace stereodepth {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Brown-Conrady iterations of cv::undistortPoints (TermCriteria(COUNT, 5, 0.01)).
constexpr int kPlumbBobIterations = 5;
// Newton steps of cv::fisheye::undistortPoints (TermCriteria(COUNT + EPS, 10, 1e-8)).
constexpr int kEquidistantIterations = 10;
constexpr double kEquidistantEps = 1e-8;

[[noreturn]] void fail(const std::string& msg) { throw std::invalid_argument(msg); }

// Distorted normalized point -> ideal normalized point, Brown-Conrady.
Eigen::Vector2d undistort_plumb_bob(const std::array<double, 8>& k, double x, double y) {
  const double x0 = x, y0 = y;
  for (int j = 0; j < kPlumbBobIterations; ++j) {
    const double r2 = x * x + y * y;
    const double icdist =
        (1 + ((k[7] * r2 + k[6]) * r2 + k[5]) * r2) / (1 + ((k[4] * r2 + k[1]) * r2 + k[0]) * r2);
    if (icdist < 0) {  // the model folds back: keep the distorted point (as OpenCV does)
      return {x0, y0};
    }
    const double dx = 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x);
    const double dy = k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y;
    x = (x0 - dx) * icdist;
    y = (y0 - dy) * icdist;
  }
  return {x, y};
}

// Distorted normalized point -> ideal normalized point, Kannala-Brandt; false where the
// model cannot be inverted.
bool undistort_equidistant(const std::array<double, 8>& k, double& x, double& y) {
  double theta_d = std::sqrt(x * x + y * y);
  theta_d = std::min(std::max(-kPi / 2, theta_d), kPi / 2);
  bool converged = false;
  double theta = theta_d;
  double scale = 0.0;
  if (std::fabs(theta_d) > kEquidistantEps) {
    for (int j = 0; j < kEquidistantIterations; ++j) {
      const double t2 = theta * theta, t4 = t2 * t2, t6 = t4 * t2, t8 = t6 * t2;
      const double k0t2 = k[0] * t2, k1t4 = k[1] * t4, k2t6 = k[2] * t6, k3t8 = k[3] * t8;
      const double fix = (theta * (1 + k0t2 + k1t4 + k2t6 + k3t8) - theta_d) /
                         (1 + 3 * k0t2 + 5 * k1t4 + 7 * k2t6 + 9 * k3t8);
      theta = theta - fix;
      if (std::fabs(fix) < kEquidistantEps) {
        converged = true;
        break;
      }
    }
    scale = std::tan(theta) / theta_d;
  } else {
    converged = true;
  }
  const bool flipped = (theta_d < 0 && theta > 0) || (theta_d > 0 && theta < 0);
  if (!converged || flipped) return false;
  if (theta_d > kEquidistantEps) {
    x *= scale;
    y *= scale;
  }
  return true;
}

// Undistorts then maps through H = P * R: what cv::undistortPoints(src, K, D, R, P) returns.
Eigen::Vector2d undistort_map(const CameraModel& cam, const Eigen::Matrix3d& H, double u,
                              double v) {
  const Eigen::Vector2d p = undistort_point(cam, u, v);
  const double x = p.x(), y = p.y();
  if (cam.model == DistortionModel::kEquidistant && x == -1e6 && y == -1e6) return p;
  const double xx = H(0, 0) * x + H(0, 1) * y + H(0, 2);
  const double yy = H(1, 0) * x + H(1, 1) * y + H(1, 2);
  const double ww = 1. / (H(2, 0) * x + H(2, 1) * y + H(2, 2));
  return {xx * ww, yy * ww};
}

// OpenCV's Mat product order: each entry summed over k = 0, 1, 2.
Eigen::Matrix3d mul(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  Eigen::Matrix3d c;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) c(i, j) = a(i, 0) * b(0, j) + a(i, 1) * b(1, j) + a(i, 2) * b(2, j);
  }
  return c;
}

Eigen::Vector3d mul(const Eigen::Matrix3d& a, const Eigen::Vector3d& b) {
  Eigen::Vector3d c;
  for (int i = 0; i < 3; ++i) c(i) = a(i, 0) * b(0) + a(i, 1) * b(1) + a(i, 2) * b(2);
  return c;
}

// The inverse by cofactors, in this exact order (stereodepth.reference follows it):
// det = a00 (a11 a22 - a12 a21) - a01 (a10 a22 - a12 a20) + a02 (a10 a21 - a11 a20),
// inv(i, j) = cofactor(j, i) * (1 / det).
Eigen::Matrix3d inverse3(const Eigen::Matrix3d& a) {
  const double c00 = a(1, 1) * a(2, 2) - a(1, 2) * a(2, 1);
  const double c01 = a(1, 0) * a(2, 2) - a(1, 2) * a(2, 0);
  const double c02 = a(1, 0) * a(2, 1) - a(1, 1) * a(2, 0);
  const double det = a(0, 0) * c00 - a(0, 1) * c01 + a(0, 2) * c02;
  if (!(std::isfinite(det) && det != 0)) fail("P @ R must be invertible");
  const double id = 1.0 / det;
  Eigen::Matrix3d inv;
  inv(0, 0) = c00 * id;
  inv(0, 1) = (a(0, 2) * a(2, 1) - a(0, 1) * a(2, 2)) * id;
  inv(0, 2) = (a(0, 1) * a(1, 2) - a(0, 2) * a(1, 1)) * id;
  inv(1, 0) = -c01 * id;
  inv(1, 1) = (a(0, 0) * a(2, 2) - a(0, 2) * a(2, 0)) * id;
  inv(1, 2) = (a(0, 2) * a(1, 0) - a(0, 0) * a(1, 2)) * id;
  inv(2, 0) = c02 * id;
  inv(2, 1) = (a(0, 1) * a(2, 0) - a(0, 0) * a(2, 1)) * id;
  inv(2, 2) = (a(0, 0) * a(1, 1) - a(0, 1) * a(1, 0)) * id;
  return inv;
}

struct RectD {
  double x, y, width, height;
};

// The inscribed (every pixel valid) and circumscribed (no pixel lost) rectangles of the
// undistorted, rectified image, from a 9 x 9 grid of points spanning the image
// (cv::getUndistortRectangles in OpenCV 5.0).
void undistort_rectangles(const CameraModel& cam, const Eigen::Matrix3d& R,
                          const Eigen::Matrix3d& P, int width, int height, RectD& inner,
                          RectD& outer) {
  constexpr int n = 9;
  const Eigen::Matrix3d H = mul(P, R);
  const double step_x = (width - 1) / static_cast<double>(n - 1);
  const double step_y = (height - 1) / static_cast<double>(n - 1);
  double ix0 = -FLT_MAX, ix1 = FLT_MAX, iy0 = -FLT_MAX, iy1 = FLT_MAX;
  double ox0 = FLT_MAX, ox1 = -FLT_MAX, oy0 = FLT_MAX, oy1 = -FLT_MAX;
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const Eigen::Vector2d p = undistort_map(cam, H, x * step_x, y * step_y);
      ox0 = std::min(ox0, p.x());
      ox1 = std::max(ox1, p.x());
      oy0 = std::min(oy0, p.y());
      oy1 = std::max(oy1, p.y());
      if (x == 0) ix0 = std::max(ix0, p.x());
      if (x == n - 1) ix1 = std::min(ix1, p.x());
      if (y == 0) iy0 = std::max(iy0, p.y());
      if (y == n - 1) iy1 = std::min(iy1, p.y());
    }
  }
  inner = {ix0, iy0, ix1 - ix0, iy1 - iy0};
  outer = {ox0, oy0, ox1 - ox0, oy1 - oy0};
}

// The rectangle (x, y, w, h), whole numbers given as doubles, clipped to the image; empty when
// nothing of it is inside or a value is not finite (a degenerate calibration, which
// stereo_rectify's caller reports by name). In doubles: converting an infinite, NaN or huge
// value to int is undefined behaviour (UBSan stops there), and x + w could overflow an int.
Rect clip_rect(double x, double y, double w, double h, int width, int height) {
  if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(w) || !std::isfinite(h)) return {};
  const double x0 = std::max(x, 0.0), y0 = std::max(y, 0.0);
  const double x1 = std::min(x + w, static_cast<double>(width));
  const double y1 = std::min(y + h, static_cast<double>(height));
  if (x1 - x0 <= 0 || y1 - y0 <= 0) return {};
  return {static_cast<int>(x0), static_cast<int>(y0), static_cast<int>(x1 - x0),
          static_cast<int>(y1 - y0)};
}

bool finite(const Eigen::MatrixXd& m) { return m.allFinite(); }

// Rounds to float32 and back. Through a volatile: GCC 12's vectorizer was seen to drop a plain
// (double)(float) round trip in the corner loop below, and the rounding is what we must match.
double as_float32(double v) {
  volatile float f = static_cast<float>(v);
  return f;
}

}  // namespace

void validate(const CameraModel& cam, const char* name) {
  const std::string n(name);
  if (!finite(cam.K)) fail(n + " camera matrix must be finite");
  if (!(cam.K(0, 0) > 0 && cam.K(1, 1) > 0)) {
    fail(n + " camera matrix must have fx > 0 and fy > 0, got fx=" + std::to_string(cam.K(0, 0)) +
         " fy=" + std::to_string(cam.K(1, 1)));
  }
  if (cam.K(0, 1) != 0 || cam.K(1, 0) != 0 || cam.K(2, 0) != 0 || cam.K(2, 1) != 0 ||
      cam.K(2, 2) != 1) {
    fail(n + " camera matrix must have the form [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]");
  }
  for (double v : cam.d) {
    if (!std::isfinite(v)) fail(n + " distortion coefficients must be finite");
  }
}

Eigen::Vector3d rotation_vector(const Eigen::Matrix3d& src) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(src, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  Eigen::Vector3d r(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  const double s = std::sqrt((r.x() * r.x() + r.y() * r.y() + r.z() * r.z()) * 0.25);
  double c = (R(0, 0) + R(1, 1) + R(2, 2) - 1) * 0.5;
  c = c > 1. ? 1. : c < -1. ? -1. : c;
  double theta = std::acos(c);
  if (s < 1e-5) {
    if (c > 0) return Eigen::Vector3d::Zero();
    double t = (R(0, 0) + 1) * 0.5;
    r.x() = std::sqrt(std::max(t, 0.));
    t = (R(1, 1) + 1) * 0.5;
    r.y() = std::sqrt(std::max(t, 0.)) * (R(0, 1) < 0 ? -1. : 1.);
    t = (R(2, 2) + 1) * 0.5;
    r.z() = std::sqrt(std::max(t, 0.)) * (R(0, 2) < 0 ? -1. : 1.);
    if (std::fabs(r.x()) < std::fabs(r.y()) && std::fabs(r.x()) < std::fabs(r.z()) &&
        (R(1, 2) > 0) != (r.y() * r.z() > 0)) {
      r.z() = -r.z();
    }
    theta /= std::sqrt(r.x() * r.x() + r.y() * r.y() + r.z() * r.z());
    return r * theta;
  }
  double vth = 1 / (2 * s);
  vth *= theta;
  return r * vth;
}

Eigen::Matrix3d rotation_matrix(const Eigen::Vector3d& v) {
  const double theta = std::sqrt(v.x() * v.x() + v.y() * v.y() + v.z() * v.z());
  if (theta < DBL_EPSILON) return Eigen::Matrix3d::Identity();
  const double c = std::cos(theta), s = std::sin(theta), c1 = 1. - c;
  const double itheta = 1. / theta;
  const double x = v.x() * itheta, y = v.y() * itheta, z = v.z() * itheta;
  const double rrt[9] = {x * x, x * y, x * z, x * y, y * y, y * z, x * z, y * z, z * z};
  const double rx[9] = {0, -z, y, z, 0, -x, -y, x, 0};
  const double eye[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  Eigen::Matrix3d R;
  for (int i = 0; i < 9; ++i) R(i / 3, i % 3) = c * eye[i] + c1 * rrt[i] + s * rx[i];
  return R;
}

Eigen::Vector2d undistort_point(const CameraModel& cam, double u, double v) {
  const Eigen::Matrix3d& K = cam.K;
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2);
  switch (cam.model) {
    case DistortionModel::kNone:
    case DistortionModel::kPlumbBob: {
      const double ifx = 1. / fx, ify = 1. / fy;
      const double x = (u - cx) * ifx, y = (v - cy) * ify;
      if (cam.model == DistortionModel::kNone) return {x, y};
      return undistort_plumb_bob(cam.d, x, y);
    }
    case DistortionModel::kEquidistant: {
      double x = (u - cx) / fx, y = (v - cy) / fy;
      if (!undistort_equidistant(cam.d, x, y)) return {-1e6, -1e6};
      return {x, y};
    }
  }
  return {u, v};
}

StereoRectification stereo_rectify(const CameraModel& cam1, const CameraModel& cam2, int width,
                                   int height, const Eigen::Matrix3d& Rm,
                                   const Eigen::Vector3d& T, const StereoRectifyParams& params) {
  validate(cam1, "K1");
  validate(cam2, "K2");
  if (width < 1 || height < 1) {
    fail("image_size must be positive, got (" + std::to_string(width) + ", " +
         std::to_string(height) + ")");
  }
  if (params.new_width < 0 || params.new_height < 0) fail("new_image_size must be >= 0");
  if (!finite(Rm) || !finite(T)) fail("R and T must be finite");
  if (!std::isfinite(params.alpha)) fail("alpha must be finite");

  const double nx = width, ny = height;
  Eigen::Vector3d om = rotation_vector(Rm) * -0.5;  // half the rotation, the other way
  const Eigen::Matrix3d r_r = rotation_matrix(om);
  Eigen::Vector3d t = mul(r_r, T);

  const int idx = std::fabs(t(0)) > std::fabs(t(1)) ? 0 : 1;
  const double c = t(idx);
  const double nt = std::sqrt(t(0) * t(0) + t(1) * t(1) + t(2) * t(2));
  if (!(nt > 0.0)) fail("T must not be zero: the cameras need a baseline");
  Eigen::Vector3d uu = Eigen::Vector3d::Zero();
  uu(idx) = c > 0 ? 1 : -1;

  // The global rotation that aligns the baseline with the x (or y) axis.
  Eigen::Vector3d ww(t(1) * uu(2) - t(2) * uu(1), t(2) * uu(0) - t(0) * uu(2),
                     t(0) * uu(1) - t(1) * uu(0));
  const double nw = std::sqrt(ww(0) * ww(0) + ww(1) * ww(1) + ww(2) * ww(2));
  if (nw > 0.0) ww *= std::acos(std::fabs(c) / nt) / nw;
  const Eigen::Matrix3d wR = rotation_matrix(ww);

  StereoRectification out;
  out.vertical = idx == 1;
  out.R1 = mul(wR, Eigen::Matrix3d(r_r.transpose()));
  out.R2 = mul(wR, r_r);
  t = mul(out.R2, T);

  int new_w = params.new_width, new_h = params.new_height;
  if (static_cast<long long>(new_w) * new_h == 0) {
    new_w = width;
    new_h = height;
  }
  const double ratio_x = static_cast<double>(new_w) / width / 2;
  const double ratio_y = static_cast<double>(new_h) / height / 2;
  const double ratio = idx == 1 ? ratio_x : ratio_y;
  double fc_new = (cam1.K(idx ^ 1, idx ^ 1) + cam2.K(idx ^ 1, idx ^ 1)) * ratio;

  // Principal points: centre the mean of the four undistorted, rotated image corners. OpenCV
  // holds these points in float32 between its steps; so do we, to give its numbers.
  double cc[2][2];
  for (int k = 0; k < 2; ++k) {
    const CameraModel& cam = k == 0 ? cam1 : cam2;
    const Eigen::Matrix3d& Rk = k == 0 ? out.R1 : out.R2;
    double sum_x = 0, sum_y = 0;
    for (int i = 0; i < 4; ++i) {
      const int j = i < 2 ? 0 : 1;
      const double px = as_float32((i % 2) * (nx - 1));
      const double py = as_float32(j * (ny - 1));
      const Eigen::Vector2d n = undistort_point(cam, px, py);
      const double X = as_float32(n.x()), Y = as_float32(n.y()), Z = 1.0;
      double x = Rk(0, 0) * X + Rk(0, 1) * Y + Rk(0, 2) * Z;
      double y = Rk(1, 0) * X + Rk(1, 1) * Y + Rk(1, 2) * Z;
      double z = Rk(2, 0) * X + Rk(2, 1) * Y + Rk(2, 2) * Z;
      z = z != 0 ? 1. / z : 1;
      x *= z;
      y *= z;
      sum_x += as_float32(x * fc_new);
      sum_y += as_float32(y * fc_new);
    }
    cc[k][0] = (nx - 1) / 2 - sum_x * 0.25;
    cc[k][1] = (ny - 1) / 2 - sum_y * 0.25;
  }

  if (params.zero_disparity) {
    cc[0][0] = cc[1][0] = (cc[0][0] + cc[1][0]) * 0.5;
    cc[0][1] = cc[1][1] = (cc[0][1] + cc[1][1]) * 0.5;
  } else if (idx == 0) {
    cc[0][1] = cc[1][1] = (cc[0][1] + cc[1][1]) * 0.5;
  } else {
    cc[0][0] = cc[1][0] = (cc[0][0] + cc[1][0]) * 0.5;
  }

  const double t_idx = t(idx);
  Eigen::Matrix<double, 3, 4> pp = Eigen::Matrix<double, 3, 4>::Zero();
  pp(0, 0) = pp(1, 1) = fc_new;
  pp(0, 2) = cc[0][0];
  pp(1, 2) = cc[0][1];
  pp(2, 2) = 1.;
  const Eigen::Matrix3d P1_0 = pp.leftCols<3>();
  pp(0, 2) = cc[1][0];
  pp(1, 2) = cc[1][1];
  pp(idx, 3) = t_idx * fc_new;
  const Eigen::Matrix3d P2_0 = pp.leftCols<3>();

  const double alpha = std::min(params.alpha, 1.);
  RectD inner1, inner2, outer1, outer2;
  undistort_rectangles(cam1, out.R1, P1_0, width, height, inner1, outer1);
  undistort_rectangles(cam2, out.R2, P2_0, width, height, inner2, outer2);

  const double cx1_0 = cc[0][0], cy1_0 = cc[0][1], cx2_0 = cc[1][0], cy2_0 = cc[1][1];
  const double cx1 = new_w * cx1_0 / width, cy1 = new_h * cy1_0 / height;
  const double cx2 = new_w * cx2_0 / width, cy2 = new_h * cy2_0 / height;
  double s = 1.;
  if (alpha >= 0) {
    const double w1 = new_w - 1, h1 = new_h - 1;
    double s0 = std::max(std::max(std::max(cx1 / (cx1_0 - inner1.x), cy1 / (cy1_0 - inner1.y)),
                                  (w1 - cx1) / (inner1.x + inner1.width - cx1_0)),
                         (h1 - cy1) / (inner1.y + inner1.height - cy1_0));
    s0 = std::max(
        std::max(std::max(std::max(cx2 / (cx2_0 - inner2.x), cy2 / (cy2_0 - inner2.y)),
                          (w1 - cx2) / (inner2.x + inner2.width - cx2_0)),
                 (h1 - cy2) / (inner2.y + inner2.height - cy2_0)),
        s0);
    double s1 = std::min(std::min(std::min(cx1 / (cx1_0 - outer1.x), cy1 / (cy1_0 - outer1.y)),
                                  (w1 - cx1) / (outer1.x + outer1.width - cx1_0)),
                         (h1 - cy1) / (outer1.y + outer1.height - cy1_0));
    s1 = std::min(
        std::min(std::min(std::min(cx2 / (cx2_0 - outer2.x), cy2 / (cy2_0 - outer2.y)),
                          (w1 - cx2) / (outer2.x + outer2.width - cx2_0)),
                 (h1 - cy2) / (outer2.y + outer2.height - cy2_0)),
        s1);
    s = s0 * (1 - alpha) + s1 * alpha;
  }

  fc_new *= s;
  pp(0, 0) = pp(1, 1) = fc_new;
  pp(0, 2) = cx2;
  pp(1, 2) = cy2;
  pp(idx, 3) *= s;
  out.P2 = pp;
  pp(0, 2) = cx1;
  pp(1, 2) = cy1;
  pp(idx, 3) = 0.;
  out.P1 = pp;

  out.roi1 = clip_rect(std::ceil((inner1.x - cx1_0) * s + cx1),
                       std::ceil((inner1.y - cy1_0) * s + cy1), std::floor(inner1.width * s),
                       std::floor(inner1.height * s), new_w, new_h);
  out.roi2 = clip_rect(std::ceil((inner2.x - cx2_0) * s + cx2),
                       std::ceil((inner2.y - cy2_0) * s + cy2), std::floor(inner2.width * s),
                       std::floor(inner2.height * s), new_w, new_h);

  out.Q << 1, 0, 0, -cx1,  //
      0, 1, 0, -cy1,       //
      0, 0, 0, fc_new,     //
      0, 0, -1. / t_idx, (idx == 0 ? cx1 - cx2 : cy1 - cy2) / t_idx;
  return out;
}

namespace {

// cv::fisheye::estimateNewCameraMatrixForUndistortRectify: focal length and principal point
// from the undistorted, rotated midpoints of the four image sides.
void fisheye_new_camera(const CameraModel& cam, int w, int h, const Eigen::Matrix3d& R,
                        const FisheyeRectifyParams& p, double& f_out, double& cx, double& cy) {
  const double balance = std::min(std::max(p.balance, 0.0), 1.0);
  const double pts[4][2] = {{static_cast<double>(w / 2), 0.0},
                            {static_cast<double>(w), static_cast<double>(h / 2)},
                            {static_cast<double>(w / 2), static_cast<double>(h)},
                            {0.0, static_cast<double>(h / 2)}};
  double q[4][2];
  double sx = 0, sy = 0;
  for (int i = 0; i < 4; ++i) {
    double x = 0, y = 0;
    const Eigen::Vector2d n = undistort_point(cam, pts[i][0], pts[i][1]);
    if (n.x() == -1e6 && n.y() == -1e6) {
      x = y = -1e6;
    } else {
      const double X = R(0, 0) * n.x() + R(0, 1) * n.y() + R(0, 2);
      const double Y = R(1, 0) * n.x() + R(1, 1) * n.y() + R(1, 2);
      const double Z = R(2, 0) * n.x() + R(2, 1) * n.y() + R(2, 2);
      x = X / Z;
      y = Y / Z;
    }
    q[i][0] = x;
    q[i][1] = y;
    sx += x;
    sy += y;
  }
  double cn0 = sx / 4, cn1 = sy / 4;
  const double ar = cam.K(0, 0) / cam.K(1, 1);
  cn1 *= ar;
  double minx = DBL_MAX, miny = DBL_MAX, maxx = -DBL_MAX, maxy = -DBL_MAX;
  for (auto& pt : q) {
    pt[1] *= ar;
    miny = std::min(miny, pt[1]);
    maxy = std::max(maxy, pt[1]);
    minx = std::min(minx, pt[0]);
    maxx = std::max(maxx, pt[0]);
  }
  const double f1 = w * 0.5 / (cn0 - minx);
  const double f2 = w * 0.5 / (maxx - cn0);
  const double f3 = h * 0.5 * ar / (cn1 - miny);
  const double f4 = h * 0.5 * ar / (maxy - cn1);
  const double fmin = std::min(f1, std::min(f2, std::min(f3, f4)));
  const double fmax = std::max(f1, std::max(f2, std::max(f3, f4)));
  double f = balance * fmin + (1.0 - balance) * fmax;
  f *= p.fov_scale > 0 ? 1.0 / p.fov_scale : 1.0;
  double fx = f, fy = f;
  double ncx = -cn0 * f + w * 0.5;
  double ncy = -cn1 * f + h * ar * 0.5;
  fy /= ar;
  ncy /= ar;
  if (p.new_width > 0 && p.new_height > 0) {
    const double rx = p.new_width / static_cast<double>(w);
    const double ry = p.new_height / static_cast<double>(h);
    fx *= rx;
    fy *= ry;
    ncx *= rx;
    ncy *= ry;
  }
  (void)fx;
  f_out = fy;  // stereoRectify takes newK(1, 1)
  cx = ncx;
  cy = ncy;
}

}  // namespace

StereoRectification fisheye_stereo_rectify(const CameraModel& cam1, const CameraModel& cam2,
                                           int width, int height, const Eigen::Matrix3d& Rm,
                                           const Eigen::Vector3d& T,
                                           const FisheyeRectifyParams& params) {
  validate(cam1, "K1");
  validate(cam2, "K2");
  if (width < 1 || height < 1) fail("image_size must be positive");
  if (!finite(Rm) || !finite(T)) fail("R and T must be finite");
  if (!std::isfinite(params.balance) || !std::isfinite(params.fov_scale)) {
    fail("balance and fov_scale must be finite");
  }
  const Eigen::Vector3d om = rotation_vector(Rm) * -0.5;
  const Eigen::Matrix3d r_r = rotation_matrix(om);
  const Eigen::Vector3d t = mul(r_r, T);
  const double nt = std::sqrt(t(0) * t(0) + t(1) * t(1) + t(2) * t(2));
  if (!(nt > 0.0)) fail("T must not be zero: the cameras need a baseline");
  const Eigen::Vector3d uu(t(0) > 0 ? 1 : -1, 0, 0);
  Eigen::Vector3d ww(t(1) * uu(2) - t(2) * uu(1), t(2) * uu(0) - t(0) * uu(2),
                     t(0) * uu(1) - t(1) * uu(0));
  const double nw = std::sqrt(ww(0) * ww(0) + ww(1) * ww(1) + ww(2) * ww(2));
  if (nw > 0.0) ww *= std::acos(std::fabs(t(0)) / nt) / nw;
  const Eigen::Matrix3d wr = rotation_matrix(ww);

  StereoRectification out;
  out.R1 = mul(wr, Eigen::Matrix3d(r_r.transpose()));
  out.R2 = mul(wr, r_r);
  const Eigen::Vector3d tnew = mul(out.R2, T);

  double f1, cx1, cy1, f2, cx2, cy2;
  fisheye_new_camera(cam1, width, height, out.R1, params, f1, cx1, cy1);
  fisheye_new_camera(cam2, width, height, out.R2, params, f2, cx2, cy2);
  const double fc = std::min(f1, f2);
  if (params.zero_disparity) {
    cx1 = cx2 = (cx1 + cx2) * 0.5;
    cy1 = cy2 = (cy1 + cy2) * 0.5;
  } else {
    cy1 = cy2 = (cy1 + cy2) * 0.5;
  }
  out.P1 << fc, 0, cx1, 0, 0, fc, cy1, 0, 0, 0, 1, 0;
  out.P2 << fc, 0, cx2, tnew(0) * fc, 0, fc, cy2, 0, 0, 0, 1, 0;
  out.Q << 1, 0, 0, -cx1, 0, 1, 0, -cy1, 0, 0, 0, fc, 0, 0, -1. / tnew(0), (cx1 - cx2) / tnew(0);
  const int ow = params.new_width > 0 && params.new_height > 0 ? params.new_width : width;
  const int oh = params.new_width > 0 && params.new_height > 0 ? params.new_height : height;
  out.roi1 = out.roi2 = Rect{0, 0, ow, oh};
  return out;
}

void init_undistort_rectify_map(const CameraModel& cam, const Eigen::Matrix3d& R,
                                const Eigen::Matrix3d& P, const ImageView<float>& map_x,
                                const ImageView<float>& map_y, int threads) {
  validate(cam, "K");
  if (!finite(R) || !finite(P)) fail("R and P must be finite");
  if (map_x.rows != map_y.rows || map_x.cols != map_y.cols) {
    fail("map_x and map_y must have the same shape");
  }
  const Eigen::Matrix3d iR = inverse3(mul(P, R));
  const double fx = cam.K(0, 0), fy = cam.K(1, 1), u0 = cam.K(0, 2), v0 = cam.K(1, 2);
  const std::array<double, 8> k = cam.d;
  const DistortionModel model = cam.model;

  auto band = [&](std::ptrdiff_t begin, std::ptrdiff_t end) {
    for (std::ptrdiff_t i = begin; i < end; ++i) {
      float* mx = map_x.row(i);
      float* my = map_y.row(i);
      const double di = static_cast<double>(i);
      for (std::ptrdiff_t j = 0; j < map_x.cols; ++j) {
        const double dj = static_cast<double>(j);
        const double X = iR(0, 0) * dj + iR(0, 1) * di + iR(0, 2);
        const double Y = iR(1, 0) * dj + iR(1, 1) * di + iR(1, 2);
        const double W = iR(2, 0) * dj + iR(2, 1) * di + iR(2, 2);
        double u, v;
        if (model == DistortionModel::kEquidistant) {
          const double x = X / W, y = Y / W;
          const double r = std::sqrt(x * x + y * y);
          const double theta = std::atan(r);
          const double t2 = theta * theta, t4 = t2 * t2, t6 = t4 * t2, t8 = t4 * t4;
          const double theta_d = theta * (1 + k[0] * t2 + k[1] * t4 + k[2] * t6 + k[3] * t8);
          const double scale = r == 0 ? 1.0 : theta_d / r;
          u = fx * x * scale + u0;
          v = fy * y * scale + v0;
          if (!(W > 0)) u = v = -1e6;  // behind the camera: nothing to sample
        } else {
          const double w = 1. / W, x = X * w, y = Y * w;
          const double x2 = x * x, y2 = y * y, r2 = x2 + y2, xy2 = 2 * x * y;
          const double kr = (1 + ((k[4] * r2 + k[1]) * r2 + k[0]) * r2) /
                            (1 + ((k[7] * r2 + k[6]) * r2 + k[5]) * r2);
          const double xd = x * kr + k[2] * xy2 + k[3] * (r2 + 2 * x2);
          const double yd = y * kr + k[2] * (r2 + 2 * y2) + k[3] * xy2;
          u = fx * xd + u0;
          v = fy * yd + v0;
        }
        mx[j] = static_cast<float>(u);
        my[j] = static_cast<float>(v);
      }
    }
  };
  const std::ptrdiff_t min_rows =
      std::max<std::ptrdiff_t>(1, (1 << 14) / std::max<std::ptrdiff_t>(map_x.cols, 1));
  parallel_for_rows(map_x.rows, resolve_threads(threads), min_rows, band);
}

}  // namespace stereodepth
