// The render and record jobs in-process: a rendered plane as a frame directory, and that
// directory copied by record with its provenance.
#include <filesystem>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/rig.h"
#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/record.h"
#include "romunect/tools/jobs/render.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::ScratchDir;

TEST(RenderJob, WritesOneFrameAndItsPicturesWithDepthErrors) {
  ScratchDir dir("render_job");
  RenderJobOptions o;
  o.out_dir = (dir / "plane").string();
  const RenderSummary s = Render(o);
  EXPECT_EQ(s.rig_name, "romunect");
  EXPECT_EQ(s.what, "plane");
  EXPECT_FALSE(s.stock);  // the modified device: depth made metric by the rig's correction
  EXPECT_GT(s.valid_fraction, 0.5);
  EXPECT_GT(s.metric.pixels, 0u);
  EXPECT_LT(s.metric.rms, 1e-3);
  EXPECT_EQ(ReadFrameDirectoryManifest(dir / "plane").frames.size(), 1u);
  for (const char* picture : {"ir.png", "depth.png", "gt_depth.png", "error.png"}) {
    EXPECT_TRUE(fs::exists(dir / "plane" / "pictures" / picture)) << picture;
  }
  EXPECT_THAT(RenderSummaryText(s), HasSubstr("rig: romunect, camera "));
  // The frame directory refuses to be written twice.
  EXPECT_THROW(Render(o), InputError);
  o.out_dir = (dir / "other").string();
  o.samples = "2";
  EXPECT_THROW(Render(o), InputError);
  EXPECT_FALSE(fs::exists(dir / "other"));
}

TEST(RenderJob, ErrorPictureScaleIsNeverDegenerate) {
  // One raw code at 1 m on the stock chip: 1^2 / (8 x 580 x 0.075) = 2.87 mm.
  const double step_m = 1.0 / (8.0 * 580.0 * 0.075);
  EXPECT_DOUBLE_EQ(ErrorPictureScaleM(0.0, 1.0, 580.0, 0.075), step_m) << "every pixel on its exact code";
  EXPECT_DOUBLE_EQ(ErrorPictureScaleM(0.01, 1.0, 580.0, 0.075), 0.01) << "a real spread wins";
  EXPECT_GT(ErrorPictureScaleM(0.0, 0.0, 580.0, 0.0), 0.0) << "no truth, no baseline: still positive";
  // A frame where most pixels hit the exact code: the stock chip on a camera-facing plane at
  // 1 m, raw exactly 742. The scale is one code, not a saturating 95th percentile, and the
  // report says how it was chosen.
  ScratchDir dir("render_job_scale");
  Rig rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion = DisparityDistortion{};
  SaveRig(dir / "kinect.json", rig);
  RenderJobOptions o;
  o.out_dir = (dir / "plane").string();
  o.rig = (dir / "kinect.json").string();
  o.distance_m = 1.0;
  const RenderSummary s = Render(o);
  EXPECT_NEAR(s.code_step_m, step_m, 0.01 * step_m);  // 1 %: the median true depth is 1 m within 5 mm
  EXPECT_GE(s.error_scale_m, s.code_step_m);
  EXPECT_GE(s.error_scale_m, s.metric.p95);
  EXPECT_THAT(RenderSummaryText(s), HasSubstr("one raw code's depth step at the median true depth"));
}

TEST(RecordJob, CopiesAFrameDirectoryAndSaysWhereItCameFrom) {
  ScratchDir dir("record_job");
  testing::WriteSampleFrameDirectory(dir / "source", testing::SmallCamera(), 4, 2);
  RecordOptions o;
  o.source = (dir / "source").string();
  o.out_dir = (dir / "copy").string();
  o.frames = 3;
  const RecordSummary s = Record(o);
  EXPECT_EQ(s.frames, 3u);
  EXPECT_EQ(s.skipped, 0);
  EXPECT_EQ(s.dropped, "");
  EXPECT_EQ(RecordSummaryText(s, o), "recorded 3 frames (0 skipped) to " + o.out_dir + "\n");
  const nlohmann::json manifest = nlohmann::json::parse(testing::ReadText(dir / "copy" / "frames.json"));
  EXPECT_EQ(manifest["recording"]["source"], o.source);
  EXPECT_EQ(manifest["recording"]["depth_from"], "the source directory's depth");
  // A frame directory is copied as it is: stream options are refused before anything is written.
  o.out_dir = (dir / "copy2").string();
  o.raw = true;
  try {
    Record(o);
    FAIL() << "--raw on a frame directory";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "--raw");
  }
  EXPECT_FALSE(fs::exists(dir / "copy2"));
}

}  // namespace
}  // namespace romunect::jobs
