#include "synthetic.h"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/frame_io.h"

namespace romunect::calib::testing {

CameraModel TruthCamera() {
  CameraModel c;
  c.width = 640;
  c.height = 480;
  c.fx = 580.0;
  c.fy = 581.5;
  c.cx = 322.3;
  c.cy = 236.8;
  c.distortion = {-0.21, 0.12, 0.0008, -0.0005, 0.0};
  return c;
}

CameraModel Scaled(const CameraModel& camera, double factor) {
  CameraModel c = camera;
  c.width = static_cast<int>(std::lround(camera.width * factor));
  c.height = static_cast<int>(std::lround(camera.height * factor));
  c.fx *= factor;
  c.fy *= factor;
  // Pixel centres at integers: the image's edge at -0.5 stays at -0.5.
  c.cx = (camera.cx + 0.5) * factor - 0.5;
  c.cy = (camera.cy + 0.5) * factor - 0.5;
  return c;
}

std::optional<BoardView> ObserveBoard(const CameraModel& camera, const BoardSpec& board, const Pose& T_C_K,
                                      double sigma_px, std::mt19937* rng) {
  BoardView view;
  if (!ProjectBoard(camera, board, T_C_K, &view.corners_px)) return std::nullopt;
  std::normal_distribution<double> noise(0.0, sigma_px);
  for (cv::Point2f& p : view.corners_px) {
    p.x += static_cast<float>(noise(*rng));
    p.y += static_cast<float>(noise(*rng));
  }
  return view;
}

namespace {
Eigen::Matrix3d Rotation(double rx, double ry, double rz) {
  return (Eigen::AngleAxisd(rz, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(rx, Eigen::Vector3d::UnitX()) *
          Eigen::AngleAxisd(ry, Eigen::Vector3d::UnitY()))
      .toRotationMatrix();
}
}  // namespace

std::vector<Pose> CentralViews(const CameraModel& camera, const BoardSpec& board, int count, double distance_m,
                               std::mt19937* rng) {
  std::uniform_real_distribution<double> tilt(-0.15, 0.15), shift(-0.01, 0.01);
  std::vector<Pose> poses;
  while (static_cast<int>(poses.size()) < count) {
    const Eigen::Matrix3d R = Rotation(tilt(*rng), tilt(*rng), 0.5 * tilt(*rng));
    const Eigen::Vector3d centre_C(shift(*rng), shift(*rng), distance_m);
    const Pose T_C_K = MakePose(R, centre_C - R * board.CentreK());
    std::vector<cv::Point2f> px;
    if (ProjectBoard(camera, board, T_C_K, &px)) poses.push_back(T_C_K);
  }
  return poses;
}

Pose TruthHandEye() {
  // Camera 80 mm ahead of the flange, offset sideways, looking along -x_H (within ~2 deg).
  return MakePose(Rotation(0.05, -1.54, 0.03), Eigen::Vector3d(0.032, -0.047, 0.081));
}

Pose TruthBoardInBase() { return MakePose(Rotation(0.02, -0.01, 0.4), Eigen::Vector3d(0.55, 0.12, 0.02)); }

HandEyeRig MakeHandEyeRig(const CameraModel& camera, const BoardSpec& board, int stations, double sigma_px,
                          double max_tilt_rad, double max_roll_rad, unsigned seed) {
  std::mt19937 rng(seed);
  HandEyeRig rig;
  rig.T_H_C = TruthHandEye();
  rig.T_B_K = TruthBoardInBase();
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  int guard = 0;
  while (static_cast<int>(rig.stations.size()) < stations) {
    ROMUNECT_CHECK(++guard < 100000);
    // Camera looks at the board centre from above (board z points away from the camera).
    const Eigen::Matrix3d R_C_K = Rotation(max_tilt_rad * unit(rng), max_tilt_rad * unit(rng),
                                           max_roll_rad * unit(rng));
    const double distance_m = 0.3 + 0.05 * unit(rng);
    const Eigen::Vector3d centre_C(0.02 * unit(rng), 0.02 * unit(rng), distance_m);
    const Pose T_C_K = MakePose(R_C_K, centre_C - R_C_K * board.CentreK());
    auto view = ObserveBoard(camera, board, T_C_K, sigma_px, &rng);
    if (!view) continue;
    view->name = "station " + std::to_string(rig.stations.size());
    const Pose T_B_H = rig.T_B_K * T_C_K.inverse() * rig.T_H_C.inverse();
    rig.stations.push_back({T_B_H, *view});
    rig.T_C_K_truth.push_back(T_C_K);
  }
  return rig;
}

void RawDepthTruth::Maps(const CameraModel& camera, cv::Mat* alpha, cv::Mat* beta) const {
  // raw = raw_ref + raw_per_px * fb_eff(x,y) * (1/Z_ref - 1/Z), so
  // 1/Z = 1/Z_ref - (raw - raw_ref) / (raw_per_px * fb_eff), i.e. alpha raw + beta.
  // fb_eff varies smoothly (+-3 %) and the reference depth by +-1 mm over the image.
  *alpha = cv::Mat(camera.height, camera.width, CV_64F);
  *beta = cv::Mat(camera.height, camera.width, CV_64F);
  for (int r = 0; r < camera.height; ++r) {
    for (int c = 0; c < camera.width; ++c) {
      const double x = (c - 0.5 * camera.width) / camera.width, y = (r - 0.5 * camera.height) / camera.height;
      const double fb = focal_baseline_px_m * (1.0 + 0.06 * x - 0.04 * y + 0.05 * x * y);
      const double z_ref = reference_depth_m + 0.001 * (x * x - y);
      const double a = -1.0 / (raw_per_px * fb);
      alpha->at<double>(r, c) = a;
      beta->at<double>(r, c) = 1.0 / z_ref - a * raw_at_reference;
    }
  }
}

cv::Mat RenderPlaneRaw(const CameraModel& camera, const RawDepthTruth& truth, const Pose& T_C_K, double sigma_raw,
                       std::mt19937* rng, int invalid_raw) {
  cv::Mat alpha, beta;
  truth.Maps(camera, &alpha, &beta);
  const cv::Mat depth = PlaneDepth(camera, T_C_K);
  std::normal_distribution<double> noise(0.0, sigma_raw);
  cv::Mat raw(camera.height, camera.width, CV_16UC1);
  for (int r = 0; r < camera.height; ++r) {
    for (int c = 0; c < camera.width; ++c) {
      const double z = depth.at<float>(r, c);
      const double value = z > 0 ? (1.0 / z - beta.at<double>(r, c)) / alpha.at<double>(r, c) + noise(*rng) : -1;
      raw.at<uint16_t>(r, c) = (value >= 0 && value < invalid_raw - 0.5) ? static_cast<uint16_t>(std::lround(value))
                                                                         : static_cast<uint16_t>(invalid_raw);
    }
  }
  return raw;
}

Pose PlaneAt(double depth_m, double tilt_x_rad, double tilt_y_rad) {
  const Eigen::Matrix3d R = Rotation(tilt_x_rad, tilt_y_rad, 0.0);
  return MakePose(R, Eigen::Vector3d(0, 0, depth_m));
}

cv::Mat RenderBoardImage(const CameraModel& camera, const BoardSpec& board, const Pose& T_C_K) {
  ROMUNECT_CHECK(!camera.HasDistortion());
  const int px_per_square = 40;
  const int w = (board.cols + 3) * px_per_square, h = (board.rows + 3) * px_per_square;
  cv::Mat texture(h, w, CV_8U, cv::Scalar(255));
  // Inner corner (0,0) at texture position (2, 2) squares; squares from 1 to cols+1.
  for (int r = 0; r <= board.rows; ++r) {
    for (int c = 0; c <= board.cols; ++c) {
      if ((r + c) % 2 == 0) {
        texture(cv::Rect((c + 1) * px_per_square, (r + 1) * px_per_square, px_per_square, px_per_square)) = 0;
      }
    }
  }
  // Texture pixel centre (i, j) -> K point: ((i + 0.5)/pps - 2) * square (edges at integers - 0.5).
  const double s = board.square_m / px_per_square;
  Eigen::Matrix3d A;  // texture px -> K (x, y, 1)
  A << s, 0, (0.5 / px_per_square - 2) * board.square_m, 0, s, (0.5 / px_per_square - 2) * board.square_m, 0, 0, 1;
  Eigen::Matrix3d P;  // K (x, y, 1) on z = 0 -> image
  const Eigen::Matrix3d K_mat =
      (Eigen::Matrix3d() << camera.fx, 0, camera.cx, 0, camera.fy, camera.cy, 0, 0, 1).finished();
  P.col(0) = T_C_K.linear().col(0);
  P.col(1) = T_C_K.linear().col(1);
  P.col(2) = T_C_K.translation();
  // Rendered at 4x and area-averaged down (anti-aliased edges); pixel u of the image covers
  // 4u .. 4u+3 of the large one, centred at 4u + 1.5.
  const Eigen::Matrix3d S = (Eigen::Matrix3d() << 4, 0, 1.5, 0, 4, 1.5, 0, 0, 1).finished();
  const Eigen::Matrix3d H = S * K_mat * P * A;
  cv::Mat H_cv(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) H_cv.at<double>(r, c) = H(r, c);
  }
  cv::Mat large, image;
  cv::warpPerspective(texture, large, H_cv, cv::Size(4 * camera.width, 4 * camera.height), cv::INTER_LINEAR,
                      cv::BORDER_CONSTANT, cv::Scalar(128));
  cv::resize(large, image, cv::Size(camera.width, camera.height), 0, 0, cv::INTER_AREA);
  return image;
}

ProjectorScene::ProjectorScene()
    : camera(TruthCamera()),
      T_C_P(MakePose(Eigen::AngleAxisd(0.06, Eigen::Vector3d(0.1, 1, 0.05).normalized()).toRotationMatrix(),
                     Eigen::Vector3d(0.075, 0.002, -0.001))),
      T_C_K(PlaneAt(0.2, 0.05, -0.08)) {
  projector.width = 1280;
  projector.height = 800;
  projector.fx = projector.fy = 1400.0;
  projector.cx = 639.5;
  projector.cy = 399.5;
  for (int r = 0; r < 8; ++r) {
    for (int c = 0; c < 12; ++c) {
      pattern_P.emplace_back(100 + c * 98.0, 80 + r * 90.0);
      const Eigen::Vector2d ideal(60 + c * 47.0, 50 + r * 52.0);
      const Eigen::Vector3d ray((ideal.x() - camera.cx) / camera.fx, (ideal.y() - camera.cy) / camera.fy, 1.0);
      target_C.push_back(*camera.Project(ray));
    }
  }
}

Eigen::Vector2d ProjectorScene::Map(const Eigen::Vector2d& q_P) const {
  const Eigen::Vector3d ray_C = T_C_P.linear() * projector.Ray(q_P);
  const Eigen::Vector3d o_C = T_C_P.translation();
  const Eigen::Vector3d n = T_C_K.linear().col(2);
  const double s = n.dot(T_C_K.translation() - o_C) / n.dot(ray_C);
  return *camera.Project(o_C + s * ray_C);
}

double ProjectorScene::TrueResidualPx(const Eigen::Matrix3d& H_P_rec) const {
  double sum = 0.0;
  for (size_t i = 0; i < pattern_P.size(); ++i) {
    sum += (Map((H_P_rec * pattern_P[i].homogeneous()).hnormalized()) - target_C[i]).squaredNorm();
  }
  return std::sqrt(sum / pattern_P.size());
}

void WriteBoardFrames(const std::filesystem::path& dir, const CameraModel& camera, const BoardSpec& board,
                      const HandEyeRig& rig) {
  FrameDirectoryWriter writer(dir, camera);
  for (size_t i = 0; i < rig.stations.size(); ++i) {
    Frame frame;
    frame.index = static_cast<int>(i);
    frame.time_s = 0.1 * i;
    RenderBoardImage(camera, board, rig.T_C_K_truth[i]).convertTo(frame.ir, CV_16U, 4.0);
    frame.raw = cv::Mat(camera.height, camera.width, CV_16U, cv::Scalar(kRawInvalid));
    frame.T_B_H = rig.stations[i].T_B_H;
    writer.Add(frame);
  }
  writer.Finish();
}

void WritePlaneFrames(const std::filesystem::path& dir, const CameraModel& camera, const HandEyeRig& rig, int planes,
                      unsigned seed) {
  std::mt19937 rng(seed);
  const RawDepthTruth truth;
  FrameDirectoryWriter writer(dir, camera);
  for (int i = 0; i < planes; ++i) {
    const Pose T_C_K = PlaneAt(0.19 + 0.02 * i / (planes - 1.0), 0.1 * std::sin(i), 0.1 * std::cos(i));
    Frame frame;
    frame.index = i;
    frame.time_s = 0.1 * i;
    frame.raw = RenderPlaneRaw(camera, truth, T_C_K, 0.3, &rng);
    frame.T_B_H = rig.T_B_K * T_C_K.inverse() * rig.T_H_C.inverse();
    writer.Add(frame);
  }
  writer.Finish();
}

}  // namespace romunect::calib::testing
