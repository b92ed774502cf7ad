#include "romunect/calib/calibration_file.h"

#include <cmath>
#include <fstream>
// GCC 12 reports a false -Wmaybe-uninitialized inside <regex>'s std::function members.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include <regex>
#pragma GCC diagnostic pop

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

namespace fs = std::filesystem;
using romunect::testing::ReadText;
using romunect::testing::ScratchDir;
using romunect::testing::WriteText;

Calibration Sample() {
  Calibration c;
  c.camera = testing::Scaled(testing::TruthCamera(), 0.1);  // 64 x 48, small maps
  c.H_P_rec << 1.01, 0.02, -3.5, -0.01, 0.99, 2.25, 1e-6, -2e-6, 1.0;
  c.T_H_C = testing::TruthHandEye();
  c.T_B_K = testing::TruthBoardInBase();
  // Float values, as a fit gives and the file stores.
  cv::Mat a(c.camera.height, c.camera.width, CV_32F), b(c.camera.height, c.camera.width, CV_32F);
  cv::randu(a, -0.003, -0.002);
  cv::randu(b, 6.0, 7.0);
  a.at<float>(3, 4) = std::numeric_limits<float>::quiet_NaN();  // an unfitted pixel
  c.depth = DepthCorrection{DepthCorrectionModel::kInverseAffineInRaw, {}, {}};
  a.convertTo(c.depth->a, CV_64F);
  b.convertTo(c.depth->b, CV_64F);
  c.chip.baseline_m = 0.0751;
  c.chip.raw_offset = 1091.5;
  c.date = "2026-11-26T12:00:00Z";
  c.residuals = {0.19, 0.21, 0.2, 0.05, 3e-5};
  return c;
}

// Same size and values, NaN where the other has NaN (YAML writes NaN as .Nan, sign lost).
::testing::AssertionResult MapsEqual(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != CV_64F || b.type() != CV_64F)
    return ::testing::AssertionFailure() << "size/type";
  for (int r = 0; r < a.rows; ++r) {
    for (int c = 0; c < a.cols; ++c) {
      const double x = a.at<double>(r, c), y = b.at<double>(r, c);
      if (!(x == y || (std::isnan(x) && std::isnan(y)))) {
        return ::testing::AssertionFailure() << "differ at " << c << "," << r << ": " << x << " vs " << y;
      }
    }
  }
  return ::testing::AssertionSuccess();
}

void ExpectSame(const Calibration& a, const Calibration& b) {
  EXPECT_EQ(a.camera, b.camera);
  EXPECT_EQ(a.H_P_rec, b.H_P_rec);
  EXPECT_TRUE(a.T_H_C.isApprox(b.T_H_C, 1e-15));
  EXPECT_TRUE(a.T_B_K.isApprox(b.T_B_K, 1e-15));
  ASSERT_EQ(a.depth.has_value(), b.depth.has_value());
  if (a.depth) {
    EXPECT_EQ(a.depth->model, b.depth->model);
    EXPECT_TRUE(MapsEqual(a.depth->a, b.depth->a));
    EXPECT_TRUE(MapsEqual(a.depth->b, b.depth->b));
  }
  EXPECT_EQ(a.chip.camera.fx, b.chip.camera.fx);
  EXPECT_EQ(a.chip.baseline_m, b.chip.baseline_m);
  EXPECT_EQ(a.chip.raw_offset, b.chip.raw_offset);
  EXPECT_EQ(a.date, b.date);
  EXPECT_EQ(a.residuals.depth_rms_m, b.residuals.depth_rms_m);
  EXPECT_EQ(a.residuals.intrinsics_holdout_rms_px, b.residuals.intrinsics_holdout_rms_px);
}

