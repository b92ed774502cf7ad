// RayScene and the renderer's layer 0 against the brute-force reference on random scenes, and
// moving parts (instances) under pose updates.
#include "romunect/sensor/embree/ray_scene.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "brute_force.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/testing/test_support.h"

namespace romunect::embree {
namespace {

using testing::AppendWorldTriangles;
using testing::IntersectBruteForce;
using testing::ReferenceHit;
using testing::WorldTriangle;

// Embree works in float: vertices, instance transforms and ray origins up to ~1 m from the
// world origin carry ~1e-7 m rounding each; a few of them stay below this. Along a ray that
// meets the surface at incidence theta the error grows by 1 / cos(theta).
constexpr double kPositionTolM = 1e-6;
// Rays meeting a surface more obliquely than this are not compared (cos(theta) below).
constexpr double kMinIncidenceCos = 0.1;
// Shadow rays start from Embree's and the reference's slightly different hit points (up to
// kPositionTolM / kMinIncidenceCos apart): occluder edges within this barycentric margin
// (20 um on the 2 cm triangles) may go either way.
constexpr double kShadowEdgeMargin = 1e-3;
// Float normals from float vertices: unit vectors agree to ~1e-6; 1e-4 allows slivers.
constexpr double kNormalTol = 1e-4;
// The shadow ray starts 2e-6 m off the surface (RenderOptions::shadow_bias_m): occluders
// closer than this to the hit point are out of reach of a fair comparison.
constexpr double kShadowNearM = 1e-4;
// At most this share of rays may be too close to an edge or tie to compare.
constexpr double kMaxAmbiguousFraction = 0.1;

Pose RandomPose(std::mt19937& rng, double translation_m) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Quaterniond q(n(rng), n(rng), n(rng), n(rng));
  return MakePose(q.normalized().toRotationMatrix(), translation_m * Eigen::Vector3d(n(rng), n(rng), n(rng)));
}

// `count` random triangles in front of the camera (given in C), expressed in O.
TriangleMesh RandomTriangles(std::mt19937& rng, int count, const Pose& T_O_C) {
  std::uniform_real_distribution<double> x(-0.06, 0.06), y(-0.045, 0.045), z(0.12, 0.28), corner(-0.015, 0.015);
  TriangleMesh mesh;
  for (int i = 0; i < count; ++i) {
    const Eigen::Vector3d centre(x(rng), y(rng), z(rng));
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d p_C = centre + Eigen::Vector3d(corner(rng), corner(rng), corner(rng));
      mesh.vertices_O.push_back((T_O_C * p_C).cast<float>());
    }
    mesh.triangles.emplace_back(3 * i, 3 * i + 1, 3 * i + 2);
  }
  return mesh;
}

CameraModel WideCamera() {
  CameraModel camera;
  camera.width = 64;
  camera.height = 48;
  camera.fx = camera.fy = 80.0;
  camera.cx = 31.5;
  camera.cy = 23.5;
  camera.distortion = {-0.05, 0.01, 0.0005, -0.0005, 0.0};
  return camera;
}

struct Comparison {
  int rays = 0, compared = 0, hits = 0, shadowed = 0;
};

