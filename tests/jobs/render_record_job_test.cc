// The render and record jobs in-process: a rendered plane as a frame directory, and that
// directory copied by record with its provenance.
#include <filesystem>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
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
