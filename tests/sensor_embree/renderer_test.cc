// GeometryRenderer against analytic ground truth of the built-in targets, the thin-lens
// quality mode, and determinism over threads and tiles.
#include "romunect/sensor/embree/renderer.h"

#include <cmath>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "romunect/testing/test_support.h"

namespace romunect::embree {
namespace {

using testing::ImagesBitEqual;

// Float hit distances at 0.2-0.3 m: ulp 3e-8 m; the plane is given exactly in float.
constexpr double kPlaneDepthTolM = 1e-5;
// Hit points re-projected through the double camera model: float rays and hits at 0.2 m
// (relative 1e-7) times ~300 px focal length.
constexpr double kReprojectionTolPx = 1e-3;
// Float hit points at 0.2-0.3 m, several roundings (lens offset, direction, t).
constexpr double kPointTolM = 2e-6;
// Unit normals computed in float from float vertices.
constexpr double kNormalTol = 1e-5;
// The projector shadow behind a step must be as wide as the geometry predicts, within 1 px
// (fidelity check F4 of docs/sensor-model.md, here for the ground-truth lit mask).
constexpr double kShadowWidthTolPx = 1.0;

const Pose kIdentity = Pose::Identity();

Pose ProjectorAt(double x_m) { return MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(x_m, 0.0, 0.0)); }

struct Rendered {
  GeometryBuffer buffer;
  RenderStats stats;
};

Rendered RenderMesh(const TriangleMesh& mesh, const CameraModel& camera, const Pose& T_C_P,
                    const RenderOptions& options = {}) {
  RayScene scene;
  scene.AddStatic(mesh, kIdentity, IrMaterial{0.3f, 0.1f, 20.0f}, 5);
  scene.Commit();
  GeometryRenderer renderer;
  Rendered r;
  r.stats = renderer.Render(scene, camera, kIdentity, T_C_P, options, &r.buffer);
  return r;
}

CameraModel PinholeCamera(int width, int height, double f) {
  CameraModel camera;
  camera.width = width;
  camera.height = height;
  camera.fx = camera.fy = f;
  camera.cx = (width - 1) / 2.0;
  camera.cy = (height - 1) / 2.0;
  return camera;
}

TEST(RendererTest, PlaneDepthIsExactAndHitsReprojectToTheirPixelCentres) {
  const CameraModel camera = testing::SmallCamera();  // with distortion
  const Rendered r = RenderMesh(MakePlaneTarget(0.2, 1.0), camera, ProjectorAt(0.05));
  ASSERT_EQ(r.buffer.layers.size(), 1u);
  ASSERT_EQ(r.buffer.materials.size(), 1u);
  EXPECT_FLOAT_EQ(r.buffer.materials[0].albedo, 0.3f);
  const GeometryLayer& layer = r.buffer.layers[0];
  EXPECT_EQ(layer.pixel_offset_px, Eigen::Vector2f::Zero());
  EXPECT_EQ(layer.lens_offset_m, Eigen::Vector2f::Zero());
  const cv::Mat depth = GroundTruthDepth(r.buffer);
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      ASSERT_NEAR(depth.at<float>(v, u), 0.2, kPlaneDepthTolM) << u << "," << v;
      const cv::Vec3f p = layer.p_C.at<cv::Vec3f>(v, u);
      const auto uv = camera.Project(Eigen::Vector3d(p[0], p[1], p[2]));
      ASSERT_TRUE(uv.has_value());
      EXPECT_LT((*uv - Eigen::Vector2d(u, v)).norm(), kReprojectionTolPx) << u << "," << v;
      const cv::Vec3f n = layer.normal_C.at<cv::Vec3f>(v, u);
      EXPECT_LT(cv::norm(n - cv::Vec3f(0, 0, -1)), kNormalTol);
      EXPECT_EQ(layer.object_id.at<int>(v, u), 5);
      EXPECT_EQ(layer.material.at<int>(v, u), 0);
      EXPECT_EQ(layer.lit.at<uint8_t>(v, u), 1);
    }
  }
  const int64_t pixels = camera.width * camera.height;
  EXPECT_EQ(r.stats.camera_rays, pixels);
  EXPECT_EQ(r.stats.hits, pixels);
  EXPECT_EQ(r.stats.lit, pixels);
  EXPECT_NE(r.stats.BriefReport().find("hits"), std::string::npos);
}

