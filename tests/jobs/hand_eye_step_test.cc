// The hand-eye step on data as a robot delivers it: a folder of board images (8 or 16 bit) and
// a pose file (16 numbers per line, or the CSV pose log), rendered here from a known T_H_C. The
// usual mistakes (millimetres read as metres, inverted poses, a pairing one pose off, a wrong
// square size) are each refused with the cause named and nothing written.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <random>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "romunect/calib/calibration_file.h"
#include "romunect/calib/hand_eye_check.h"
#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/calibrate.h"
#include "synthetic.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using romunect::testing::InputErrorOf;
using romunect::testing::ScratchDir;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr double kDeg = M_PI / 180.0;
// Rendered, 4x supersampled 640 x 480 images, camera refined: within 0.05 deg (0.02 deg
// measured); the 0.01 deg bar holds at 1920 x 1080 (hand_eye_images_benchmark).
constexpr double kHandEyeAngleRad = 0.05 * kDeg;
constexpr double kHandEyeTranslationM = 0.3e-3;

struct Scene {
  CameraModel camera;
  calib::BoardSpec board{9, 6, 0.025};
  calib::testing::HandEyeRig rig;
  Scene(int stations, unsigned seed) : camera(calib::testing::TruthCamera()) {
    camera.distortion = {};  // the board image renderer is a homography
    rig = calib::testing::MakeHandEyeRig(camera, board, stations, 0.0, 0.5, 0.8, seed);
  }
};

// Images first..first+count-1 of the rig as img_NN.png (8 or 16 bit).
void WriteImages(const fs::path& dir, const Scene& scene, int first, int count, bool sixteen_bit) {
  fs::create_directories(dir);
  for (int i = 0; i < count; ++i) {
    cv::Mat image = calib::testing::RenderBoardImage(scene.camera, scene.board, scene.rig.T_C_K_truth[first + i]);
    if (sixteen_bit) image.convertTo(image, CV_16U, 4.0);  // 10 bits used, as the IR stream
    char name[32];
    std::snprintf(name, sizeof(name), "img_%02d.png", i);
    cv::imwrite((dir / name).string(), image);
  }
}

// One 4x4 row-major matrix per line with `decimals` decimals.
void WritePoses(const fs::path& file, const std::vector<Pose>& poses, int decimals) {
  std::ofstream out(file);
  out << "# T_B_H, row-major\n";
  for (const Pose& T : poses) {
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) out << std::fixed << std::setprecision(decimals) << T.matrix()(r, c) << ' ';
    }
    out << '\n';
  }
}

std::vector<Pose> TruePoses(const Scene& scene, int first, int count) {
  std::vector<Pose> poses;
  for (int i = first; i < first + count; ++i) poses.push_back(scene.rig.stations[i].T_B_H);
  return poses;
}

fs::path WriteIntrinsics(const fs::path& dir, const CameraModel& camera, double focal_scale = 1.0) {
  calib::Calibration c;
  c.camera = camera;
  c.camera.fx *= focal_scale;
  c.camera.fy *= focal_scale;
  c.residuals.intrinsics_rms_px = 0.05;
  const fs::path file = dir / "intrinsics.yaml";
  calib::SaveCalibration(file, c);
  return file;
}

HandEyeStepOptions Step(const fs::path& dir, const fs::path& intrinsics) {
  HandEyeStepOptions o;
  o.images = (dir / "images").string();
  o.poses.log = (dir / "poses.txt").string();
  o.intrinsics = intrinsics.string();
  o.file.output = (dir / "out.yaml").string();
  return o;
}