// Compares layer 0 of a rendered buffer with the brute-force reference, pixel by pixel.
Comparison CompareWithReference(const GeometryBuffer& buffer, const std::vector<WorldTriangle>& soup,
                                const CameraModel& camera, const Pose& T_W_C, const Pose& T_C_P) {
  Comparison c;
  const cv::Mat table = camera.RayTable();
  const GeometryLayer& layer = buffer.layers[0];
  const Eigen::Vector3d p_P_W = T_W_C * T_C_P.translation();
  const Eigen::Matrix3d R_C_W = T_W_C.rotation().transpose();
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      ++c.rays;
      const cv::Vec2f xy = table.at<cv::Vec2f>(v, u);
      const Eigen::Vector3d o = T_W_C.translation();
      const Eigen::Vector3d d = T_W_C.rotation() * Eigen::Vector3d(xy[0], xy[1], 1.0);
      const ReferenceHit ref = IntersectBruteForce(soup, o, d, 0.0, 1e30);
      if (ref.ambiguous) continue;
      const cv::Vec3f p = layer.p_C.at<cv::Vec3f>(v, u);
      const int id = layer.object_id.at<int>(v, u);
      const bool lit = layer.lit.at<uint8_t>(v, u) != 0;
      if (!ref.hit) {
        ++c.compared;
        EXPECT_TRUE(std::isnan(p[2])) << u << "," << v;
        EXPECT_EQ(id, -1);
        EXPECT_FALSE(lit);
        continue;
      }
      // Shadow: the reference decides first whether this pixel is fairly comparable.
      const Eigen::Vector3d p_W = o + ref.t * d;
      Eigen::Vector3d n_W = ref.normal.dot(d) > 0.0 ? -ref.normal : ref.normal;
      const Eigen::Vector3d to_P = p_P_W - p_W;
      const double facing = n_W.dot(to_P.normalized());
      if (std::abs(facing) < 1e-3) continue;
      const double incidence_cos = std::abs(ref.normal.dot(d.normalized()));
      if (incidence_cos < kMinIncidenceCos) continue;
      bool ref_lit = false;
      if (facing > 0.0) {
        const ReferenceHit blocker = IntersectBruteForce(soup, p_W, to_P, 0.0, 1.0, ref.triangle, kShadowEdgeMargin);
        if (blocker.ambiguous || (blocker.hit && blocker.t * to_P.norm() < kShadowNearM)) continue;
        ref_lit = !blocker.hit;
      }
      ++c.compared;
      ++c.hits;
      c.shadowed += !ref_lit;
      EXPECT_NEAR(p[2], ref.t, kPositionTolM / incidence_cos) << "pixel " << u << "," << v;
      EXPECT_EQ(id, soup[ref.triangle].object_id) << "pixel " << u << "," << v;
      EXPECT_EQ(lit, ref_lit) << "pixel " << u << "," << v << " facing " << facing;
      const cv::Vec3f n = layer.normal_C.at<cv::Vec3f>(v, u);
      const Eigen::Vector3d n_C_ref = R_C_W * n_W;
      EXPECT_LT((Eigen::Vector3d(n[0], n[1], n[2]) - n_C_ref).norm(), kNormalTol);
    }
  }
  return c;
}

TEST(RaySceneTest, MatchesBruteForceOnRandomScenesBeforeAndAfterPoseUpdates) {
  const CameraModel camera = WideCamera();
  const Pose T_C_P = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.05, 0.0, 0.0));
  for (uint32_t seed : {1u, 2u, 3u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    std::mt19937 rng(seed);
    const Pose T_W_C = RandomPose(rng, 0.3);
    RayScene scene;
    std::vector<WorldTriangle> soup;
    std::vector<TriangleMesh> moving_meshes;
    std::vector<int> handles;
    for (int part = 0; part < 4; ++part) {
      const Pose T_W_O = RandomPose(rng, 0.3);
      const TriangleMesh mesh = RandomTriangles(rng, 150, T_W_O.inverse() * T_W_C);
      const int object_id = (part < 2 ? 10 : 20) + part;
      if (part < 2) {
        scene.AddStatic(mesh, T_W_O, IrMaterial{}, object_id);
      } else {
        handles.push_back(scene.AddMoving(mesh, T_W_O, IrMaterial{}, object_id));
        moving_meshes.push_back(mesh);
      }
      AppendWorldTriangles(mesh, T_W_O, object_id, &soup);
    }
    scene.Commit();
    GeometryRenderer renderer;
    GeometryBuffer buffer;
    renderer.Render(scene, camera, T_W_C, T_C_P, RenderOptions{}, &buffer);
    Comparison c = CompareWithReference(buffer, soup, camera, T_W_C, T_C_P);
    EXPECT_GE(c.compared, (1.0 - kMaxAmbiguousFraction) * c.rays);
    EXPECT_GT(c.hits, c.rays / 3);       // the scene covers much of the view
    EXPECT_GT(c.shadowed, c.hits / 20);  // and shadows something: the shadow test means something

    // Move the two moving parts by a small random motion and compare again.
    soup.resize(300);  // the static part's triangles come first
    for (size_t k = 0; k < handles.size(); ++k) {
      const Pose small = MakePose(Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                                  Eigen::Vector3d(0.003, -0.002, 0.01));
      const Pose T_W_O_new = T_W_C * small * T_W_C.inverse() * scene.pose(handles[k]);
      scene.SetPose(handles[k], T_W_O_new);
      AppendWorldTriangles(moving_meshes[k], T_W_O_new, 22 + static_cast<int>(k), &soup);
    }
    EXPECT_FALSE(scene.committed());
    scene.Commit();
    renderer.Render(scene, camera, T_W_C, T_C_P, RenderOptions{}, &buffer);
    c = CompareWithReference(buffer, soup, camera, T_W_C, T_C_P);
    EXPECT_GE(c.compared, (1.0 - kMaxAmbiguousFraction) * c.rays);
    EXPECT_GT(c.hits, c.rays / 4);
    EXPECT_EQ(scene.stats().static_builds, 1);  // pose updates never rebuild the static BVH
  }
}

