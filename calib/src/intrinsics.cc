#include "romunect/calib/intrinsics.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <random>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/calib/picture.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect::calib {
namespace fs = std::filesystem;
namespace {

constexpr const char* kSource = "intrinsics";

cv::Mat ToGrey8(const cv::Mat& image) {
  cv::Mat grey = image;
  if (grey.channels() == 3) cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  if (grey.channels() == 4) cv::cvtColor(image, grey, cv::COLOR_BGRA2GRAY);
  if (grey.depth() == CV_8U) return grey;
  // 16-bit IR (10 bits used) or float: stretch the used range to 8 bits.
  double lo = 0.0, hi = 0.0;
  cv::minMaxLoc(grey, &lo, &hi);
  cv::Mat out;
  const double scale = hi > lo ? 255.0 / (hi - lo) : 1.0;
  grey.convertTo(out, CV_8U, scale, -lo * scale);
  return out;
}

std::vector<cv::Point3f> ObjectPoints(const BoardSpec& board) {
  std::vector<cv::Point3f> points;
  for (const Eigen::Vector3d& p : board.CornersK()) points.emplace_back(p.x(), p.y(), p.z());
  return points;
}

CameraModel ModelFrom(const cv::Mat& K, const cv::Mat& dist, cv::Size size) {
  CameraModel camera;
  camera.width = size.width;
  camera.height = size.height;
  camera.fx = K.at<double>(0, 0);
  camera.fy = K.at<double>(1, 1);
  camera.cx = K.at<double>(0, 2);
  camera.cy = K.at<double>(1, 2);
  for (int i = 0; i < 5; ++i) camera.distortion[i] = i < static_cast<int>(dist.total()) ? dist.at<double>(i) : 0.0;
  return camera;
}

Pose PoseFromRvecTvec(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d R_e;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R_e(r, c) = R.at<double>(r, c);
  }
  return MakePose(R_e, Eigen::Vector3d(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)));
}

double SquaredReprojection(const BoardView& view, const BoardSpec& board, const cv::Mat& K, const cv::Mat& dist,
                           const cv::Mat& rvec, const cv::Mat& tvec) {
  std::vector<cv::Point2f> projected;
  cv::projectPoints(ObjectPoints(board), rvec, tvec, K, dist, projected);
  double sum = 0.0;
  for (size_t i = 0; i < projected.size(); ++i) {
    const cv::Point2f d = projected[i] - view.corners_px[i];
    sum += d.dot(d);
  }
  return sum;
}

struct CvCalibration {
  cv::Mat K, dist;
  std::vector<cv::Mat> rvecs, tvecs;
  cv::Mat per_view_errors;
  double rms = 0.0;
};

// guess: start from this solution (the held-out folds start from the full fit: they converge
// in a few iterations instead of 100).
CvCalibration RunCalibrateCamera(const std::vector<const BoardView*>& views, const BoardSpec& board, cv::Size size,
                                 DistortionModel model, const CvCalibration* guess = nullptr) {
  const std::vector<cv::Point3f> object = ObjectPoints(board);
  std::vector<std::vector<cv::Point3f>> object_points(views.size(), object);
  std::vector<std::vector<cv::Point2f>> image_points;
  for (const BoardView* v : views) image_points.push_back(v->corners_px);
  CvCalibration out;
  int flags = model == DistortionModel::kK1K2P1P2 ? cv::CALIB_FIX_K3 : 0;
  if (guess != nullptr) {
    flags |= cv::CALIB_USE_INTRINSIC_GUESS;
    out.K = guess->K.clone();
    out.dist = guess->dist.clone();
  }
  // stop when a step changes the parameters by less than 1e-9 (px and unitless): each
  // iteration solves a dense system of 4 + 5 + 6 views unknowns by SVD, so the 100 iterations a
  // tolerance never reached would cost seconds with 20 views
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, guess ? 30 : 100,
                                  guess ? 1e-7 : 1e-9);
  // the overload without standard deviations: those cost most of the time with many views
  out.rms = cv::calibrateCamera(object_points, image_points, size, out.K, out.dist, out.rvecs, out.tvecs, flags,
                                criteria);
  out.per_view_errors.create(static_cast<int>(views.size()), 1, CV_64F);
  for (size_t i = 0; i < views.size(); ++i) {
    out.per_view_errors.at<double>(static_cast<int>(i)) = std::sqrt(
        SquaredReprojection(*views[i], board, out.K, out.dist, out.rvecs[i], out.tvecs[i]) /
        views[i]->corners_px.size());
  }
  return out;
}