TEST(RendererTest, MissedRaysAreNaNWithNoIdAndZeroGroundTruth) {
  const CameraModel camera = testing::SmallCamera();
  // A plane 1 cm wide at 0.2 m covers the middle 15 px of the 80 px image.
  const Rendered r = RenderMesh(MakePlaneTarget(0.2, 0.01), camera, ProjectorAt(0.05));
  const GeometryLayer& layer = r.buffer.layers[0];
  const cv::Mat depth = GroundTruthDepth(r.buffer);
  EXPECT_TRUE(std::isnan(layer.p_C.at<cv::Vec3f>(0, 0)[0]));
  EXPECT_EQ(depth.at<float>(0, 0), 0.0f);
  EXPECT_EQ(layer.object_id.at<int>(0, 0), -1);
  EXPECT_EQ(layer.material.at<int>(0, 0), -1);
  EXPECT_EQ(layer.lit.at<uint8_t>(0, 0), 0);
  EXPECT_NEAR(depth.at<float>(29, 39), 0.2, kPlaneDepthTolM);
  EXPECT_EQ(cv::countNonZero(depth), r.stats.hits);
  EXPECT_LT(r.stats.hits, camera.width * camera.height / 10);
}

TEST(RendererTest, TiltedPlaneMatchesAnalyticDepth) {
  const CameraModel camera = testing::SmallCamera();
  const double d = 0.2, tilt = 0.5;
  const Rendered r = RenderMesh(MakeTiltedPlaneTarget(d, 1.0, tilt), camera, ProjectorAt(0.05));
  const cv::Mat table = camera.RayTable();
  const cv::Mat depth = GroundTruthDepth(r.buffer);
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      // z = d + x tan(tilt) with x = z x_n  =>  z = d / (1 - x_n tan(tilt)).
      const double x_n = table.at<cv::Vec2f>(v, u)[0];
      EXPECT_NEAR(depth.at<float>(v, u), d / (1.0 - x_n * std::tan(tilt)), kPlaneDepthTolM);
    }
  }
}

TEST(RendererTest, SphereMatchesAnalyticDepthWithinItsFacets) {
  const CameraModel camera = PinholeCamera(96, 72, 300.0);
  const double front = 0.2, radius = 0.03;
  const TriangleMesh mesh = MakeSphereTarget(front, radius, 5);
  // The mesh lies inside the sphere, by at most the sagitta of its largest facet.
  double circumradius = 0.0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices_O[t[0]].cast<double>(), b = mesh.vertices_O[t[1]].cast<double>(),
                          c = mesh.vertices_O[t[2]].cast<double>();
    const double A = (b - c).norm(), B = (a - c).norm(), C = (a - b).norm();
    circumradius = std::max(circumradius, A * B * C / (2.0 * (b - a).cross(c - a).norm()));
  }
  const double sagitta = radius - std::sqrt(radius * radius - circumradius * circumradius);
  // Along a ray meeting the surface at incidence <= 60 degrees: sagitta / cos(60).
  const double facet_tol_m = 2.0 * sagitta + kPointTolM;
  ASSERT_LT(facet_tol_m, 2e-5);  // level 5 is fine enough for a meaningful check

  const Rendered r = RenderMesh(mesh, camera, ProjectorAt(0.05));
  const cv::Mat depth = GroundTruthDepth(r.buffer);
  const Eigen::Vector3d centre(0, 0, front + radius);
  int checked = 0;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const Eigen::Vector3d ray = camera.Ray(Eigen::Vector2d(u, v));
      // |z ray - centre| = radius: a z^2 - 2 b z + c = 0.
      const double a = ray.squaredNorm(), b = ray.dot(centre), c = centre.squaredNorm() - radius * radius;
      const double disc = b * b - a * c;
      const float z = depth.at<float>(v, u);
      if (disc < 0.0) {
        EXPECT_EQ(z, 0.0f) << u << "," << v;  // the mesh is inside the sphere: no hit
        continue;
      }
      const double z_true = (b - std::sqrt(disc)) / a;
      const Eigen::Vector3d normal = (z_true * ray - centre).normalized();
      if (-normal.dot(ray.normalized()) < 0.5) continue;  // grazing: facets dominate
      ++checked;
      EXPECT_GE(z, z_true - kPointTolM) << u << "," << v;
      EXPECT_LE(z, z_true + facet_tol_m) << u << "," << v;
      EXPECT_EQ(r.buffer.layers[0].lit.at<uint8_t>(v, u), 1) << u << "," << v;
    }
  }
  EXPECT_GT(checked, 1000);
}