// Rigid motion of the whole world (camera and part together) leaves the image in C unchanged,
// up to float rounding of the moved instance transform and rays.
TEST(RaySceneTest, MovingPartWithTheCameraGivesTheSameImage) {
  const CameraModel camera = WideCamera();
  const Pose T_C_P = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.05, 0.0, 0.0));
  const TriangleMesh sphere = MakeSphereTarget(0.0, 0.05, 4);
  const Pose T_W_O = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.0, 0.0, 0.15));
  RayScene scene;
  const int part = scene.AddMoving(sphere, T_W_O, IrMaterial{}, 3);
  scene.Commit();
  GeometryRenderer renderer;
  GeometryBuffer before, after;
  renderer.Render(scene, camera, Pose::Identity(), T_C_P, RenderOptions{}, &before);
  std::mt19937 rng(7);
  const Pose D = RandomPose(rng, 0.2);
  scene.SetPose(part, D * T_W_O);
  scene.Commit();
  renderer.Render(scene, camera, D, T_C_P, RenderOptions{}, &after);
  int hits = 0;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const cv::Vec3f a = before.layers[0].p_C.at<cv::Vec3f>(v, u);
      const cv::Vec3f b = after.layers[0].p_C.at<cv::Vec3f>(v, u);
      ASSERT_EQ(std::isnan(a[2]), std::isnan(b[2])) << u << "," << v;
      if (std::isnan(a[2])) continue;
      ++hits;
      const cv::Vec3f n = before.layers[0].normal_C.at<cv::Vec3f>(v, u);
      const double incidence_cos = std::abs(n.dot(a)) / cv::norm(a);
      if (incidence_cos < kMinIncidenceCos) continue;  // silhouette: rounding grows unbounded
      EXPECT_LT(cv::norm(a - b), kPositionTolM / incidence_cos) << u << "," << v;
      EXPECT_EQ(before.layers[0].lit.at<uint8_t>(v, u), after.layers[0].lit.at<uint8_t>(v, u));
      EXPECT_EQ(after.layers[0].object_id.at<int>(v, u), 3);
    }
  }
  EXPECT_GT(hits, camera.width * camera.height / 4);
}

