// `romunect render` end to end, as a user runs it: both presets to frame directories with
// pictures, and bad input that must end with a clear message and a non-zero exit.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "romunect/sensor/frame_io.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

using testing::RunRomunect;
using testing::ScratchDir;
namespace fs = std::filesystem;

// Ground truth comes from float hit distances (the renderer's plane test tolerance).
constexpr double kPlaneDepthTolM = 1e-5;

TEST(CliRenderTest, RendersBothPresetsIntoFrameDirectoriesWithPictures) {
  ScratchDir dir("render");
  for (const std::string rig : {"romunect", "kinect-v1"}) {
    const fs::path out = dir / rig;
    const double distance_m = rig == "romunect" ? 0.2 : 1.0;
    const auto result = RunRomunect("render " + out.string() + " --rig " + rig + " --target plane --distance " +
                                    std::to_string(distance_m));
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_NE(result.output.find("valid depth"), std::string::npos) << result.output;
    const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(out);
    ASSERT_EQ(manifest.frames.size(), 1u);
    const Frame frame = LoadFrame(out, manifest, 0);
    ASSERT_FALSE(frame.ir.empty());
    ASSERT_FALSE(frame.raw.empty());
    ASSERT_FALSE(frame.depth_m.empty());
    ASSERT_FALSE(frame.gt_depth_m.empty());
    double lo, hi;
    cv::minMaxLoc(frame.gt_depth_m, &lo, &hi);
    EXPECT_NEAR(lo, distance_m, kPlaneDepthTolM);
    EXPECT_NEAR(hi, distance_m, kPlaneDepthTolM);
    cv::minMaxLoc(frame.raw, &lo, &hi);
    EXPECT_LE(hi, 2047.0);  // 11-bit raw, 2047 = invalid
    // A textured plane in focus: most pixels get a depth.
    EXPECT_GT(cv::countNonZero(frame.depth_m), frame.depth_m.total() / 2) << rig;
    // The directory's depth is metric on both rigs (the modified one's chip depth is 0.8 m off at
    // 0.2 m): the median error is a fraction of a raw step. Measured 0.001 mm (romunect, through
    // the ground-truth correction) and 0.000 mm (kinect-v1, whose chip depth is metric).
    std::vector<float> errors;
    for (int v = 0; v < frame.depth_m.rows; ++v) {
      for (int u = 0; u < frame.depth_m.cols; ++u) {
        if (frame.depth_m.at<float>(v, u) > 0.0f)
          errors.push_back(std::abs(frame.depth_m.at<float>(v, u) - frame.gt_depth_m.at<float>(v, u)));
      }
    }
    ASSERT_FALSE(errors.empty());
    std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
    constexpr double kMedianErrorM = 1e-3;  // a raw step is ~0.1 mm at 0.2 m (romunect), ~3 mm at 1 m (kinect)
    EXPECT_LT(errors[errors.size() / 2], kMedianErrorM) << rig;
    for (const char* picture : {"ir.png", "depth.png", "gt_depth.png", "error.png"}) {
      EXPECT_TRUE(fs::exists(out / "pictures" / picture)) << picture;
    }
  }
}

// The adaptive quality mode refines the pixels at the step's edge and its shadow, not the flat
// parts: the stats line counts them.
TEST(CliRenderTest, AdaptiveSamplesRefineOnlyEdgePixels) {
  ScratchDir dir("adaptive");
  const fs::path out = dir / "step";
  const auto result = RunRomunect("render " + out.string() + " --target step --samples adaptive");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const size_t at = result.output.find(" refined");
  ASSERT_NE(at, std::string::npos) << result.output;
  const size_t start = result.output.rfind(' ', at - 1) + 1;
  const long refined = std::stol(result.output.substr(start, at - start));
  const long pixels = 640 * 480;
  EXPECT_GT(refined, 0) << result.output;
  EXPECT_LT(refined, pixels / 4) << result.output;  // edges are a small share of a step scene
  EXPECT_TRUE(fs::exists(out / "frames.json"));
}

// Runs `arguments`, expects a non-zero exit and every part of `parts` in the message.
void ExpectFailure(const std::string& arguments, const std::vector<std::string>& parts) {
  const auto result = RunRomunect(arguments);
  EXPECT_NE(result.exit_code, 0) << arguments << "\n" << result.output;
  for (const auto& part : parts) {
    EXPECT_NE(result.output.find(part), std::string::npos) << arguments << "\n" << result.output;
  }
}

TEST(CliRenderTest, BadInputEndsWithAMessageNamingTheFieldAndANonZeroExit) {
  ScratchDir dir("bad");
  const std::string out = (dir / "out").string();
  ExpectFailure("render " + out + " --target donut", {"--target", "donut"});
  ExpectFailure("render " + out + " --samples 3", {"--samples", "must be 1, 4 or adaptive"});
  ExpectFailure("render " + out + " --rig nosuchpreset", {"nosuchpreset"});
  ExpectFailure("render " + out + " --rig " + (dir / "missing.json").string(), {"missing.json"});
  testing::WriteText(dir / "nan.obj", "v 0 0 nan\nv 1 0 0.2\nv 0 1 0.2\nf 1 2 3\n");
  ExpectFailure("render " + out + " --mesh " + (dir / "nan.obj").string(), {"nan.obj", "vertices[0]"});
  testing::WriteText(dir / "empty.stl", "solid empty\nendsolid empty\n");
  ExpectFailure("render " + out + " --mesh " + (dir / "empty.stl").string(), {"empty.stl", "empty"});
  // Distances and sizes: positive, finite, within what float meshes hold (inf crashed the scene).
  for (const char* bad : {"--distance inf", "--distance -0.2", "--distance nan", "--size 1e39", "--size -1"}) {
    ExpectFailure("render " + out + " " + bad,
                  {std::string(bad).substr(0, std::string(bad).find(' ')), "must be in (0, 1000] metres"});
  }
  EXPECT_FALSE(fs::exists(dir / "out"));  // nothing half-written, not even an empty folder
  // An existing frame directory is never overwritten.
  ASSERT_EQ(RunRomunect("render " + out + " --target plane").exit_code, 0);
  ExpectFailure("render " + out + " --target plane", {"frames.json"});
}

}  // namespace
}  // namespace romunect
