#include "romunect/sensor/rig.h"

#include <cmath>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

using romunect::testing::ReadText;
using romunect::testing::ScratchDir;
using romunect::testing::WriteText;

// The paper's numbers are round ("about 6 x 4 cm", "about 5 cm", "15 deg"): 10 % is "about".
constexpr double kAboutFraction = 0.10;

TEST(RigPresetTest, RomunectMatchesThePaper) {
  const Rig rig = RigPreset("romunect");
  EXPECT_EQ(rig.Problem(), "");
  EXPECT_EQ(rig.camera.width, 640);
  EXPECT_EQ(rig.camera.height, 480);
  EXPECT_DOUBLE_EQ(rig.frame_rate_hz, 30.0);
  const double width_m = rig.camera.width / rig.camera.fx * 0.2;
  EXPECT_NEAR(width_m, 0.06, 0.06 * kAboutFraction);
  const double baseline_m = rig.T_C_P.translation().norm();
  EXPECT_NEAR(baseline_m, 0.05, 0.05 * kAboutFraction);
  // Stereo angle at 20 cm: between the rays from both centres to the camera axis at 0.2 m.
  const Eigen::Vector3d p_C(0, 0, 0.2);
  const Eigen::Vector3d to_projector = (rig.T_C_P.translation() - p_C).normalized();
  const double angle_deg = std::acos(to_projector.dot(-p_C.normalized())) * 180 / M_PI;
  EXPECT_NEAR(angle_deg, 15.0, 15.0 * kAboutFraction);
  // The projector's axis meets the camera's near 200 mm: its centre pixel sees (0, 0, 0.2).
  const auto x_P = rig.projector.Project(rig.T_C_P.inverse() * p_C);
  ASSERT_TRUE(x_P);
  EXPECT_NEAR(x_P->x(), rig.projector.cx, 2.0);
  // Quantization step at 200 mm: Z^2 / (8 f b) = 0.047 mm (issue F1).
  EXPECT_NEAR(0.2 * 0.2 / (8 * rig.camera.fx * baseline_m), 0.047e-3, 0.047e-3 * 0.05);
  // Focused range about 2 cm: projector blur stays below ~3 px within +-1 cm only.
  EXPECT_LT(rig.projector.CircleOfConfusionPx(0.206), 0.1);
  EXPECT_GT(rig.projector.CircleOfConfusionPx(0.206 - 0.02), 5.0);
}

TEST(RigPresetTest, KinectV1IsTheStockDevice) {
  const Rig rig = RigPreset("kinect-v1");
  EXPECT_EQ(rig.Problem(), "");
  EXPECT_DOUBLE_EQ(rig.camera.fx, 580.0);
  EXPECT_DOUBLE_EQ(rig.T_C_P.translation().x(), 0.075);
  // The stock device is the chip's own geometry, so its reported depth is right.
  EXPECT_EQ(rig.camera, rig.depth_engine.chip.camera);
  EXPECT_DOUBLE_EQ(rig.depth_engine.chip.baseline_m, 0.075);
  EXPECT_TRUE(rig.H_P_rec.isIdentity());
  // In focus from 0.5 m on: under 1.5 projector pixels of blur out to 8 m.
  for (double z : {0.5, 1.0, 3.0, 8.0}) EXPECT_LT(rig.projector.CircleOfConfusionPx(z), 1.5) << z;
  EXPECT_THROW(RigPreset("kinect-v3"), InputError);
}

TEST(RigTest, IdealPrewarpPutsThePatternWhereTheReferenceHasIt) {
  const Rig rig = RigPreset("romunect");
  const ChipGeometry& chip = rig.depth_engine.chip;
  const double z_m = 0.2;
  const Eigen::Matrix3d H_rec_P = rig.H_P_rec.inverse();
  // Reprojection through exact geometry must agree to numerical precision.
  constexpr double kTolerancePx = 1e-6;
  for (double u : {10.0, 319.5, 600.0}) {
    for (double v : {5.0, 239.5, 470.0}) {
      // Camera pixel -> plane point -> projector pixel -> pattern pixel.
      const Eigen::Vector3d p_C = rig.camera.Unproject({u, v}, z_m);
      const Eigen::Vector2d x_P = *rig.projector.Project(rig.T_C_P.inverse() * p_C);
      const Eigen::Vector3d x_pat = H_rec_P * x_P.homogeneous();
      const Eigen::Vector2d pattern_px = x_pat.hnormalized();
      // The stock camera sees that pattern pixel, on its reference plane, at the same pixel.
      const double u_ref = chip.camera.fx / chip.projector.fx * (pattern_px.x() - chip.projector.cx) + chip.camera.cx +
                           chip.FocalTimesBaseline() / chip.reference_distance_m;
      const double v_ref = chip.camera.fy / chip.projector.fy * (pattern_px.y() - chip.projector.cy) + chip.camera.cy;
      EXPECT_NEAR(u_ref, u, kTolerancePx);
      EXPECT_NEAR(v_ref, v, kTolerancePx);
    }
  }
}