// Moving parts that no ray can reach are skipped (RenderStats counts them) and change nothing:
// a part behind the camera (as an arm's links behind a hand-held sensor) leaves every byte as
// without it; a part beside the view but between the scene and the projector is out of the
// camera rays' reach yet still casts its shadow, checked against the brute-force reference.
TEST(RaySceneTest, MovingPartsOutOfReachAreSkippedAndChangeNothing) {
  const CameraModel camera = WideCamera();
  const Pose T_C_P = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.05, 0.0, 0.0));
  std::mt19937 rng(11);
  const Pose T_W_C = RandomPose(rng, 0.3);
  const TriangleMesh plane = MakePlaneTarget(0.2, 1.0);  // in C: z = 0.2
  // Behind the lens plane (z in C from -0.05 to -0.01 m): no camera or shadow ray gets there.
  const TriangleMesh behind = MakeIcosphere(Eigen::Vector3d(0.0, 0.0, -0.03), 0.02, 2);
  // Beside the view (slopes up to ~0.42 reach x = 0.015 m at z = 0.035 m) and 3 cm in front of
  // the projector: it shadows a disc of ~3 cm radius around x = 0.05 m on the plane.
  const TriangleMesh caster = MakeIcosphere(Eigen::Vector3d(0.05, 0.0, 0.03), 0.005, 2);
  auto render = [&](const std::vector<const TriangleMesh*>& moving, GeometryBuffer* buffer) {
    RayScene scene;
    scene.AddStatic(plane, T_W_C, IrMaterial{}, 1);
    for (size_t k = 0; k < moving.size(); ++k) {
      scene.AddMoving(*moving[k], T_W_C, IrMaterial{}, 2 + static_cast<int>(k));
    }
    scene.Commit();
    GeometryRenderer renderer;
    return renderer.Render(scene, camera, T_W_C, T_C_P, RenderOptions{}, buffer);
  };
  GeometryBuffer alone, with_behind, with_caster;
  const RenderStats alone_stats = render({}, &alone);
  EXPECT_EQ(alone_stats.moving_out_of_view, 0);
  const RenderStats behind_stats = render({&behind}, &with_behind);
  EXPECT_EQ(behind_stats.moving_out_of_view, 1);
  EXPECT_EQ(behind_stats.moving_out_of_shadows, 1);
  const GeometryLayer& a = alone.layers[0];
  const GeometryLayer& b = with_behind.layers[0];
  EXPECT_TRUE(testing::ImagesBitEqual(a.p_C, b.p_C));
  EXPECT_TRUE(testing::ImagesBitEqual(a.normal_C, b.normal_C));
  EXPECT_TRUE(testing::ImagesBitEqual(a.material, b.material));
  EXPECT_TRUE(testing::ImagesBitEqual(a.object_id, b.object_id));
  EXPECT_TRUE(testing::ImagesBitEqual(a.lit, b.lit));

  const RenderStats caster_stats = render({&behind, &caster}, &with_caster);
  EXPECT_EQ(caster_stats.moving_out_of_view, 2);
  EXPECT_EQ(caster_stats.moving_out_of_shadows, 1);  // the caster is within the shadow rays' reach
  EXPECT_TRUE(testing::ImagesBitEqual(a.p_C, with_caster.layers[0].p_C));
  const int unlit = camera.width * camera.height - cv::countNonZero(with_caster.layers[0].lit);
  EXPECT_GT(unlit, camera.width * camera.height / 20);
  std::vector<WorldTriangle> soup;
  AppendWorldTriangles(plane, T_W_C, 1, &soup);
  AppendWorldTriangles(behind, T_W_C, 2, &soup);
  AppendWorldTriangles(caster, T_W_C, 3, &soup);
  const Comparison c = CompareWithReference(with_caster, soup, camera, T_W_C, T_C_P);
  EXPECT_GE(c.compared, (1.0 - kMaxAmbiguousFraction) * c.rays);
  EXPECT_GT(c.shadowed, c.rays / 20);
}

// Float instance transform of a translation: exact to float rounding at 0.25 m (~1.5e-8 m).
constexpr double kPlaneDepthTolM = 1e-5;

TEST(RaySceneTest, PlaneInstanceDepthFollowsItsPose) {
  const CameraModel camera = WideCamera();
  RayScene scene;
  const int part = scene.AddMoving(MakePlaneTarget(0.0, 1.0),
                                   MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.2)), IrMaterial{}, 1);
  scene.Commit();
  GeometryRenderer renderer;
  GeometryBuffer buffer;
  const Pose T_C_P = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.05, 0, 0));
  for (double z : {0.2, 0.25, 0.31}) {
    scene.SetPose(part, MakePose(Eigen::AngleAxisd(0.7 * z, Eigen::Vector3d::UnitZ()).toRotationMatrix(),
                                 Eigen::Vector3d(0.01, -0.02, z)));
    scene.Commit();
    renderer.Render(scene, camera, Pose::Identity(), T_C_P, RenderOptions{}, &buffer);
    const cv::Mat depth = GroundTruthDepth(buffer);
    double lo, hi;
    cv::minMaxLoc(depth, &lo, &hi);
    EXPECT_NEAR(lo, z, kPlaneDepthTolM);
    EXPECT_NEAR(hi, z, kPlaneDepthTolM);
    EXPECT_EQ(cv::countNonZero(buffer.layers[0].lit), camera.width * camera.height);
  }
}

TEST(RaySceneTest, InvalidMeshIsAProgrammerError) {
  TriangleMesh bad = MakePlaneTarget(0.2, 0.1);
  bad.triangles[1][0] = 17;
  EXPECT_DEATH(
      {
        RayScene scene;
        scene.AddStatic(bad, Pose::Identity(), IrMaterial{}, 0);
      },
      "triangles\\[1\\]");
}

TEST(RaySceneTest, OptionsNameTheirBadField) {
  RaySceneOptions options;
  options.build_threads = -1;
  EXPECT_NE(options.Problem().find("build_threads = -1"), std::string::npos);
}

}  // namespace
}  // namespace romunect::embree