// Mean grey in a small square around p; -1 when it leaves the image.
double MeanGrey(const cv::Mat& grey, cv::Point2f p, int half) {
  const cv::Rect box(cvRound(p.x) - half, cvRound(p.y) - half, 2 * half + 1, 2 * half + 1);
  if ((box & cv::Rect(0, 0, grey.cols, grey.rows)) != box) return -1.0;
  return cv::mean(grey(box))[0];
}

// The detectors may start a board at either end (a 180 deg turn of K), and mixed orders across
// views break hand-eye. With cols + rows odd the squares at the two ends of the corner grid
// differ in colour: the order starts at the end whose square is dark (square (0, 0) of K, between
// the first four corners, is black, as is (-1, -1)).
void OrderFromTheDarkCorner(const cv::Mat& grey, const BoardSpec& board, std::vector<cv::Point2f>* corners) {
  if ((board.cols + board.rows) % 2 == 0) return;  // symmetric colours: the order is ambiguous
  const std::vector<cv::Point2f>& c = *corners;
  const int n = board.corner_count(), w = board.cols;
  const cv::Point2f first = 0.25f * (c[0] + c[1] + c[w] + c[w + 1]);
  const cv::Point2f last = 0.25f * (c[n - 1] + c[n - 2] + c[n - 1 - w] + c[n - 2 - w]);
  const cv::Point2f step = c[1] - c[0];
  const int half = std::max(1, static_cast<int>(0.2 * std::sqrt(step.dot(step))));
  const double g_first = MeanGrey(grey, first, half), g_last = MeanGrey(grey, last, half);
  if (g_first >= 0.0 && g_last >= 0.0 && g_first > g_last) std::reverse(corners->begin(), corners->end());
}

}  // namespace

std::optional<std::vector<cv::Point2f>> DetectBoard(const cv::Mat& image, const BoardSpec& board, std::string* reason) {
  ROMUNECT_CHECK(reason != nullptr);
  if (image.empty()) {
    *reason = "empty image";
    return std::nullopt;
  }
  const cv::Mat grey = ToGrey8(image);
  const cv::Size pattern(board.cols, board.rows);
  std::vector<cv::Point2f> corners;
  // Cheapest first (measured on the simulated rig's 640x480 views, CPU): the plain detector
  // finds or misses a board in 1-7 ms; where it misses (strong tilts, blur) the sector-based
  // detector finds it in 40-70 ms; adaptive thresholding, which cost 2-3 s per miss, runs last.
  // All three end in the same cornerSubPix refinement below.
  bool found = cv::findChessboardCorners(grey, pattern, corners,
                                         cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
  if (!found) found = cv::findChessboardCornersSB(grey, pattern, corners, 0);
  if (!found) {
    found = cv::findChessboardCorners(
        grey, pattern, corners, cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
  }
  if (!found || static_cast<int>(corners.size()) != board.corner_count()) {
    *reason = "board " + std::to_string(board.cols) + "x" + std::to_string(board.rows) + " not found completely (" +
              std::to_string(corners.size()) +
              " corners); is the whole board in view and the size given as inner corners?";
    return std::nullopt;
  }
  // Search window: well inside one square, so the refinement never jumps to a neighbour.
  double spacing = 1e9;
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c + 1 < board.cols; ++c) {
      const cv::Point2f d = corners[r * board.cols + c + 1] - corners[r * board.cols + c];
      spacing = std::min(spacing, std::sqrt(static_cast<double>(d.dot(d))));
    }
  }
  const int half = std::clamp(static_cast<int>(spacing * 0.4), 2, 11);
  cv::cornerSubPix(grey, corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-3));
  OrderFromTheDarkCorner(grey, board, &corners);
  reason->clear();
  return corners;
}

std::vector<fs::path> ListBoardImages(const fs::path& dir) {
  if (!fs::is_directory(dir)) throw InputError(dir.string(), "", "not a folder of images");
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(dir)) {
    std::string ext = entry.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
    if (entry.is_regular_file() &&
        (ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" || ext == ".tif" || ext == ".tiff")) {
      files.push_back(entry.path());
    }
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) {
    throw InputError(dir.string(), "", "holds no images (png, jpg, bmp, tif); give the folder of board views");
  }
  return files;
}