TEST(RendererTest, StepShadowIsAsWideAsTheGeometryPredictsOnTheFarSide) {
  const CameraModel camera = PinholeCamera(160, 120, 400.0);
  const double d = 0.2, h = 0.02, b = 0.05;
  const TriangleMesh step = MakeStepTarget(d, h, 0.3);
  // Projector on the near (x < 0) side: the riser's top edge shadows the far plane over
  // 0 < x <= b h / (d - h), seen at u - cx = fx x / d.
  const double expected_px = camera.fx * b * h / ((d - h) * d);
  const Rendered r = RenderMesh(step, camera, ProjectorAt(-b));
  const cv::Mat depth = GroundTruthDepth(r.buffer);
  const cv::Mat& lit = r.buffer.layers[0].lit;
  for (int v : {10, 60, 110}) {
    int shadow = 0, first_shadow = -1, last_shadow = -1;
    for (int u = 0; u < camera.width; ++u) {
      const bool far = std::abs(depth.at<float>(v, u) - d) < kPlaneDepthTolM;
      const bool near = std::abs(depth.at<float>(v, u) - (d - h)) < kPlaneDepthTolM;
      ASSERT_TRUE(far || near) << u << "," << v;
      if (!lit.at<uint8_t>(v, u)) {
        EXPECT_TRUE(far) << u;
        ++shadow;
        if (first_shadow < 0) first_shadow = u;
        last_shadow = u;
      }
    }
    EXPECT_NEAR(shadow, expected_px, kShadowWidthTolPx) << "row " << v;
    EXPECT_EQ(first_shadow, 80);                        // starts at the first far-plane pixel (x > 0)
    EXPECT_EQ(last_shadow - first_shadow + 1, shadow);  // one band
  }
  // Projector on the far side: the far plane sees it past the riser, no shadow at all.
  const Rendered other = RenderMesh(step, camera, ProjectorAt(b));
  EXPECT_EQ(cv::countNonZero(other.buffer.layers[0].lit), camera.width * camera.height);
}

TEST(RendererTest, BoxOnPlaneShowsTopAndFloorDepths) {
  const CameraModel camera = PinholeCamera(96, 72, 300.0);
  const double d = 0.2, box = 0.02, height = 0.01;
  const Rendered r = RenderMesh(MakeBoxOnPlaneTarget(d, 0.2, box, height), camera, ProjectorAt(0.05));
  const cv::Mat depth = GroundTruthDepth(r.buffer);
  // Box top spans |x| < box/2 at z = d - h: |u - cx| < fx box / (2 (d - h)) = 31.6 px.
  int top = 0, floor = 0;
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) {
      const double x_n = (u - camera.cx) / camera.fx, y_n = (v - camera.cy) / camera.fy;
      const float z = depth.at<float>(v, u);
      if (std::max(std::abs(x_n), std::abs(y_n)) * (d - height) < 0.5 * box - 1e-4) {
        EXPECT_NEAR(z, d - height, kPlaneDepthTolM) << u << "," << v;
        ++top;
      } else if (std::max(std::abs(x_n), std::abs(y_n)) * d > 0.5 * box + 1e-4) {
        EXPECT_NEAR(z, d, kPlaneDepthTolM) << u << "," << v;
        ++floor;
      }
    }
  }
  EXPECT_GT(top, 1000);
  EXPECT_GT(floor, 1000);
}

