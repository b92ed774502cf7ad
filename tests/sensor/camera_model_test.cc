#include "romunect/sensor/camera_model.h"

#include <random>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

// OpenCV and we evaluate the same polynomial in doubles: only round-off may differ.
constexpr double kProjectionTolerancePx = 1e-6;
// Round trips go through an iterative inverse that converges to machine precision.
constexpr double kRoundTripTolerancePx = 1e-9;

CameraModel DistortedCamera() {
  CameraModel c;
  c.width = 640;
  c.height = 480;
  c.fx = 2400.0;  // a C-mount lens at 200 mm: about 6 cm across 640 px
  c.fy = 2398.0;
  c.cx = 322.3;
  c.cy = 236.8;
  c.distortion = {-0.21, 0.15, 0.0012, -0.0008, -0.05};
  return c;
}

std::vector<cv::Point3d> RandomPointsInView(const CameraModel& c, int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-0.5, c.width - 0.5), v(-0.5, c.height - 0.5), z(0.15, 0.5);
  std::vector<cv::Point3d> points;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d p = c.Unproject(Eigen::Vector2d(u(rng), v(rng)), z(rng));
    points.emplace_back(p.x(), p.y(), p.z());
  }
  return points;
}

TEST(CameraModel, ProjectMatchesOpenCvProjectPoints) {
  const CameraModel c = DistortedCamera();
  const std::vector<cv::Point3d> points = RandomPointsInView(c, 2000, 1);
  std::vector<cv::Point2d> expected;
  cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cv::Mat(c.CameraMatrix()), c.DistortionVector(),
                    expected);
  for (size_t i = 0; i < points.size(); ++i) {
    const auto u = c.Project(Eigen::Vector3d(points[i].x, points[i].y, points[i].z));
    ASSERT_TRUE(u.has_value());
    EXPECT_NEAR(u->x(), expected[i].x, kProjectionTolerancePx);
    EXPECT_NEAR(u->y(), expected[i].y, kProjectionTolerancePx);
  }
}

TEST(CameraModel, UndistortMatchesOpenCvUndistortPoints) {
  const CameraModel c = DistortedCamera();
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-0.5, c.width - 0.5), v(-0.5, c.height - 0.5);
  std::vector<cv::Point2d> pixels;
  for (int i = 0; i < 2000; ++i) pixels.emplace_back(u(rng), v(rng));
  std::vector<cv::Point2d> expected;
  // OpenCV's default stops after 5 iterations; ask it to converge so both are exact inverses.
  cv::undistortPoints(pixels, expected, cv::Mat(c.CameraMatrix()), c.DistortionVector(), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-15));
  for (size_t i = 0; i < pixels.size(); ++i) {
    const Eigen::Vector3d ray = c.Ray(Eigen::Vector2d(pixels[i].x, pixels[i].y));
    // Compare in pixels of the ideal camera.
    EXPECT_NEAR(c.fx * ray.x(), c.fx * expected[i].x, kProjectionTolerancePx);
    EXPECT_NEAR(c.fy * ray.y(), c.fy * expected[i].y, kProjectionTolerancePx);
  }
}

TEST(CameraModel, UnprojectThenProjectIsIdentity) {
  const CameraModel c = DistortedCamera();
  for (int v = 0; v < c.height; v += 7) {
    for (int u = 0; u < c.width; u += 7) {
      const Eigen::Vector2d px(u + 0.25, v - 0.3);
      const auto back = c.Project(c.Unproject(px, 0.2));
      ASSERT_TRUE(back.has_value());
      EXPECT_LT((*back - px).norm(), kRoundTripTolerancePx) << "at " << px.transpose();
    }
  }
}

TEST(CameraModel, RayHasUnitDepthAndPrincipalPointLooksForward) {
  CameraModel c = DistortedCamera();
  const Eigen::Vector3d ray = c.Ray(Eigen::Vector2d(c.cx, c.cy));
  EXPECT_DOUBLE_EQ(ray.z(), 1.0);
  EXPECT_NEAR(ray.x(), 0.0, 1e-15);
  EXPECT_NEAR(ray.y(), 0.0, 1e-15);
  EXPECT_FALSE(c.Project(Eigen::Vector3d(0, 0, -1)).has_value());
  EXPECT_FALSE(c.Project(Eigen::Vector3d(0, 0, 0)).has_value());
}

TEST(CameraModel, RayTableMatchesRay) {
  CameraModel c = DistortedCamera();
  c.width = 64;
  c.height = 48;
  c.cx = 31.5;
  c.cy = 23.5;
  c.fx = c.fy = 240.0;
  const cv::Mat table = c.RayTable();
  ASSERT_EQ(table.type(), CV_32FC2);
  for (int v = 0; v < c.height; ++v) {
    for (int u = 0; u < c.width; ++u) {
      const Eigen::Vector3d ray = c.Ray(Eigen::Vector2d(u, v));
      EXPECT_FLOAT_EQ(table.at<cv::Vec2f>(v, u)[0], static_cast<float>(ray.x()));
      EXPECT_FLOAT_EQ(table.at<cv::Vec2f>(v, u)[1], static_cast<float>(ray.y()));
    }
  }
}