DetectedViews DetectBoardInFolder(const fs::path& dir, const BoardSpec& board) {
  const std::vector<fs::path> files = ListBoardImages(dir);
  DetectedViews out;
  for (const fs::path& file : files) {
    const cv::Mat image = ReadPicture(file);  // a bomb is refused from its header, before decoding
    if (image.empty()) {
      out.rejected.emplace_back(file.filename().string(), "cannot be read as an image");
      continue;
    }
    if (out.image_size.area() == 0) {
      out.image_size = image.size();
    } else if (image.size() != out.image_size) {
      throw InputError(file.string(), "size",
                       std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                           " differs from the first image's " + std::to_string(out.image_size.width) + "x" +
                           std::to_string(out.image_size.height) +
                           "; all views must come from one camera at one resolution");
    }
    std::string reason;
    auto corners = DetectBoard(image, board, &reason);
    if (!corners) {
      out.rejected.emplace_back(file.filename().string(), reason);
      continue;
    }
    out.views.push_back({file.filename().string(), std::move(*corners)});
  }
  return out;
}

std::string IntrinsicsOptions::Problem() const {
  if (min_views < 3) return "min_views is " + std::to_string(min_views) + "; Zhang needs at least 3";
  if (holdout_folds < 0 || holdout_folds == 1) {
    return "holdout_folds is " + std::to_string(holdout_folds) + "; must be 0 (off) or >= 2";
  }
  if (coverage_cells_x < 1 || coverage_cells_y < 1) return "coverage cells must be >= 1 each way";
  return "";
}

std::string IntrinsicsResult::BriefReport() const {
  char line[400];
  std::snprintf(line, sizeof(line),
                "intrinsics: %zu views, RMS %.3f px, held-out %.3f px; fx %.2f fy %.2f cx %.2f cy %.2f "
                "k [%.4f %.4f %.5f %.5f %.4f]; coverage %.0f %% cells, tilt spread x %.1f deg y %.1f deg",
                per_view_rms_px.size(), rms_px, holdout_rms_px, camera.fx, camera.fy, camera.cx, camera.cy,
                camera.distortion[0], camera.distortion[1], camera.distortion[2], camera.distortion[3],
                camera.distortion[4], 100.0 * coverage.cell_fraction, coverage.tilt_x_spread_rad * 180.0 / M_PI,
                coverage.tilt_y_spread_rad * 180.0 / M_PI);
  return line;
}

IntrinsicsResult CalibrateIntrinsics(const std::vector<BoardView>& views, const BoardSpec& board, cv::Size image_size,
                                     const IntrinsicsOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  if (const std::string p = board.Problem(); !p.empty()) throw InputError(kSource, "board", p);
  if (image_size.width <= 0 || image_size.height <= 0) {
    throw InputError(kSource, "image_size", "must be positive");
  }
  if (static_cast<int>(views.size()) < options.min_views) {
    throw InputError(kSource, "views",
                     std::to_string(views.size()) + " usable views; need at least " +
                         std::to_string(options.min_views) +
                         ": capture more views of the whole board at varied positions and tilts");
  }
  for (const BoardView& v : views) {
    if (static_cast<int>(v.corners_px.size()) != board.corner_count()) {
      throw InputError(kSource, v.name,
                       std::to_string(v.corners_px.size()) + " corners; the board has " +
                           std::to_string(board.corner_count()));
    }
  }
  std::vector<const BoardView*> all;
  for (const BoardView& v : views) all.push_back(&v);
  CvCalibration cal;
  try {
    cal = RunCalibrateCamera(all, board, image_size, options.model);
  } catch (const cv::Exception& e) {
    throw InputError(kSource, "views", std::string("OpenCV calibrateCamera failed: ") + e.what());
  }
  IntrinsicsResult result;
  result.camera = ModelFrom(cal.K, cal.dist, image_size);
  result.rms_px = cal.rms;
  for (size_t i = 0; i < views.size(); ++i) {
    result.per_view_rms_px.push_back(cal.per_view_errors.at<double>(static_cast<int>(i)));
    result.T_C_K.push_back(PoseFromRvecTvec(cal.rvecs[i], cal.tvecs[i]));
  }
  if (options.holdout_folds >= 2) {
    const int folds = std::min<int>(options.holdout_folds, static_cast<int>(views.size()));
    double sum = 0.0;
    size_t count = 0;
    for (int f = 0; f < folds; ++f) {
      std::vector<const BoardView*> train, test;
      for (size_t i = 0; i < views.size(); ++i) (static_cast<int>(i) % folds == f ? test : train).push_back(&views[i]);
      if (train.size() < 3 || test.empty()) continue;
      CvCalibration fold;
      try {
        fold = RunCalibrateCamera(train, board, image_size, options.model, &cal);
      } catch (const cv::Exception&) {
        continue;  // a fold that cannot calibrate adds no estimate
      }
      for (const BoardView* v : test) {
        cv::Mat rvec, tvec;
        cv::solvePnP(ObjectPoints(board), v->corners_px, fold.K, fold.dist, rvec, tvec);
        sum += SquaredReprojection(*v, board, fold.K, fold.dist, rvec, tvec);
        count += v->corners_px.size();
      }
    }
    if (count > 0) result.holdout_rms_px = std::sqrt(sum / count);
  }
  result.coverage = MeasureCoverage(views, result.T_C_K, image_size, options.coverage_cells_x,
                                    options.coverage_cells_y);
  return result;
}