TEST(RendererTest, ThinLensSamplesConvergeAtTheFocusDistanceAndSpreadOffIt) {
  const CameraModel camera = testing::SmallCamera();
  RenderOptions options;
  options.samples_per_pixel = 4;
  options.focus_distance_m = 0.2;
  options.aperture_radius_m = 0.004;
  const auto pattern = QualitySamplePattern(4, options.aperture_radius_m);
  ASSERT_EQ(pattern.size(), 4u);
  Eigen::Vector2f pixel_sum = Eigen::Vector2f::Zero(), lens_sum = Eigen::Vector2f::Zero();
  for (const auto& s : pattern) {
    pixel_sum += s.pixel_offset_px;
    lens_sum += s.lens_offset_m;
    EXPECT_LT(s.pixel_offset_px.cwiseAbs().maxCoeff(), 0.5f);      // inside the pixel
    EXPECT_LE(s.lens_offset_m.norm(), options.aperture_radius_m);  // inside the aperture
  }
  EXPECT_LT(pixel_sum.norm(), 1e-6f);  // centred on the pixel centre
  EXPECT_LT(lens_sum.norm(), 1e-9f);   // and on the lens centre

  for (double z : {0.2, 0.25}) {
    const Rendered r = RenderMesh(MakePlaneTarget(z, 1.0), camera, ProjectorAt(0.05), options);
    ASSERT_EQ(r.buffer.layers.size(), 4u);
    EXPECT_EQ(r.stats.camera_rays, 4 * camera.width * camera.height);
    for (int k = 0; k < 4; ++k) {
      const GeometryLayer& layer = r.buffer.layers[k];
      EXPECT_EQ(layer.pixel_offset_px, pattern[k].pixel_offset_px);
      EXPECT_EQ(layer.lens_offset_m, pattern[k].lens_offset_m);
      // Through lens point l towards the focus point: p = z ray(u + offset) + l (1 - z / z_f).
      const Eigen::Vector2d blur = pattern[k].lens_offset_m.cast<double>() * (1.0 - z / options.focus_distance_m);
      for (int v = 0; v < camera.height; v += 7) {
        for (int u = 0; u < camera.width; u += 7) {
          const Eigen::Vector2d at = Eigen::Vector2d(u, v) + pattern[k].pixel_offset_px.cast<double>();
          Eigen::Vector3d expected = camera.Unproject(at, z);
          expected.head<2>() += blur;
          const cv::Vec3f p = layer.p_C.at<cv::Vec3f>(v, u);
          EXPECT_LT((Eigen::Vector3d(p[0], p[1], p[2]) - expected).norm(), kPointTolM)
              << "z " << z << " layer " << k << " pixel " << u << "," << v;
        }
      }
    }
  }
}