TEST(RigFileTest, SaveLoadRoundTripsBothPresets) {
  ScratchDir dir("rig_round_trip");
  for (const char* name : {"romunect", "kinect-v1"}) {
    const Rig rig = RigPreset(name);
    SaveRig(dir / "rig.json", rig);
    const Rig loaded = LoadRig(dir / "rig.json");
    EXPECT_EQ(loaded.name, rig.name);
    EXPECT_EQ(loaded.camera, rig.camera);
    EXPECT_EQ(loaded.optics, rig.optics);
    EXPECT_EQ(loaded.projector, rig.projector);
    EXPECT_EQ(loaded.pattern, rig.pattern);
    EXPECT_EQ(loaded.depth_engine, rig.depth_engine);
    EXPECT_TRUE(loaded.T_C_P.matrix() == rig.T_C_P.matrix());
    EXPECT_TRUE(loaded.H_P_rec == rig.H_P_rec);
    SaveRig(dir / "again.json", loaded);
    EXPECT_EQ(ReadText(dir / "again.json"), ReadText(dir / "rig.json"));
  }
}

// Edits one field of a saved preset and expects LoadRig to name the file and that field.
void ExpectBadField(const std::string& json_pointer, const nlohmann::json& value, const std::string& expected_field) {
  ScratchDir dir("rig_bad_field");
  SaveRig(dir / "rig.json", RigPreset("romunect"));
  nlohmann::json doc = nlohmann::json::parse(ReadText(dir / "rig.json"));
  if (value.is_null()) {
    const nlohmann::json::json_pointer ptr(json_pointer);
    doc[ptr.parent_pointer()].erase(ptr.back());
  } else {
    doc[nlohmann::json::json_pointer(json_pointer)] = value;
  }
  WriteText(dir / "bad.json", doc.dump());
  try {
    LoadRig(dir / "bad.json");
    ADD_FAILURE() << json_pointer << ": no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), (dir / "bad.json").string()) << e.what();
    EXPECT_EQ(e.field(), expected_field) << e.what();
  }
}

TEST(RigFileTest, BadFieldsAreNamed) {
  ExpectBadField("/camera/fx", -500.0, "camera.fx");
  ExpectBadField("/projector/fy", -1.0, "projector.fy");
  ExpectBadField("/projector/aperture_m", nullptr, "projector.aperture_m");
  ExpectBadField("/pattern/width", 100, "pattern.width");  // Kinect tiles need multiples of 3
  ExpectBadField("/pattern/kind", "stripes", "pattern.kind");
  ExpectBadField("/optics/bits", 0, "optics.bits");
  ExpectBadField("/depth_engine/window_px", 8, "depth_engine.window_px");
  ExpectBadField("/optics/speckle_contrast", 1.5, "optics.speckle_contrast");
  ExpectBadField("/depth_engine/subpixel_equiangular_weight", 1.2, "depth_engine.subpixel_equiangular_weight");
  ExpectBadField("/depth_engine/subpixel_rounding_slope", -0.1, "depth_engine.subpixel_rounding_slope");
  ExpectBadField("/depth_engine/subpixel_rounding_slope", "0.3", "depth_engine.subpixel_rounding_slope");  // optional, but a number when present
  ExpectBadField("/depth_engine/subpixel_quarter_correction", -0.6, "depth_engine.subpixel_quarter_correction");
  ExpectBadField("/depth_engine/subpixel_quarter_correction", "0.1", "depth_engine.subpixel_quarter_correction");  // optional, but a number when present
  ExpectBadField("/depth_engine/subpixel_eighth_correction", 0.7, "depth_engine.subpixel_eighth_correction");
  ExpectBadField("/depth_engine/subpixel_eighth_correction", "0.1", "depth_engine.subpixel_eighth_correction");  // optional, but a number when present
  ExpectBadField("/depth_engine/chip/pattern/width", 795, "depth_engine.chip.pattern.width");
  ExpectBadField("/H_P_rec", nlohmann::json::array({1, 0, 0, 0, 1, 0, 0, 0}), "H_P_rec");
  ExpectBadField("/T_C_P", nlohmann::json::array({1, 0, 0, 0.05, 0, 1, 0, 0, 0, 0, 1, -0.3, 0, 0, 0, 1}),
                 "T_C_P");  // projector 30 cm behind the camera
  ExpectBadField("/T_C_P", nlohmann::json::array({1, 0, 0, 0.05, 0, 2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}),
                 "T_C_P");  // not a rotation
  // Values no rig has: they passed, and a 100,000 px projector failed later inside OpenCV.
  ExpectBadField("/projector/width", 100000, "projector.width");
  ExpectBadField("/projector/fx", 1e308, "projector.fx");
  ExpectBadField("/camera/fx", 1e308, "camera");
  ExpectBadField("/camera/distortion", nlohmann::json::array({1e10, 0, 0, 0, 0}), "camera");
  ExpectBadField("/T_C_P", nlohmann::json::array({1, 0, 0, 50, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}),
                 "T_C_P");  // a 50 m baseline
}