TEST(HandEyeStep, ImagesAndAPoseFileRecoverTheTruth) {
  ScratchDir dir("he_images");
  const Scene scene(15, 3);
  WriteImages(dir / "images", scene, 0, 15, false);  // 8-bit
  WritePoses(dir / "poses.txt", TruePoses(scene, 0, 15), 17);
  // intrinsics from weakly tilted views: the focal length 0.1 % short
  HandEyeStepOptions o = Step(dir.path(), WriteIntrinsics(dir.path(), scene.camera, 0.999));
  o.refine_intrinsics = true;
  ::testing::internal::CaptureStdout();
  const calib::Calibration c = RunHandEyeStep(o);
  const std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_THAT(out, HasSubstr("constrain the focal length weakly"));
  EXPECT_THAT(out, HasSubstr("stations used"));
  EXPECT_TRUE(romunect::testing::PosesNear(c.T_H_C, scene.rig.T_H_C, kHandEyeAngleRad, kHandEyeTranslationM));
  EXPECT_NEAR(c.camera.fx, scene.camera.fx, 0.1);  // refined back: 0.1 % is 0.58 px
  EXPECT_TRUE(fs::exists(o.file.output));
  EXPECT_FALSE(fs::exists(dir / "images" / "out.yaml"));
}

TEST(HandEyeStep, SixteenBitImagesAndRoundedMillimetrePosesInverted) {
  ScratchDir dir("he_16bit_mm");
  const Scene scene(15, 4);
  WriteImages(dir / "images", scene, 0, 15, true);
  std::vector<Pose> poses = TruePoses(scene, 0, 15);
  for (Pose& T : poses) {
    T = T.inverse();
    T.translation() *= 1000.0;
  }
  WritePoses(dir / "poses.txt", poses, 6);  // rotations rounded: re-orthonormalized
  HandEyeStepOptions o = Step(dir.path(), WriteIntrinsics(dir.path(), scene.camera));
  o.pose_units = "mm";
  o.poses_are = "base-in-hand";
  ::testing::internal::CaptureStdout();
  const calib::Calibration c = RunHandEyeStep(o);
  const std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_THAT(out, HasSubstr("rotations re-orthonormalized"));
  EXPECT_THAT(out, Not(HasSubstr("weakly")));  // the true camera: no warning about its focal length
  // 6 decimals of millimetres and rotations: 1e-6 rad, well below the goal
  EXPECT_TRUE(romunect::testing::PosesNear(c.T_H_C, scene.rig.T_H_C, kHandEyeAngleRad, kHandEyeTranslationM));
}

// Each mistake: refused, its cause and remedy named, nothing written.
void ExpectRefused(const fs::path& dir, const HandEyeStepOptions& o, const std::string& remedy) {
  const std::string error = InputErrorOf([&] { RunHandEyeStep(o); });
  EXPECT_THAT(error, HasSubstr("over the limit"));
  EXPECT_THAT(error, HasSubstr(remedy));
  EXPECT_FALSE(fs::exists(o.file.output)) << dir;
}

TEST(HandEyeStep, MillimetresGivenAsMetresAreRefusedAndNamed) {
  ScratchDir dir("he_mm");
  const Scene scene(15, 5);
  WriteImages(dir / "images", scene, 0, 15, false);
  std::vector<Pose> poses = TruePoses(scene, 0, 15);
  for (Pose& T : poses) T.translation() *= 1000.0;
  WritePoses(dir / "poses.txt", poses, 9);
  ExpectRefused(dir.path(), Step(dir.path(), WriteIntrinsics(dir.path(), scene.camera)), "--pose-units mm");
}

TEST(HandEyeStep, InvertedPosesAreRefusedAndNamed) {
  ScratchDir dir("he_inverted");
  const Scene scene(15, 6);
  WriteImages(dir / "images", scene, 0, 15, false);
  std::vector<Pose> poses = TruePoses(scene, 0, 15);
  for (Pose& T : poses) T = T.inverse();
  WritePoses(dir / "poses.txt", poses, 12);
  ExpectRefused(dir.path(), Step(dir.path(), WriteIntrinsics(dir.path(), scene.camera)), "--poses-are base-in-hand");
}

TEST(HandEyeStep, APairingOneOffIsRefusedAndNamed) {
  ScratchDir dir("he_shifted");
  const Scene scene(16, 7);
  WriteImages(dir / "images", scene, 1, 15, false);            // image i shows station i + 1
  WritePoses(dir / "poses.txt", TruePoses(scene, 0, 15), 12);  // pose i is station i
  ExpectRefused(dir.path(), Step(dir.path(), WriteIntrinsics(dir.path(), scene.camera)),
                "image i paired with pose i + 1");
}