TEST(CameraModel, PixelCentreConvention) {
  CameraModel c;
  EXPECT_TRUE(c.Contains(Eigen::Vector2d(-0.5, -0.5)));
  EXPECT_FALSE(c.Contains(Eigen::Vector2d(-0.51, 0)));
  EXPECT_TRUE(c.Contains(Eigen::Vector2d(639.49, 479.49)));
  EXPECT_FALSE(c.Contains(Eigen::Vector2d(639.5, 0)));
}

TEST(CameraModel, SavesAndLoadsThroughFileStorage) {
  testing::ScratchDir dir("camera");
  const CameraModel c = DistortedCamera();
  for (const char* name : {"camera.yaml", "camera.json", "camera.xml"}) {
    c.Save(dir / name);
    EXPECT_EQ(CameraModel::Load(dir / name), c) << name;
    // Plain OpenCV reads it under OpenCV's usual names.
    cv::FileStorage fs((dir / name).string(), cv::FileStorage::READ);
    cv::Mat K;
    fs["camera_matrix"] >> K;
    EXPECT_DOUBLE_EQ(K.at<double>(0, 0), c.fx);
  }
}

TEST(CameraModel, RejectsBadModelsAndFiles) {
  CameraModel c;
  c.fx = -1;
  EXPECT_NE(c.Problem(), "");
  c = CameraModel();
  c.width = 0;
  EXPECT_NE(c.Problem(), "");
  c = CameraModel();
  c.distortion[0] = std::nan("");
  EXPECT_NE(c.Problem(), "");
  c = CameraModel();
  c.distortion[0] = -50.0;  // folds the image over itself
  EXPECT_NE(c.Problem(), "");

  testing::ScratchDir dir("bad");
  testing::WriteText(dir / "no_k.yaml", "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n");
  EXPECT_THROW(
      {
        try {
          CameraModel::Load(dir / "no_k.yaml");
        } catch (const InputError& e) {
          EXPECT_NE(std::string(e.what()).find("camera_matrix"), std::string::npos) << e.what();
          throw;
        }
      },
      InputError);
  EXPECT_THROW(CameraModel::Load(dir / "missing.yaml"), InputError);
  // A list where a map is expected made OpenCV throw its own exception (found by the fuzz target).
  testing::WriteText(dir / "list.yaml", "%YAML:1.0\n---\n- 1\n- 2\n");
  EXPECT_THROW(CameraModel::Load(dir / "list.yaml"), InputError);
  testing::WriteText(dir / "huge.yaml", "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n"
                                        "camera_matrix: !!opencv-matrix\n   rows: 2000000000\n   cols: 3\n   dt: d\n"
                                        "   data: [ 1. ]\n");
  EXPECT_THROW(CameraModel::Load(dir / "huge.yaml"), InputError);
}

// Values no camera has are refused with the field named: they used to pass (fx = 1e308, k1 = 1e10,
// a 100,000 px image) or to go through an undefined cast (image_width 1e300).
TEST(CameraModel, RefusesValuesBeyondPhysicalBounds) {
  const auto problem_with = [](auto change) {
    CameraModel c;
    change(&c);
    return c.Problem();
  };
  EXPECT_EQ(problem_with([](CameraModel*) {}), "");
  EXPECT_NE(problem_with([](CameraModel* c) { c->fx = 1e308; }).find("focal lengths"), std::string::npos);
  EXPECT_NE(problem_with([](CameraModel* c) { c->fy = 1e-3; }).find("focal lengths"), std::string::npos);
  EXPECT_NE(problem_with([](CameraModel* c) { c->distortion[0] = 1e10; }).find("k1, k2, k3"), std::string::npos);
  EXPECT_NE(problem_with([](CameraModel* c) { c->distortion[3] = 2.0; }).find("p1, p2"), std::string::npos);
  EXPECT_NE(problem_with([](CameraModel* c) { c->width = 100000; }).find("image size"), std::string::npos);
  EXPECT_NE(problem_with([](CameraModel* c) { c->cx = 1e9; }).find("principal point"), std::string::npos);

  testing::ScratchDir dir("bounds");
  CameraModel().Save(dir / "camera.yaml");
  std::string text = testing::ReadText(dir / "camera.yaml");
  const size_t at = text.find("image_width: ") + std::string("image_width: ").size();
  text.replace(at, text.find('\n', at) - at, "1.0e+300");
  testing::WriteText(dir / "camera.yaml", text);
  try {
    CameraModel::Load(dir / "camera.yaml");
    ADD_FAILURE() << "loaded image_width 1e300";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "image_width/image_height") << e.what();
    EXPECT_NE(std::string(e.what()).find("must lie in [1, 16384]"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace romunect