TEST(RigFileTest, DeepNestingIsRefusedBeforeParsing) {
  ScratchDir dir("rig_deep");
  WriteText(dir / "deep.json", "{\"x\": " + std::string(80000, '[') + std::string(80000, ']') + "}");
  try {
    LoadRig(dir / "deep.json");
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("deeper than 64"), std::string::npos) << e.what();
  }
}

// Check() names the field at fault as structure (the key path a rig file uses); Problem() is
// the same finding as prose.
TEST(RigTest, CheckNamesTheFieldAndTheRule) {
  Rig rig = RigPreset("romunect");
  EXPECT_FALSE(rig.Check());
  EXPECT_EQ(rig.Problem(), "");
  rig.optics.exposure_s = 0.0;
  EXPECT_EQ(rig.Check().field, "optics.exposure_s");
  EXPECT_EQ(rig.Check().rule, "must be in (0, 1] s, found 0");
  EXPECT_EQ(rig.Problem(), "optics.exposure_s: must be in (0, 1] s, found 0");
  rig = RigPreset("romunect");
  rig.depth_engine.chip.camera.fx = -1.0;
  EXPECT_EQ(rig.Check().field, "depth_engine.chip.camera");
  EXPECT_EQ(rig.Problem(), "depth_engine.chip.camera: " + rig.depth_engine.chip.camera.Problem());
}

TEST(RigFileTest, MissingAndMalformedFilesAreNamed) {
  ScratchDir dir("rig_bad_file");
  EXPECT_THROW(LoadRig(dir / "none.json"), InputError);
  WriteText(dir / "cut.json", "{\"name\": \"x\", ");
  EXPECT_THROW(LoadRig(dir / "cut.json"), InputError);
}

}  // namespace
}  // namespace romunect

namespace romunect {
namespace {

TEST(RigFileTest, ShippedRigFilesAreThePresets) {
  for (const char* name : {"romunect", "kinect-v1"}) {
    const std::filesystem::path path = std::filesystem::path(ROMUNECT_SOURCE_DIR) / "scenes" / "rigs" /
                                       (std::string(name) + ".json");
    const Rig file = LoadRig(path);
    const Rig preset = RigPreset(name);
    EXPECT_EQ(file.camera, preset.camera) << name;
    EXPECT_EQ(file.optics, preset.optics) << name;
    EXPECT_EQ(file.projector, preset.projector) << name;
    EXPECT_EQ(file.pattern, preset.pattern) << name;
    EXPECT_EQ(file.depth_engine, preset.depth_engine) << name;
    EXPECT_TRUE(file.T_C_P.matrix() == preset.T_C_P.matrix()) << name;
    EXPECT_TRUE(file.H_P_rec == preset.H_P_rec) << name;
  }
}

}  // namespace
}  // namespace romunect