TEST(HandEyeStep, AWrongSquareSizeIsRefusedAndTheRightOneNamed) {
  ScratchDir dir("he_square");
  const Scene scene(15, 8);
  WriteImages(dir / "images", scene, 0, 15, false);
  WritePoses(dir / "poses.txt", TruePoses(scene, 0, 15), 12);
  HandEyeStepOptions o = Step(dir.path(), WriteIntrinsics(dir.path(), scene.camera));
  o.square_m = 0.030;
  ExpectRefused(dir.path(), o, "--square 0.0250");
}

TEST(HandEyeStep, InputIsCheckedBeforeAnyWork) {
  ScratchDir dir("he_input");
  const Scene scene(6, 9);
  WriteImages(dir / "images", scene, 0, 6, false);
  const fs::path intrinsics = WriteIntrinsics(dir.path(), scene.camera);
  WritePoses(dir / "poses.txt", TruePoses(scene, 0, 5), 12);
  EXPECT_THAT(InputErrorOf([&] { RunHandEyeStep(Step(dir.path(), intrinsics)); }), HasSubstr("5 poses for 6 images"));

  std::vector<Pose> poses = TruePoses(scene, 0, 6);
  poses[2].linear() *= 1.001;  // 2e-3 off orthonormal: no rounding does that
  WritePoses(dir / "poses.txt", poses, 12);
  EXPECT_THAT(InputErrorOf([&] { RunHandEyeStep(Step(dir.path(), intrinsics)); }), HasSubstr("not orthonormal"));

  HandEyeStepOptions o = Step(dir.path(), intrinsics);
  o.square_m = 0.0;
  EXPECT_THAT(InputErrorOf([&] { RunHandEyeStep(o); }), HasSubstr("--square"));
  o = Step(dir.path(), intrinsics);
  o.frames = "somewhere";
  EXPECT_THAT(InputErrorOf([&] { RunHandEyeStep(o); }), HasSubstr("either --frames"));
  EXPECT_FALSE(fs::exists(o.file.output));
}

// Fit on even stations, reproject the odd ones: the refined fit against OpenCV's five solvers.
TEST(HandEyeCheck, HeldOutErrorIsNoWorseThanOpenCvsBest) {
  const Scene scene(30, 11);
  std::mt19937 rng(12);
  calib::HandEyeCaptures fit, held_out;
  for (size_t i = 0; i < scene.rig.stations.size(); ++i) {
    auto view = calib::testing::ObserveBoard(scene.camera, scene.board, scene.rig.T_C_K_truth[i], 0.1, &rng);
    ASSERT_TRUE(view.has_value());
    calib::HandEyeCaptures& into = i % 2 == 0 ? fit : held_out;
    into.T_B_H.push_back(scene.rig.stations[i].T_B_H);
    into.views.push_back(view);
  }
  const calib::CheckedHandEye ours = calib::CalibrateHandEyeChecked(fit, scene.camera, scene.board);
  ASSERT_TRUE(ours.accepted);
  const auto held_out_rms = [&](const calib::HandEyeResult& r) {
    const std::vector<double> per = calib::HandEyeStationRmsPx(held_out.Stations(), r, scene.board);
    double sum = 0.0;
    for (double v : per) sum += v * v;
    return std::sqrt(sum / per.size());
  };
  const double ours_px = held_out_rms(ours.fit);
  double best_opencv_px = 1e9;
  for (const calib::OpenCvHandEyeResult& cv : calib::OpenCvHandEyeAll(fit.Stations(), scene.camera, scene.board)) {
    best_opencv_px = std::min(best_opencv_px, held_out_rms(cv.fit));
  }
  std::printf("held-out RMS: ours %.4f px, best of OpenCV's five %.4f px\n", ours_px, best_opencv_px);
  EXPECT_LE(ours_px, best_opencv_px);
}

}  // namespace
}  // namespace romunect::jobs