// A pile in a bin and a tilted plate (a moving part) above it, seen from 0.2 m.
struct PileScene {
  RayScene scene;
  CameraModel camera = PinholeCamera(96, 72, 320.0);
  Pose T_C_P = MakePose(Eigen::AngleAxisd(-0.26, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                        Eigen::Vector3d(0.05, 0.0, 0.0));
  PileScene() {
    BinSceneOptions bin;
    bin.triangle_count = 20000;
    scene.AddStatic(MakeBinScene(bin), kIdentity, IrMaterial{}, 1);
    const int lid = scene.AddMoving(MakePlaneTarget(0.0, 0.02), kIdentity, IrMaterial{0.9f}, 2);
    scene.SetPose(lid, MakePose(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                                Eigen::Vector3d(0.005, 0.0, 0.17)));
    scene.Commit();
  }
};

bool SameSample(const GeometryLayer& a, const GeometryLayer& b, int v, int u) {
  const cv::Vec3f pa = a.p_C.at<cv::Vec3f>(v, u), pb = b.p_C.at<cv::Vec3f>(v, u);
  const bool same_point = (pa == pb) || (std::isnan(pa[2]) && std::isnan(pb[2]));
  return same_point && a.normal_C.at<cv::Vec3f>(v, u) == b.normal_C.at<cv::Vec3f>(v, u) &&
         a.material.at<int>(v, u) == b.material.at<int>(v, u) &&
         a.object_id.at<int>(v, u) == b.object_id.at<int>(v, u) && a.lit.at<uint8_t>(v, u) == b.lit.at<uint8_t>(v, u);
}

void ExpectBitEqual(const GeometryBuffer& a, const GeometryBuffer& b) {
  ASSERT_EQ(a.layers.size(), b.layers.size());
  for (size_t k = 0; k < a.layers.size(); ++k) {
    EXPECT_TRUE(ImagesBitEqual(a.layers[k].p_C, b.layers[k].p_C)) << k;
    EXPECT_TRUE(ImagesBitEqual(a.layers[k].normal_C, b.layers[k].normal_C)) << k;
    EXPECT_TRUE(ImagesBitEqual(a.layers[k].material, b.layers[k].material)) << k;
    EXPECT_TRUE(ImagesBitEqual(a.layers[k].object_id, b.layers[k].object_id)) << k;
    EXPECT_TRUE(ImagesBitEqual(a.layers[k].lit, b.layers[k].lit)) << k;
  }
}

TEST(RendererTest, ResultsAreBitIdenticalAtAnyThreadCountAndTileSize) {
  PileScene pile;
  RayScene& scene = pile.scene;
  const CameraModel& camera = pile.camera;
  const Pose& T_C_P = pile.T_C_P;
  RenderOptions options;
  options.samples_per_pixel = 4;
  options.aperture_radius_m = 0.003;
  GeometryRenderer renderer;
  GeometryBuffer one, two, small_tiles;
  options.threads = 1;
  renderer.Render(scene, camera, kIdentity, T_C_P, options, &one);
  options.threads = 2;
  const RenderStats stats = renderer.Render(scene, camera, kIdentity, T_C_P, options, &two);
  options.tile_size_px = 8;
  renderer.Render(scene, camera, kIdentity, T_C_P, options, &small_tiles);
  EXPECT_GT(stats.hits, stats.camera_rays / 2);
  EXPECT_LT(stats.lit, stats.hits);  // the pile shadows itself: a non-trivial lit mask
  ASSERT_EQ(one.layers.size(), 4u);
  for (const GeometryBuffer* other : {&two, &small_tiles}) ExpectBitEqual(one, *other);
}

// Every kernel the CPU has writes the bytes of the portable SSE2 one (the same IEEE operations
// in the same order), for a turned camera (every rotation element in use), border packets with
// fewer than 16 lanes, moving parts, the thin lens and adaptive sampling. The hit points are, bit
// for bit, Eigen's o_C + t (ray - o_C / focus, 1) with t their depth.
TEST(RendererTest, EveryKernelWritesTheBytesOfThePortableOneAndOfEigen) {
  PileScene pile;
  CameraModel camera = pile.camera;
  camera.width = 94;
  camera.height = 70;
  const Pose T_W_C = MakePose(Eigen::AngleAxisd(0.05, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix(),
                              Eigen::Vector3d(0.002, -0.001, 0.003));
  GeometryRenderer renderer;
  for (int samples : {1, 4, -4}) {
    SCOPED_TRACE(samples);
    RenderOptions options;
    options.samples_per_pixel = std::abs(samples);
    options.adaptive = samples < 0;
    options.aperture_radius_m = 0.003;
    options.isa = Isa::kSse2;
    GeometryBuffer portable;
    const RenderStats stats = renderer.Render(pile.scene, camera, T_W_C, pile.T_C_P, options, &portable);
    EXPECT_LT(stats.lit, stats.hits);
    for (Isa isa : {Isa::kAvx2, Isa::kAvx512, Isa::kAuto}) {
      options.isa = isa;
      if (!options.Problem().empty()) continue;  // not on this CPU
      SCOPED_TRACE(ToString(isa));
      GeometryBuffer other;
      renderer.Render(pile.scene, camera, T_W_C, pile.T_C_P, options, &other);
      ExpectBitEqual(portable, other);
    }
    const float inv_focus_m = static_cast<float>(1.0 / options.focus_distance_m);
    const size_t traced_layers = options.adaptive ? 1 : portable.layers.size();  // adaptive: some repeat layer 0
    int checked = 0;
    for (size_t k = 0; k < traced_layers; ++k) {
      const GeometryLayer& layer = portable.layers[k];
      const Eigen::Vector3f o_C(layer.lens_offset_m.x(), layer.lens_offset_m.y(), 0.0f);
      for (int v = 0; v < camera.height; ++v) {
        for (int u = 0; u < camera.width; ++u) {
          if (layer.object_id.at<int>(v, u) < 0) continue;
          const Eigen::Vector2f ray =
              camera.Ray(Eigen::Vector2d(u + layer.pixel_offset_px.x(), v + layer.pixel_offset_px.y()))
                  .head<2>()
                  .cast<float>();
          const cv::Vec3f p = layer.p_C.at<cv::Vec3f>(v, u);
          const Eigen::Vector3f expected = o_C + p[2] * Eigen::Vector3f(ray.x() - o_C.x() * inv_focus_m,
                                                                        ray.y() - o_C.y() * inv_focus_m, 1.0f);
          ASSERT_TRUE(expected.x() == p[0] && expected.y() == p[1] && expected.z() == p[2])
              << "layer " << k << " pixel " << u << "," << v;
          ++checked;
        }
      }
    }
    EXPECT_GT(checked, camera.width * camera.height / 2);
  }
}

// A sample 1/3 px off the centre crosses an edge that neither neighbour pair shows only at
// corners and sub-pixel features (a sliver of a sphere's rim): at most this share of the
// pixels whose samples see another object or shadow state than their centre.
constexpr double kMaxMissedEdgeFraction = 0.05;

TEST(RendererTest, AdaptiveSamplingTracesEdgePixelsExactlyAndRepeatsTheCentreElsewhere) {
  PileScene pile;
  GeometryRenderer renderer;
  // Reference: all four samples everywhere, through the pinhole (adaptive leaves the lens to
  // image synthesis).
  RenderOptions full;
  full.samples_per_pixel = 4;
  GeometryBuffer reference, adaptive, adaptive_two, adaptive_small_tiles;
  renderer.Render(pile.scene, pile.camera, kIdentity, pile.T_C_P, full, &reference);
  RenderOptions options = full;
  options.adaptive = true;
  options.aperture_radius_m = 0.003;  // ignored by adaptive sampling
  const RenderStats stats = renderer.Render(pile.scene, pile.camera, kIdentity, pile.T_C_P, options, &adaptive);
  options.threads = 2;
  renderer.Render(pile.scene, pile.camera, kIdentity, pile.T_C_P, options, &adaptive_two);
  options.tile_size_px = 8;
  renderer.Render(pile.scene, pile.camera, kIdentity, pile.T_C_P, options, &adaptive_small_tiles);
  ExpectBitEqual(adaptive, adaptive_two);
  ExpectBitEqual(adaptive, adaptive_small_tiles);

  ASSERT_EQ(adaptive.layers.size(), 4u);
  const int pixels = pile.camera.width * pile.camera.height;
  int refined = 0, edge_pixels = 0, missed = 0;
  for (int v = 0; v < pile.camera.height; ++v) {
    for (int u = 0; u < pile.camera.width; ++u) {
      ASSERT_TRUE(SameSample(adaptive.layers[0], reference.layers[0], v, u)) << u << "," << v;
      const bool traced = SameSample(adaptive.layers[1], reference.layers[1], v, u) &&
                          !SameSample(adaptive.layers[1], adaptive.layers[0], v, u);
      bool crosses = false;
      for (int k = 1; k < 4; ++k) {
        const GeometryLayer& a = adaptive.layers[k];
        // Each extra sample is either the reference's sample or a copy of the centre's.
        EXPECT_TRUE(SameSample(a, reference.layers[k], v, u) || SameSample(a, adaptive.layers[0], v, u))
            << u << "," << v << " layer " << k;
        crosses |= reference.layers[k].object_id.at<int>(v, u) != reference.layers[0].object_id.at<int>(v, u) ||
                   reference.layers[k].lit.at<uint8_t>(v, u) != reference.layers[0].lit.at<uint8_t>(v, u);
      }
      refined += traced;
      edge_pixels += crosses;
      missed += crosses && SameSample(adaptive.layers[1], adaptive.layers[0], v, u) &&
                SameSample(adaptive.layers[2], adaptive.layers[0], v, u) &&
                SameSample(adaptive.layers[3], adaptive.layers[0], v, u);
    }
  }
  EXPECT_GT(edge_pixels, 100);
  EXPECT_LE(missed, kMaxMissedEdgeFraction * edge_pixels) << missed << " of " << edge_pixels;
  // Samples that happen to equal the centre's bit for bit are rare but possible.
  EXPECT_LE(refined, stats.refined_pixels);
  EXPECT_GT(refined, stats.refined_pixels * 9 / 10);
  EXPECT_LT(stats.refined_pixels, pixels / 2);  // the point: most pixels get one sample
  EXPECT_EQ(stats.camera_rays, pixels + 3 * stats.refined_pixels);
  for (int k = 1; k < 4; ++k) EXPECT_TRUE(adaptive.layers[k].lens_offset_m.isZero());
}

TEST(RendererTest, OptionsNameTheFieldValueAndRule) {
  RenderOptions o;
  EXPECT_EQ(o.Problem(), "");
  o.samples_per_pixel = 3;
  EXPECT_EQ(o.Problem(), "samples_per_pixel = 3: must be 1 or 4");
  o = RenderOptions{};
  o.threads = 0;
  EXPECT_EQ(o.Problem(), "threads = 0: must be in [1, 256]");
  o = RenderOptions{};
  o.tile_size_px = 6;
  EXPECT_NE(o.Problem().find("tile_size_px = 6"), std::string::npos);
  o = RenderOptions{};
  o.focus_distance_m = 0.0;
  EXPECT_NE(o.Problem().find("focus_distance_m = 0"), std::string::npos);
  o = RenderOptions{};
  o.aperture_radius_m = -1.0;
  EXPECT_NE(o.Problem().find("aperture_radius_m = -1"), std::string::npos);
  o = RenderOptions{};
  o.adaptive = true;
  EXPECT_EQ(o.Problem(), "adaptive = true: needs samples_per_pixel = 4 (the samples it adds at edges)");
  o.samples_per_pixel = 4;
  EXPECT_EQ(o.Problem(), "");
  o.edge_slope = 0.0;
  EXPECT_EQ(o.Problem(), "edge_slope = 0: must be positive");
  o = RenderOptions{};
  o.isa = Isa::kSse2;
  EXPECT_EQ(o.Problem(), "");  // every x86-64 CPU has it
  o.isa = Isa::kScalar;
  EXPECT_EQ(o.Problem(), "isa = scalar: the renderer implements sse2, avx2, avx512");
}

}  // namespace
}  // namespace romunect::embree
