// LoopingSource: a finite source replayed as an endless stream whose times and indices go on.
#include "romunect/sensor/looping_source.h"

#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

// One entry of a scripted pass: a good frame at (index, time_s), or a bad one.
struct Step {
  FrameStatus status = FrameStatus::kOk;
  int index = 0;
  double time_s = 0.0;
};

// A source that plays a fixed script once.
class ScriptedSource : public FrameSource {
 public:
  ScriptedSource(std::vector<Step> script, const CameraModel& camera) : script_(std::move(script)), camera_(camera) {}
  const CameraModel& camera() const override { return camera_; }
  std::string Describe() const override { return "script of " + std::to_string(script_.size()); }
  FrameStatus Next(Frame* frame, std::string* error) override {
    if (next_ >= script_.size()) return FrameStatus::kEndOfStream;
    const Step& s = script_[next_++];
    if (s.status == FrameStatus::kBadFrame) {
      *error = "scripted bad frame";
      return s.status;
    }
    *frame = Frame();
    frame->index = s.index;
    frame->time_s = s.time_s;
    return FrameStatus::kOk;
  }

 private:
  std::vector<Step> script_;
  CameraModel camera_;
  size_t next_ = 0;
};

LoopingSource::Opener Scripted(std::vector<Step> script, int* opened = nullptr) {
  return [script, opened] {
    if (opened != nullptr) ++*opened;
    return std::make_unique<ScriptedSource>(script, testing::SmallCamera());
  };
}

TEST(LoopingSource, TimesAndIndicesGoOnAcrossPasses) {
  int opened = 0;
  // A capture whose clock does not start at 0, as a recorded one.
  LoopingSource source(
      Scripted({{FrameStatus::kOk, 4, 10.0}, {FrameStatus::kOk, 5, 10.1}, {FrameStatus::kOk, 6, 10.2}}, &opened), 0.1);
  EXPECT_EQ(opened, 1);
  EXPECT_EQ(source.camera(), testing::SmallCamera());
  EXPECT_NE(source.Describe().find("looped"), std::string::npos);
  Frame f;
  std::string error;
  for (int k = 0; k < 9; ++k) {
    ASSERT_EQ(source.Next(&f, &error), FrameStatus::kOk) << error;
    EXPECT_EQ(f.index, 4 + k);
    EXPECT_NEAR(f.time_s, 10.0 + 0.1 * k, 1e-9) << "frame " << k;
  }
  EXPECT_EQ(source.passes(), 3);
  EXPECT_EQ(opened, 3);
}

TEST(LoopingSource, BadFramesPassThroughAndLoopingGoesOn) {
  LoopingSource source(Scripted({{FrameStatus::kBadFrame}, {FrameStatus::kOk, 1, 0.5}, {FrameStatus::kOk, 2, 1.0}}),
                       0.25);
  Frame f;
  std::string error;
  std::vector<FrameStatus> statuses;
  std::vector<double> times;
  for (int k = 0; k < 6; ++k) {
    statuses.push_back(source.Next(&f, &error));
    if (statuses.back() == FrameStatus::kOk) {
      times.push_back(f.time_s);
    } else {
      EXPECT_EQ(error, "scripted bad frame");
    }
  }
  EXPECT_EQ(statuses, (std::vector<FrameStatus>{FrameStatus::kBadFrame, FrameStatus::kOk, FrameStatus::kOk,
                                                FrameStatus::kBadFrame, FrameStatus::kOk, FrameStatus::kOk}));
  // The second pass's first good frame follows the first pass's last by the gap.
  ASSERT_EQ(times.size(), 4u);
  EXPECT_DOUBLE_EQ(times[0], 0.5);
  EXPECT_DOUBLE_EQ(times[1], 1.0);
  EXPECT_DOUBLE_EQ(times[2], 1.25);
  EXPECT_DOUBLE_EQ(times[3], 1.75);
}

TEST(LoopingSource, AnEmptyPassEndsTheStream) {
  LoopingSource empty(Scripted({}), 0.1);
  Frame f;
  std::string error;
  EXPECT_EQ(empty.Next(&f, &error), FrameStatus::kEndOfStream);

  // A source that is gone on its second opening: the first pass plays, then the stream ends.
  int opened = 0;
  LoopingSource once(
      [&opened]() -> std::unique_ptr<FrameSource> {
        std::vector<Step> script;
        if (opened++ == 0) script = {{FrameStatus::kOk, 0, 0.0}, {FrameStatus::kOk, 1, 0.1}};
        return std::make_unique<ScriptedSource>(script, testing::SmallCamera());
      },
      0.1);
  EXPECT_EQ(once.Next(&f, &error), FrameStatus::kOk);
  EXPECT_EQ(once.Next(&f, &error), FrameStatus::kOk);
  EXPECT_EQ(once.Next(&f, &error), FrameStatus::kEndOfStream);
  EXPECT_EQ(once.Next(&f, &error), FrameStatus::kEndOfStream);  // and stays ended,
  EXPECT_EQ(opened, 2);                                         // without opening it again
}

TEST(LoopingSource, APassWithAnotherCameraIsAnInputError) {
  int opened = 0;
  LoopingSource source(
      [&opened] {
        CameraModel camera = testing::SmallCamera();
        if (opened++ > 0) camera.width *= 2;
        return std::make_unique<ScriptedSource>(std::vector<Step>{{FrameStatus::kOk, 0, 0.0}}, camera);
      },
      0.1);
  Frame f;
  std::string error;
  ASSERT_EQ(source.Next(&f, &error), FrameStatus::kOk);
  try {
    source.Next(&f, &error);
    FAIL() << "a changed camera must throw";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("changed between passes"), std::string::npos) << e.what();
  }
}

TEST(LoopingSource, ReplaysAFrameDirectoryWithItsImages) {
  testing::ScratchDir dir("frames");
  constexpr int kFrames = 3;
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 5);
  FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir.path());
  for (FrameRecord& r : manifest.frames) r.gt_depth.clear();  // left out: never loaded
  const double period_s = manifest.frames[1].time_s - manifest.frames[0].time_s;
  const double span_s = manifest.frames.back().time_s - manifest.frames.front().time_s;
  LoopingSource source([&] { return std::make_unique<FrameDirectorySource>(dir.path(), manifest); }, period_s);
  Frame f;
  std::string error;
  for (int k = 0; k < 2 * kFrames + 1; ++k) {
    ASSERT_EQ(source.Next(&f, &error), FrameStatus::kOk) << error;
    const int i = k % kFrames;
    const Frame expected = LoadFrame(dir.path(), manifest, i);
    SCOPED_TRACE("frame " + std::to_string(k));
    EXPECT_TRUE(testing::ImagesBitEqual(f.depth_m, expected.depth_m));
    EXPECT_TRUE(testing::ImagesBitEqual(f.ir, expected.ir));
    EXPECT_TRUE(f.gt_depth_m.empty());
    EXPECT_EQ(f.index, manifest.frames[0].index + k);
    EXPECT_NEAR(f.time_s, manifest.frames[i].time_s + (k / kFrames) * (span_s + period_s), 1e-9);
  }
}

}  // namespace
}  // namespace romunect