TEST(CalibrationFileTest, RoundTripsAndPlainOpenCvReadsIt) {
  ScratchDir dir("file");
  const Calibration c = Sample();
  SaveCalibration(dir / "calib.yaml", c);
  ExpectSame(LoadCalibration(dir / "calib.yaml"), c);

  // Plain OpenCV, no romunect: the names ROS and OpenCV samples use.
  cv::FileStorage fs((dir / "calib.yaml").string(), cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  cv::Mat K, dist, T_H_C, a;
  fs["camera_matrix"] >> K;
  fs["distortion_coefficients"] >> dist;
  fs["T_H_C"] >> T_H_C;
  fs["depth_model"]["a"] >> a;
  EXPECT_EQ(K.at<double>(0, 0), c.camera.fx);
  EXPECT_EQ(dist.total(), 5u);
  EXPECT_EQ(T_H_C.at<double>(0, 3), c.T_H_C.translation().x());
  EXPECT_EQ(a.size(), c.depth->a.size());
  EXPECT_EQ(static_cast<std::string>(fs["depth_model"]["kind"]), "inverse_affine_in_raw");
}

TEST(CalibrationFileTest, RoundTripsMapsAsExrBesideTheFile) {
  ScratchDir dir("exr");
  const Calibration c = Sample();
  SaveCalibration(dir / "rig.yaml", c, {.maps_as_exr = true});
  EXPECT_TRUE(fs::exists(dir / "rig_depth_a.exr"));
  EXPECT_EQ(ReadText(dir / "rig.yaml").find("\"a\":"), std::string::npos);
  ExpectSame(LoadCalibration(dir / "rig.yaml"), c);
}

TEST(CalibrationFileTest, RoundTripsWithoutADepthModel) {
  ScratchDir dir("none");
  Calibration c = Sample();
  c.depth = std::nullopt;
  SaveCalibration(dir / "c.yaml", c);
  const Calibration loaded = LoadCalibration(dir / "c.yaml");
  EXPECT_FALSE(loaded.depth.has_value());
  ExpectSame(loaded, c);
}

TEST(CalibrationFileTest, StampsTheDateWhenEmpty) {
  ScratchDir dir("date");
  Calibration c = Sample();
  c.date.clear();
  SaveCalibration(dir / "c.yaml", c);
  EXPECT_TRUE(std::regex_match(LoadCalibration(dir / "c.yaml").date, std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ)")));
}

// Rewrites one line of a saved file, then expects the load to fail naming `field`.
void ExpectLoadFails(const std::string& from_regex, const std::string& to, const std::string& field) {
  ScratchDir dir("bad");
  SaveCalibration(dir / "c.yaml", Sample());
  const std::string text = ReadText(dir / "c.yaml");
  const std::string changed = std::regex_replace(text, std::regex(from_regex), to,
                                                 std::regex_constants::format_first_only);
  ASSERT_NE(changed, text) << from_regex;
  WriteText(dir / "c.yaml", changed);
  try {
    LoadCalibration(dir / "c.yaml");
    FAIL() << "loaded with " << to;
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), field) << e.what();
    EXPECT_NE(std::string(e.what()).find("c.yaml"), std::string::npos) << e.what();
  }
}

TEST(CalibrationFileTest, MissingOrMalformedFieldsNameTheField) {
  ExpectLoadFails("T_H_C:", "T_H_X:", "T_H_C");
  ExpectLoadFails("kind: inverse_affine_in_raw", "kind: quadratic", "depth_model.kind");
  ExpectLoadFails("chip_baseline_m: [^\\n]*", "chip_baseline_m: -0.075", "depth_model.chip_baseline_m");
  ExpectLoadFails("chip_raw_offset: [^\\n]*", "chip_raw_offset: 3000.", "depth_model.chip_raw_offset");
  ExpectLoadFails("depth_rms_m: [^\\n]*", "depth_rms_m: fast", "residuals.depth_rms_m");
  ExpectLoadFails("date: [^\\n]*", "dat: x", "date");
  ExpectLoadFails("format: [^\\n]*", "format: something", "format");
  // A non-rigid T_H_C: scale the first entry.
  ExpectLoadFails("(T_H_C: !!opencv-matrix\\n(?:.*\\n){3}\\s*data: \\[ )", "$01.5, ", "T_H_C");
  // A depth map of the wrong size.
  ExpectLoadFails("(a: !!opencv-matrix\\n\\s*rows: )48", "$0147", "depth_model.a");
  // A version is matched exactly: 1.9 is not 1, and 1e300 has no int (the cast was undefined).
  ExpectLoadFails("version: [^\\n]*", "version: 1.9", "version");
  ExpectLoadFails("version: [^\\n]*", "version: 1.0e+300", "version");
  // A map that claims 100000 rows is refused before OpenCV allocates it.
  ExpectLoadFails("(a: !!opencv-matrix\\n\\s*rows: )48\\n(\\s*cols: )64", "$01100000\n$02100000", "depth_model.a");
  // A pose matrix that claims 2e9 rows: OpenCV allocated 64 GB for them (found by the fuzz target).
  ExpectLoadFails("(T_H_C: !!opencv-matrix\\n\\s*rows: )4", "$012000000000", "T_H_C");
}

// One key of 50,000 nested sequences overflowed the stack inside cv::FileStorage.
TEST(CalibrationFileTest, RefusesDeepNestingBeforeOpenCvParsesIt) {
  ScratchDir dir("deep");
  SaveCalibration(dir / "c.yaml", Sample());
  WriteText(dir / "c.yaml", ReadText(dir / "c.yaml") + "deep: " + std::string(50000, '[') + std::string(50000, ']'));
  try {
    LoadCalibration(dir / "c.yaml");
    FAIL() << "loaded";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("c.yaml"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("nest deeper than 64"), std::string::npos) << e.what();
  }
}