Coverage MeasureCoverage(const std::vector<BoardView>& views, const std::vector<Pose>& T_C_K, cv::Size image_size,
                         int cells_x, int cells_y) {
  ROMUNECT_CHECK(views.size() == T_C_K.size());
  ROMUNECT_CHECK(cells_x > 0 && cells_y > 0);
  std::vector<char> hit(static_cast<size_t>(cells_x) * cells_y, 0);
  for (const BoardView& v : views) {
    for (const cv::Point2f& p : v.corners_px) {
      const int cx = std::clamp(static_cast<int>((p.x + 0.5) * cells_x / image_size.width), 0, cells_x - 1);
      const int cy = std::clamp(static_cast<int>((p.y + 0.5) * cells_y / image_size.height), 0, cells_y - 1);
      hit[cy * cells_x + cx] = 1;
    }
  }
  Coverage c;
  c.cell_fraction = static_cast<double>(std::count(hit.begin(), hit.end(), 1)) / hit.size();
  double tx_lo = 1e9, tx_hi = -1e9, ty_lo = 1e9, ty_hi = -1e9;
  for (const Pose& T : T_C_K) {
    Eigen::Vector3d n = T.linear().col(2);
    if (n.z() < 0) n = -n;
    const double tx = std::atan2(n.y(), n.z()), ty = std::atan2(n.x(), n.z());
    tx_lo = std::min(tx_lo, tx);
    tx_hi = std::max(tx_hi, tx);
    ty_lo = std::min(ty_lo, ty);
    ty_hi = std::max(ty_hi, ty);
    c.max_tilt_rad = std::max(c.max_tilt_rad, std::acos(std::clamp(n.z(), -1.0, 1.0)));
  }
  if (!T_C_K.empty()) {
    c.tilt_x_spread_rad = tx_hi - tx_lo;
    c.tilt_y_spread_rad = ty_hi - ty_lo;
  }
  return c;
}

