#include "romunect/sim/scanner.h"

#include <atomic>
#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect::sim {
namespace {

// Float hit points of a ray tracer at 0.2-0.4 m: a few micrometres of round-off.
constexpr double kDepthToleranceM = 2e-5;
// Poses handed out are the world's executed ones, copied: exact.
constexpr double kExact = 1e-12;

// The romunect rig at a quarter of its resolution (same field of view), for fast tests.
void Quarter(CameraModel* c) {
  c->width /= 4;
  c->height /= 4;
  c->fx /= 4;
  c->fy /= 4;
  c->cx = (c->cx + 0.5) / 4 - 0.5;
  c->cy = (c->cy + 0.5) / 4 - 0.5;
}
Rig SmallRig() {
  Rig rig = RigPreset("romunect");
  Quarter(&rig.camera);
  Quarter(&rig.depth_engine.chip.camera);
  return rig;
}

ScanOptions SmallScan() {
  ScanOptions options;
  options.rig = SmallRig();
  options.pile.num_objects = 4;
  options.pile.seed = 2;
  return options;
}

// Slow, obvious reference: the nearest hit of a ray over every triangle of every visible geom
// (Moller-Trumbore in double), NaN when nothing is hit.
double BruteForceDistance(const World& world, const Eigen::Vector3d& o_W, const Eigen::Vector3d& d_W,
                          bool with_arm = true) {
  std::vector<Pose> T_W_G;
  world.GeomPoses(&T_W_G);
  double best = std::numeric_limits<double>::infinity();
  for (size_t g = 0; g < world.Geoms().size(); ++g) {
    if (world.Geoms()[g].arm && !with_arm) continue;
    const Mesh& mesh = world.Geoms()[g].mesh_G;
    for (const auto& t : mesh.triangles) {
      const Eigen::Vector3d a = T_W_G[g] * mesh.vertices[t[0]], b = T_W_G[g] * mesh.vertices[t[1]],
                            c = T_W_G[g] * mesh.vertices[t[2]];
      const Eigen::Vector3d e1 = b - a, e2 = c - a, p = d_W.cross(e2);
      const double det = e1.dot(p);
      if (std::abs(det) < 1e-18) continue;
      const Eigen::Vector3d s = o_W - a;
      const double u = s.dot(p) / det;
      if (u < 0 || u > 1) continue;
      const Eigen::Vector3d q = s.cross(e1);
      const double v = d_W.dot(q) / det;
      if (v < 0 || u + v > 1) continue;
      const double dist = e2.dot(q) / det;
      if (dist > 1e-9 && dist < best) best = dist;
    }
  }
  return std::isfinite(best) ? best : std::numeric_limits<double>::quiet_NaN();
}

TEST(ScannerTest, FramesMatchBruteForceRayCastingAndTheExecutedPoses) {
  Scanner scanner(SmallScan());
  ASSERT_GT(scanner.frame_count(), 5);  // the descent's frames: the rest is planned once they are measured
  const CameraModel& camera = scanner.camera();
  Frame frame;
  std::string error;
  int frames = 0;
  while (scanner.Next(&frame, &error) == FrameStatus::kOk) {
    ASSERT_TRUE(frame.T_W_C && frame.T_B_H);
    EXPECT_EQ(frame.index, frames);
    EXPECT_NEAR(frame.time_s, frames / 30.0, 1e-12);
    EXPECT_TRUE(testing::PosesNear(*frame.T_W_C, scanner.world().T_W_C(), kExact, kExact));
    EXPECT_TRUE(testing::PosesNear(*frame.T_B_H, scanner.world().T_B_H(), kExact, kExact));
    ASSERT_EQ(frame.gt_depth_m.size(), cv::Size(camera.width, camera.height));
    // Every 8th frame, 40 pixels against the slow reference.
    if (frames % 8 == 0) {
      for (int k = 0; k < 40; ++k) {
        const int u = (k * 37) % camera.width, v = (k * 53 + frames) % camera.height;
        const Eigen::Vector3d ray_C = camera.Ray(Eigen::Vector2d(u, v));
        const Eigen::Vector3d d_W = frame.T_W_C->rotation() * ray_C.normalized();
        const double dist = BruteForceDistance(scanner.world(), frame.T_W_C->translation(), d_W);
        const double expected = std::isnan(dist) ? 0.0 : dist / ray_C.norm();
        EXPECT_NEAR(frame.gt_depth_m.at<float>(v, u), expected, kDepthToleranceM)
            << "frame " << frames << " px " << u << "," << v;
      }
    }
    // Without an imager the sensor is ideal.
    EXPECT_TRUE(testing::ImagesBitEqual(frame.depth_m, frame.gt_depth_m));
    ++frames;
  }
  EXPECT_EQ(frames, scanner.frame_count());
  EXPECT_EQ(scanner.stats().frames, frames);
  // The last frame is at the lowest stand-off level, looking down at the bin (z in C is -z in
  // W); the levels come from the rig's focused range, around its 200 mm working distance.
  const Eigen::Vector3d p_Bin = scanner.world().T_W_Bin().inverse() * frame.T_W_C->translation();
  EXPECT_NEAR(p_Bin.z(), scanner.plan().levels_m.back(), 5e-3);  // within the servo's tracking error
  // The lowest level holds the table (5 mm below the floor) in the rig's measurable range.
  const DepthRange range = MeasurableDepthRange(scanner.options().rig);
  EXPECT_LE(scanner.plan().levels_m.back() + 0.005, range.far_m);
  EXPECT_GE(scanner.plan().levels_m.back(), range.near_m);
  std::cout << scanner.stats().BriefReport() << "\n";
}

// The scanner's stages on a pipeline deliver Next()'s frames, in order, bit for bit; a pipeline
// destroyed mid-approach stops the scanner after the frame in hand.
TEST(ScannerTest, ItsStagesOnAPipelineDeliverTheSameFramesAsNext) {
  std::vector<Frame> in_line, piped;
  {
    Scanner scanner(SmallScan());
    Frame frame;
    std::string error;
    while (scanner.Next(&frame, &error) == FrameStatus::kOk) in_line.push_back(frame);
  }
  Scanner scanner(SmallScan());
  FramePipeline<ScanWork> pipeline;
  AddScanStages(&scanner, &pipeline, 2);
  pipeline.AddStage({"collect"}, [&piped](ScanWork* work) {
    EXPECT_EQ(work->geometry, nullptr);  // given back to the scanner after imaging
    piped.push_back(std::move(work->frame));
  });
  pipeline.Run();
  ASSERT_EQ(piped.size(), in_line.size());
  EXPECT_EQ(scanner.stats().frames, static_cast<int>(piped.size()));
  const std::vector<PipelineStageTiming> timings = pipeline.timings();
  ASSERT_EQ(timings.size(), 4u);
  EXPECT_EQ(timings[0].name, "render");
  EXPECT_EQ(timings[0].items, static_cast<int>(piped.size()));
  for (size_t i = 0; i < piped.size(); ++i) {
    EXPECT_EQ(piped[i].index, in_line[i].index);
    EXPECT_TRUE(piped[i].T_W_C->matrix() == in_line[i].T_W_C->matrix()) << "frame " << i;
    EXPECT_TRUE(testing::ImagesBitEqual(piped[i].gt_depth_m, in_line[i].gt_depth_m)) << "frame " << i;
    EXPECT_TRUE(testing::ImagesBitEqual(piped[i].depth_m, in_line[i].depth_m)) << "frame " << i;
  }

  Scanner stopped(SmallScan());
  std::atomic<int> collected{0};
  {
    FramePipeline<ScanWork> early;
    AddScanStages(&stopped, &early);
    early.AddStage({"collect"}, [&collected](ScanWork*) { ++collected; });
    early.Start();
    while (collected.load() < 2) std::this_thread::yield();
  }
  EXPECT_LT(stopped.stats().frames, stopped.frame_count());
}

TEST(ScannerTest, GroundTruthHeightMapShowsBinFloorRimAndObjects) {
  ScanOptions options = SmallScan();
  Scanner scanner(options);
  const Pose T_W_Bin = scanner.world().T_W_Bin();
  HeightMapGeometry layout;
  layout.voxel_m = 1e-3;
  layout.nx = 150;
  layout.ny = 80;
  layout.min_x_m = T_W_Bin.translation().x() - 0.075;
  layout.min_y_m = T_W_Bin.translation().y() - 0.04;
  const cv::Mat h = GroundTruthHeightMap(scanner.world(), layout);
  ASSERT_EQ(h.size(), cv::Size(150, 80));
  // Compare with vertical brute-force rays at a sample of cells; the 30 m "orthographic"
  // camera leans rays by up to 0.075/30 rad, so a vertical face may shift by 0.1 mm: sample
  // and allow for it on steep cells by taking the nearer of the two neighbours.
  int checked = 0;
  for (int j = 3; j < 80; j += 11) {
    for (int i = 2; i < 150; i += 13) {
      const Eigen::Vector3d o(layout.CellCentreX_m(i), layout.CellCentreY_m(j), 1.0);
      const double dist = BruteForceDistance(scanner.world(), o, -Eigen::Vector3d::UnitZ(), /*with_arm=*/false);
      ASSERT_FALSE(std::isnan(dist));
      EXPECT_NEAR(h.at<float>(j, i), 1.0 - dist, 2e-4) << "cell " << i << "," << j;
      ++checked;
    }
  }
  EXPECT_GT(checked, 50);
  // Outside the bin on the table: z = 0; on the rim: 40 mm (5 mm floor + 35 mm walls).
  EXPECT_NEAR(h.at<float>(40, 1), 0.0, 1e-5);
  EXPECT_NEAR(h.at<float>(40, 13), 0.040, 1e-5);
}

TEST(ScannerTest, PileThatDoesNotSettleAndUnreachableApproachAreInputErrors) {
  ScanOptions options = SmallScan();
  options.pile.kinetic_energy_threshold_j = 1e-300;
  options.pile.max_settle_time_s = 0.05;
  EXPECT_THROW(Scanner scanner(options), InputError);
  options = SmallScan();
  options.approach.start_distance_m = 1.5;
  EXPECT_THROW(Scanner scanner(options), InputError);
}

TEST(ScannerTest, OverviewPictureShowsTheArmAndTheBin) {
  ScanOptions options = SmallScan();
  options.pile.num_objects = 2;
  Scanner scanner(options);
  const cv::Mat picture = OverviewPicture(scanner.world(), 320, 240);
  ASSERT_EQ(picture.type(), CV_8UC3);
  // The arm's orange (more red than blue) and the bin's blue-grey both appear.
  int orange = 0, bluish = 0;
  for (int v = 0; v < picture.rows; ++v) {
    for (int u = 0; u < picture.cols; ++u) {
      const cv::Vec3b p = picture.at<cv::Vec3b>(v, u);
      if (p[2] > p[0] + 60) ++orange;
      if (p[0] > p[2] + 20) ++bluish;
    }
  }
  EXPECT_GT(orange, 500);
  EXPECT_GT(bluish, 500);
}

}  // namespace
}  // namespace romunect::sim