// A device's calibration (record, fuse): a file `calibrate` wrote loads whole; an integrator's
// file of camera and T_H_C alone loads without a depth model or residuals; both are validated.
TEST(CalibrationFileTest, DeviceCalibrationTakesFullFilesAndCameraWithHandEyeAlone) {
  ScratchDir dir("device");
  const Calibration full = Sample();
  SaveCalibration(dir / "full.yml", full);
  ExpectSame(LoadDeviceCalibration(dir / "full.yml"), full);

  auto write_minimal = [&](const std::string& name, const std::string& format, const Pose& T_H_C) {
    cv::FileStorage fs((dir / name).string(), cv::FileStorage::WRITE);
    fs << "format" << format << "version" << kCalibrationVersion;
    full.camera.Write(fs);
    cv::Mat m(4, 4, CV_64F);
    for (int i = 0; i < 16; ++i) m.at<double>(i / 4, i % 4) = T_H_C.matrix()(i / 4, i % 4);
    fs << "T_H_C" << m;
  };
  write_minimal("minimal.yml", kCalibrationFormat, full.T_H_C);
  const Calibration minimal = LoadDeviceCalibration(dir / "minimal.yml");
  EXPECT_EQ(minimal.camera, full.camera);
  EXPECT_TRUE(minimal.T_H_C.isApprox(full.T_H_C, 1e-15));
  EXPECT_FALSE(minimal.depth.has_value());
  EXPECT_EQ(minimal.residuals.hand_eye_rms_px, -1.0);
  EXPECT_THROW(LoadCalibration(dir / "minimal.yml"), InputError);  // not a whole calibration

  write_minimal("other_format.yml", "something", full.T_H_C);
  Pose skewed = full.T_H_C;
  skewed.matrix()(0, 0) *= 1.5;
  write_minimal("skewed.yml", kCalibrationFormat, skewed);
  for (const auto& [name, field] : {std::pair{"other_format.yml", "format"}, std::pair{"skewed.yml", "T_H_C"}}) {
    try {
      LoadDeviceCalibration(dir / name);
      ADD_FAILURE() << name << " loaded";
    } catch (const InputError& e) {
      EXPECT_EQ(e.field(), field) << name << ": " << e.what();
    }
  }

  // The hand-eye warning: an identity T_H_C that no hand-eye step produced.
  write_minimal("identity.yml", kCalibrationFormat, Pose::Identity());
  EXPECT_NE(HandEyeWarning(LoadDeviceCalibration(dir / "identity.yml"), "identity.yml"), "");
  EXPECT_EQ(HandEyeWarning(minimal, "minimal.yml"), "");
  Calibration solved = minimal;
  solved.T_H_C = Pose::Identity();
  solved.residuals.hand_eye_rms_px = 0.2;
  EXPECT_EQ(HandEyeWarning(solved, "solved.yml"), "");
  // A T_H_C written in millimetres is rigid, but no camera on a hand lies 66 m from the flange.
  Calibration millimetres = minimal;
  millimetres.T_H_C.translation() = Eigen::Vector3d(40.0, 0.0, 52.0);
  EXPECT_NE(HandEyeWarning(millimetres, "mm.yml").find("millimetres where metres are expected"), std::string::npos);

  // A file with a depth_model is a whole calibration file, and the error says so.
  WriteText(dir / "half.yml", ReadText(dir / "minimal.yml") + "depth_model:\n  kind: none\n");
  try {
    LoadDeviceCalibration(dir / "half.yml");
    ADD_FAILURE() << "half.yml loaded";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "date") << e.what();
    EXPECT_NE(std::string(e.what()).find("read as a whole calibration file"), std::string::npos) << e.what();
  }
}

// A depth model without one fitted pixel would turn every frame into no depth.
TEST(CalibrationFileTest, RefusesADepthModelThatFitsNoPixel) {
  ScratchDir dir("unfitted");
  Calibration c = Sample();
  c.depth->a.setTo(std::numeric_limits<double>::quiet_NaN());
  SaveCalibration(dir / "c.yml", c);
  try {
    LoadCalibration(dir / "c.yml");
    FAIL() << "loaded";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "depth_model.a") << e.what();
  }
}

TEST(CalibrationFileTest, NeverOverwritesWithAWorseResultWithoutTheFlag) {
  ScratchDir dir("worse");
  const Calibration good = Sample();
  SaveCalibration(dir / "c.yaml", good);
  Calibration worse = Sample();
  worse.residuals.hand_eye_rms_px = 0.5;
  worse.H_P_rec(0, 0) = 2.0;
  try {
    SaveCalibration(dir / "c.yaml", worse);
    FAIL() << "worse result overwrote the file";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("hand_eye_rms_px"), std::string::npos) << e.what();
  }
  EXPECT_EQ(LoadCalibration(dir / "c.yaml").H_P_rec(0, 0), good.H_P_rec(0, 0));
  const SaveReport report = SaveCalibration(dir / "c.yaml", worse, {.overwrite_worse = true});
  EXPECT_TRUE(report.replaced_existing);
  EXPECT_NE(report.worse_than_existing.find("hand_eye_rms_px"), std::string::npos);
  EXPECT_EQ(LoadCalibration(dir / "c.yaml").H_P_rec(0, 0), 2.0);

  // A better one replaces it without the flag and says nothing is worse.
  const SaveReport better = SaveCalibration(dir / "c.yaml", good);
  EXPECT_TRUE(better.worse_than_existing.empty());
}

}  // namespace
}  // namespace romunect::calib