MappingError FullImageMappingError(const CameraModel& estimate, const CameraModel& truth, int step_px,
                                   bool compensate_rotation) {
  ROMUNECT_CHECK(step_px > 0);
  std::vector<Eigen::Vector2d> pixels;
  for (int v = 0; v < truth.height; v += step_px) {
    for (int u = 0; u < truth.width; u += step_px) pixels.emplace_back(u, v);
  }
  // The best rotation R with R * ray_truth(u) ~ ray_estimate(u) (Kabsch on unit rays): a
  // rotation of the camera frame is absorbed by the board poses, so it is no calibration error.
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  if (compensate_rotation) {
    Eigen::Matrix3d cross = Eigen::Matrix3d::Zero();
    for (const Eigen::Vector2d& u : pixels) {
      cross += estimate.Ray(u).normalized() * truth.Ray(u).normalized().transpose();
    }
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(cross, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
    R = svd.matrixU() * D * svd.matrixV().transpose();
  }
  double sum = 0.0, max = 0.0;
  for (const Eigen::Vector2d& u : pixels) {
    const auto projected = estimate.Project(R * truth.Ray(u));
    const double e = projected ? (*projected - u).norm() : 1e6;
    sum += e * e;
    max = std::max(max, e);
  }
  return {std::sqrt(sum / pixels.size()), max};
}

std::string ViewPlanOptions::Problem() const {
  if (view_count < 3) return "view_count is " + std::to_string(view_count) + "; need at least 3";
  if (!(distance_m > 0.0)) return "distance_m must be positive";
  if (!(max_tilt_rad >= 0.0 && max_tilt_rad < 1.4)) return "max_tilt_rad must be in [0, 1.4)";
  if (!(margin_px >= 0.0)) return "margin_px must be >= 0";
  return "";
}

std::vector<Pose> PlanViews(const CameraModel& camera, const BoardSpec& board, const ViewPlanOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError("view planner", "options", p);
  if (const std::string p = board.Problem(); !p.empty()) throw InputError("view planner", "board", p);
  std::mt19937 rng(options.seed);
  std::uniform_real_distribution<double> jitter(-1.0, 1.0);
  const Eigen::Vector3d centre_K = board.CentreK();
  const double half_w = 0.5 * camera.width, half_h = 0.5 * camera.height;

  auto fits = [&](const Pose& T_C_K) {
    for (const Eigen::Vector3d& p_K : board.CornersK()) {
      const auto u = camera.Project(T_C_K * p_K);
      if (!u || u->x() < options.margin_px - 0.5 || u->y() < options.margin_px - 0.5 ||
          u->x() > camera.width - 0.5 - options.margin_px || u->y() > camera.height - 0.5 - options.margin_px) {
        return false;
      }
    }
    return true;
  };
  // The board centre placed on the ray through pixel `target`, at distance_m, rotated by R.
  auto pose_at = [&](const Eigen::Matrix3d& R_C_K, const Eigen::Vector2d& target) {
    const Eigen::Vector3d centre_C = options.distance_m * camera.Ray(target);
    return MakePose(R_C_K, centre_C - R_C_K * centre_K);
  };
  const Eigen::Vector2d image_centre(camera.cx, camera.cy);
  if (!fits(pose_at(Eigen::Matrix3d::Identity(), image_centre))) {
    throw InputError("view planner", "distance_m",
                     "the board does not fit the image at " + std::to_string(options.distance_m) +
                         " m; increase the distance or use a smaller board");
  }
  // Board-centre directions: the 8 border positions first (corners, then edge middles), then
  // the centre, so even a short plan reaches the image corners.
  const double dirs[9][2] = {{-1, -1}, {1, 1}, {1, -1}, {-1, 1}, {0, -1}, {0, 1}, {-1, 0}, {1, 0}, {0, 0}};
  // Tilt directions, cycling: about x, about y, both (signs chosen to face the image centre
  // for border positions, so the board's far edge still fits).
  std::vector<Pose> plan;
  for (int i = 0; i < options.view_count; ++i) {
    const double* d = dirs[i % 9];
    const int tilt_kind = (i / 9 + i) % 3;
    const double magnitude = options.max_tilt_rad * (0.75 + 0.25 * jitter(rng));
    const double sign = (i / 9) % 2 == 0 ? 1.0 : -1.0;
    double tilt_x = 0.0, tilt_y = 0.0;
    if (tilt_kind == 0 || tilt_kind == 2) tilt_x = sign * magnitude * (tilt_kind == 2 ? 0.7071 : 1.0);
    if (tilt_kind == 1 || tilt_kind == 2) tilt_y = -sign * magnitude * (tilt_kind == 2 ? 0.7071 : 1.0);
    const Eigen::Matrix3d R_C_K = (Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()) *
                                   Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()))
                                      .toRotationMatrix();
    Eigen::Vector2d dir(d[0] + 0.05 * jitter(rng), d[1] + 0.05 * jitter(rng));
    // Push the centre as far out along dir as the board still fits (bisection).
    double lo = 0.0, hi = 1.0;
    Eigen::Matrix3d R = R_C_K;
    if (!fits(pose_at(R, image_centre))) R = Eigen::Matrix3d::Identity();  // tilt too strong here
    for (int it = 0; it < 30; ++it) {
      const double s = 0.5 * (lo + hi);
      const Eigen::Vector2d target = image_centre + s * Eigen::Vector2d(dir.x() * half_w, dir.y() * half_h);
      (fits(pose_at(R, target)) ? lo : hi) = s;
    }
    const Eigen::Vector2d target = image_centre + lo * Eigen::Vector2d(dir.x() * half_w, dir.y() * half_h);
    plan.push_back(pose_at(R, target).inverse());
  }
  return plan;
}

}  // namespace romunect::calib
