#include "romunect/sim/frame_pipeline.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect::sim {
namespace {

// A source whose frames depend only on their index (a seeded pattern), with a bad frame and,
// optionally, a throw at given indices; it sleeps a little per frame so the pipeline runs ahead.
class CountingSource : public FrameSource {
 public:
  CountingSource(int count, int bad_at, int throw_at) : count_(count), bad_at_(bad_at), throw_at_(throw_at) {
    camera_.width = 16;
    camera_.height = 12;
    camera_.fx = camera_.fy = 20;
    camera_.cx = 7.5;
    camera_.cy = 5.5;
  }
  const CameraModel& camera() const override { return camera_; }
  std::string Describe() const override { return "counting source"; }
  FrameStatus Next(Frame* frame, std::string* error) override {
    on_thread_ = std::this_thread::get_id();
    if (next_ >= count_) return FrameStatus::kEndOfStream;
    const int i = next_++;
    std::this_thread::sleep_for(std::chrono::microseconds(200));
    if (i == throw_at_) throw InputError("counting source", "frame " + std::to_string(i), "gone");
    if (i == bad_at_) {
      *error = "frame " + std::to_string(i) + " is bad";
      return FrameStatus::kBadFrame;
    }
    *frame = MakeFrame(camera_, i);
    return FrameStatus::kOk;
  }
  static Frame MakeFrame(const CameraModel& camera, int i) {
    Frame frame;
    frame.index = i;
    frame.time_s = i / 30.0;
    frame.depth_m.create(camera.height, camera.width, CV_32F);
    for (int v = 0; v < camera.height; ++v) {
      for (int u = 0; u < camera.width; ++u) frame.depth_m.at<float>(v, u) = 0.2f + 1e-3f * i + 1e-5f * (v * 16 + u);
    }
    return frame;
  }
  std::thread::id on_thread() const { return on_thread_; }

 private:
  CameraModel camera_;
  int count_, bad_at_, throw_at_;
  int next_ = 0;
  std::thread::id on_thread_;
};

TEST(FramePipelineTest, PrefetchingDeliversTheSourcesFramesInOrderOnAnotherThread) {
  CountingSource reference(20, 7, -1), piped(20, 7, -1);
  PrefetchingSource source(&piped, 3);
  EXPECT_EQ(source.camera().width, 16);
  EXPECT_EQ(source.Describe(), "counting source");
  int ok = 0, bad = 0;
  for (;;) {
    Frame expected, got;
    std::string expected_error, got_error;
    const FrameStatus want = reference.Next(&expected, &expected_error);
    const FrameStatus status = source.Next(&got, &got_error);
    ASSERT_EQ(status, want);
    if (status == FrameStatus::kEndOfStream) break;
    if (status == FrameStatus::kBadFrame) {
      EXPECT_EQ(got_error, expected_error);
      ++bad;
      continue;
    }
    EXPECT_EQ(got.index, expected.index);
    EXPECT_TRUE(testing::ImagesBitEqual(got.depth_m, expected.depth_m));
    ++ok;
  }
  EXPECT_EQ(ok, 19);
  EXPECT_EQ(bad, 1);
  EXPECT_NE(piped.on_thread(), std::this_thread::get_id());
  Frame frame;
  std::string error;
  EXPECT_EQ(source.Next(&frame, &error), FrameStatus::kEndOfStream);  // and stays there
}

// Same bytes: the frames of a pipelined run equal those of a plain run, image for image.
TEST(FramePipelineTest, PipelinedFramesAreBitEqualToUnpipelinedOnes) {
  auto run = [](bool pipelined) {
    CountingSource counting(12, -1, -1);
    std::vector<Frame> frames;
    Frame frame;
    std::string error;
    if (pipelined) {
      PrefetchingSource source(&counting, 2);
      while (source.Next(&frame, &error) == FrameStatus::kOk) frames.push_back(frame);
    } else {
      while (counting.Next(&frame, &error) == FrameStatus::kOk) frames.push_back(frame);
    }
    return frames;
  };
  const std::vector<Frame> a = run(false), b = run(true);
  ASSERT_EQ(a.size(), 12u);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].index, b[i].index);
    EXPECT_TRUE(testing::ImagesBitEqual(a[i].depth_m, b[i].depth_m)) << "frame " << i;
    // Delivered frames own their images: no two frames share a buffer.
    if (i > 0) {
      EXPECT_NE(b[i].depth_m.data, b[i - 1].depth_m.data);
    }
  }
}

TEST(FramePipelineTest, PrefetchingRethrowsWhatTheSourceThrewAndEnds) {
  CountingSource counting(10, -1, 4);
  PrefetchingSource source(&counting, 2);
  Frame frame;
  std::string error;
  for (int i = 0; i < 4; ++i) ASSERT_EQ(source.Next(&frame, &error), FrameStatus::kOk);
  EXPECT_THROW(source.Next(&frame, &error), InputError);
  EXPECT_EQ(source.Next(&frame, &error), FrameStatus::kEndOfStream);
}

TEST(FramePipelineTest, DestroyingAPrefetcherMidStreamStopsItsThread) {
  CountingSource counting(1000, -1, -1);
  {
    PrefetchingSource source(&counting, 2);
    Frame frame;
    std::string error;
    ASSERT_EQ(source.Next(&frame, &error), FrameStatus::kOk);
  }
  // At most the frame delivered, the ones queued (2) and the one in production were made.
  Frame frame;
  std::string error;
  ASSERT_EQ(counting.Next(&frame, &error), FrameStatus::kOk);
  EXPECT_LE(frame.index, 4);
}

TEST(FramePipelineTest, WorkerRunsTheJobInOrderAndRethrowsItsFailure) {
  std::vector<int> seen;
  FrameWorker worker([&seen](const Frame& f) { seen.push_back(f.index); }, 2);
  Frame frame;
  for (int i = 0; i < 30; ++i) {
    frame.index = i;
    worker.Push(frame);
  }
  worker.Finish();
  ASSERT_EQ(seen.size(), 30u);
  for (int i = 0; i < 30; ++i) EXPECT_EQ(seen[i], i);
  EXPECT_GE(worker.busy_s(), 0.0);

  std::atomic<int> runs{0};
  FrameWorker failing(
      [&runs](const Frame& f) {
        ++runs;
        if (f.index == 3) throw std::runtime_error("disk full");
      },
      1);
  bool thrown = false;
  try {
    for (int i = 0; i < 10; ++i) {
      frame.index = i;
      failing.Push(frame);
    }
    failing.Finish();
  } catch (const std::runtime_error& e) {
    thrown = true;
    EXPECT_STREQ(e.what(), "disk full");
  }
  EXPECT_TRUE(thrown);
  failing.Finish();        // drained; the failure was reported once
  EXPECT_EQ(runs.load(), 4);  // frames after the failure are dropped
}

// A worker started with a nice value runs its job at that lower priority (the caller's own
// priority is untouched).
TEST(FramePipelineTest, WorkerRunsItsJobAtTheLowerPriorityAskedFor) {
  const int caller = getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)));
  std::atomic<int> job_nice{-100};
  FrameWorker worker([&](const Frame&) { job_nice = getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid))); },
                     1, 10);
  worker.Push(Frame{});
  worker.Finish();
  EXPECT_EQ(job_nice.load(), std::min(19, caller + 10));
  EXPECT_EQ(getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid))), caller);
}

}  // namespace
}  // namespace romunect::sim
