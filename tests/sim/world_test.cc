#include "romunect/sim/world.h"

#include <cmath>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect::sim {
namespace {

constexpr double kExact = 1e-12;  // rigid-body kinematics of the same numbers: round-off only

World::ArmVector ScanSeed() {
  World::ArmVector q;
  q << 0.0, 0.3, 0.9, 0.0, 0.37, 0.0;
  return q;
}

TEST(WorldTest, DefaultSceneHasThePapersBin) {
  World world(WorldOptions{});
  // The paper's bin: 120 x 55 x 35 mm inside; geometry is given to 0.1 mm.
  EXPECT_NEAR(world.bin_inner_size_m().x(), 0.120, 1e-9);
  EXPECT_NEAR(world.bin_inner_size_m().y(), 0.055, 1e-9);
  EXPECT_NEAR(world.bin_inner_size_m().z(), 0.035, 1e-9);
  EXPECT_EQ(world.num_objects(), 0);
}

TEST(WorldTest, MissingSceneFileNamesTheFile) {
  WorldOptions options;
  options.scene_file = "/nonexistent/scene.xml";
  try {
    World world(options);
    FAIL() << "no exception";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/scene.xml"), std::string::npos) << e.what();
  }
}

TEST(WorldTest, InvalidMjcfSceneWithoutBinAndMissingMeshAreInputErrors) {
  testing::ScratchDir dir("sim_world_bad_scenes");
  const std::string arm = (ScenesDir() / "arm" / "arm.xml").string();
  testing::WriteText(dir / "broken.xml", "<mujoco><worldbody><body></mujoco>");
  testing::WriteText(dir / "no_bin.xml", "<mujoco><include file=\"" + arm + "\"/></mujoco>");
  testing::WriteText(dir / "no_mesh.xml", "<mujoco><include file=\"" + arm +
                                              "\"/><asset><mesh name=\"m\" file=\"missing.stl\"/></asset>"
                                              "<worldbody><body name=\"bin\"><geom type=\"mesh\" mesh=\"m\"/>"
                                              "</body></worldbody></mujoco>");
  for (const char* name : {"broken.xml", "no_bin.xml", "no_mesh.xml"}) {
    WorldOptions options;
    options.scene_file = dir / name;
    try {
      World world(options);
      ADD_FAILURE() << name << ": no exception";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
}

TEST(WorldTest, RigThatDoesNotFitOnTheHandIsRejected) {
  WorldOptions options;
  options.T_H_C = Pose::Identity();
  options.T_H_C->translation() = Eigen::Vector3d(0.5, 0, 0);
  EXPECT_THROW(World world(options), InputError);
}

TEST(WorldTest, RigReplacesCameraAndProjectorSites) {
  WorldOptions options;
  options.T_H_C = MakePose(Eigen::Matrix3d(Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ())), {0.03, 0.01, 0.06});
  options.T_C_P = MakePose(Eigen::Matrix3d(Eigen::AngleAxisd(-0.2, Eigen::Vector3d::UnitY())), {0.05, 0, 0});
  World world(options);
  world.SetArmQ(ScanSeed());
  const Pose T_W_H = world.SitePose_W(ArmSite::kHand);
  EXPECT_TRUE(testing::PosesNear(world.T_W_C(), T_W_H * *options.T_H_C, kExact, kExact));
  EXPECT_TRUE(testing::PosesNear(world.T_W_P(), T_W_H * *options.T_H_C * *options.T_C_P, kExact, kExact));
  EXPECT_TRUE(testing::PosesNear(world.T_C_P(), *options.T_C_P, kExact, kExact));
}

TEST(WorldTest, DefaultCameraLooksAlongTheFlangeWithFiveCentimetreBaseline) {
  World world(WorldOptions{});
  world.SetArmQ(ScanSeed());
  const Pose T_H_C = world.SitePose_W(ArmSite::kHand).inverse() * world.T_W_C();
  EXPECT_NEAR(T_H_C.rotation().col(2).dot(Eigen::Vector3d::UnitZ()), 1.0, kExact);
  EXPECT_NEAR(world.T_C_P().translation().norm(), 0.05, 1e-9);
  // The projector's axis meets the camera's at the 200 mm working distance (toe-in), to 1 mm.
  const Pose T_C_P = world.T_C_P();
  const Eigen::Vector3d p = T_C_P.translation(), d = T_C_P.rotation().col(2);
  const double s = -p.x() / d.x();
  EXPECT_NEAR((p + s * d).z(), 0.2, 1e-3);
}

TEST(WorldTest, ForwardKinematicsMatchesTheSimulatedState) {
  World world(WorldOptions{});
  World::ArmVector q = ScanSeed();
  q[3] = 0.4;
  world.SetArmQ(q);
  for (ArmSite site : {ArmSite::kHand, ArmSite::kCamera, ArmSite::kProjector, ArmSite::kSuctionTip}) {
    EXPECT_TRUE(testing::PosesNear(world.ForwardKinematics(q, site), world.SitePose_W(site), kExact, kExact));
  }
  EXPECT_TRUE(
      testing::PosesNear(world.T_B_H(), world.T_W_B().inverse() * world.SitePose_W(ArmSite::kHand), kExact, kExact));
}

TEST(WorldTest, JacobianMatchesFiniteDifferencesOfForwardKinematics) {
  World world(WorldOptions{});
  const World::ArmVector q = ScanSeed();
  const World::Jacobian J = world.SiteJacobian(q, ArmSite::kCamera);
  // Slow reference: central differences; O(h^2) truncation at h = 1e-6 is far below 1e-7.
  constexpr double h = 1e-6, kTolerance = 1e-7;
  for (int j = 0; j < World::kArmDof; ++j) {
    World::ArmVector qp = q, qm = q;
    qp[j] += h;
    qm[j] -= h;
    const Pose Tp = world.ForwardKinematics(qp, ArmSite::kCamera), Tm = world.ForwardKinematics(qm, ArmSite::kCamera);
    const Eigen::Vector3d v = (Tp.translation() - Tm.translation()) / (2 * h);
    const Eigen::AngleAxisd aa(Tp.rotation() * Tm.rotation().transpose());
    const Eigen::Vector3d w = aa.angle() * aa.axis() / (2 * h);
    EXPECT_LT((v - J.col(j).head<3>()).norm(), kTolerance) << "joint " << j;
    EXPECT_LT((w - J.col(j).tail<3>()).norm(), kTolerance) << "joint " << j;
  }
}

TEST(WorldTest, ArmHoldsItsPoseUnderGravityAtTheDefaultTimeStep) {
  World world(WorldOptions{});
  world.SetArmQ(ScanSeed());
  const Pose start = world.T_W_C();
  world.Step(static_cast<int>(std::lround(1.0 / world.timestep_s())));
  // Gravity compensation holds the arm: drift after 1 s below 0.01 mm, at rest.
  EXPECT_LT((world.T_W_C().translation() - start.translation()).norm(), 1e-5);
  EXPECT_LT(world.arm_qdot().norm(), 1e-4);
}

TEST(WorldTest, ObjectsAreGeneratedWithCollisionAndRenderGeometry) {
  WorldOptions options;
  for (ObjectKind kind :
       {ObjectKind::kKey, ObjectKind::kPillBox, ObjectKind::kPuzzlePiece, ObjectKind::kLegoBrick, ObjectKind::kGear}) {
    options.objects.push_back(MakeObject(kind, 3));
  }
  World world(options);
  ASSERT_EQ(world.num_objects(), 5);
  std::vector<int> render_parts(5, 0);
  for (const GeomInfo& g : world.Geoms()) {
    if (g.object >= 0) {
      ++render_parts[g.object];
      EXPECT_TRUE(g.moving);
      EXPECT_NEAR(g.material.albedo, options.objects[g.object].material.albedo, 1e-6);
    }
  }
  for (int i = 0; i < 5; ++i) {
    const auto& o = options.objects[i];
    EXPECT_EQ(render_parts[i], static_cast<int>(o.visual_O.empty() ? o.parts_O.size() : o.visual_O.size()));
  }
}

}  // namespace
}  // namespace romunect::sim

namespace romunect::sim {
namespace {

// A 2 cm cube as a binary STL file, in millimetres; without its last `drop` triangles, an open box.
void WriteCubeStlMm(const std::filesystem::path& path, size_t drop = 0) {
  Mesh cube = Box(Eigen::Vector3d::Zero(), Eigen::Vector3d(10, 10, 10));
  cube.triangles.resize(cube.triangles.size() - drop);
  std::string bytes(80, '\0');
  auto put = [&bytes](const void* p, size_t n) { bytes.append(static_cast<const char*>(p), n); };
  const uint32_t count = static_cast<uint32_t>(cube.triangles.size());
  put(&count, 4);
  for (const auto& t : cube.triangles) {
    const float normal[3] = {0, 0, 0};
    put(normal, 12);
    for (int k = 0; k < 3; ++k) {
      const float v[3] = {static_cast<float>(cube.vertices[t[k]].x()), static_cast<float>(cube.vertices[t[k]].y()),
                          static_cast<float>(cube.vertices[t[k]].z())};
      put(v, 12);
    }
    const uint16_t attr = 0;
    put(&attr, 2);
  }
  testing::WriteText(path, bytes);
}

TEST(WorldTest, UserStlMeshBecomesAnObjectAtItsScale) {
  testing::ScratchDir dir("sim_world_user_mesh");
  WriteCubeStlMm(dir / "cube.stl");
  WorldOptions options;
  options.objects.push_back(MakeUserMeshObject(dir / "cube.stl", 1e-3, DarkMaterial()));
  World world(options);
  ASSERT_EQ(world.num_objects(), 1);
  int render_geoms = 0;
  for (const GeomInfo& g : world.Geoms()) {
    if (g.object != 0) continue;
    ++render_geoms;
    double extent = 0.0;
    for (const auto& v : g.mesh_G.vertices) extent = std::max(extent, v.cwiseAbs().maxCoeff());
    EXPECT_NEAR(extent, 0.01, 1e-6);  // 10 mm half size, in metres (float STL)
    EXPECT_NEAR(g.material.albedo, DarkMaterial().albedo, 1e-6);
  }
  EXPECT_EQ(render_geoms, 1);
  EXPECT_THROW(MakeUserMeshObject(dir / "missing.stl", 1e-3, DarkMaterial()), InputError);
  EXPECT_THROW(MakeUserMeshObject(dir / "cube.ply", 1e-3, DarkMaterial()), InputError);
}

// Meshes are checked as MuJoCo takes them, each error naming the user's file: these passed our
// check and then failed inside MuJoCo, blamed on the composed scene, or (the open box) were taken.
TEST(WorldTest, UserMeshesAreCheckedAsMuJoCoTakesThem) {
  testing::ScratchDir dir("sim_world_user_mesh_checks");
  auto error_of = [&](const std::string& name) {
    return testing::InputErrorOf([&] { MakeUserMeshObject(dir / name, 1e-3, DarkMaterial()); });
  };
  const Mesh cube = Box(Eigen::Vector3d::Zero(), Eigen::Vector3d(10, 10, 10));
  std::string ascii = "solid cube\n";
  for (const auto& t : cube.triangles) {
    ascii += "facet normal 0 0 0\nouter loop\n";
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d v = cube.vertices[t[k]];
      ascii += "vertex " + std::to_string(v.x()) + " " + std::to_string(v.y()) + " " + std::to_string(v.z()) + "\n";
    }
    ascii += "endloop\nendfacet\n";
  }
  testing::WriteText(dir / "ascii.stl", ascii + "endsolid cube\n");
  EXPECT_NE(error_of("ascii.stl").find("ascii.stl: format: an ASCII STL; MuJoCo reads binary STL only"),
            std::string::npos)
      << error_of("ascii.stl");
  std::string many(80, '\0');
  const uint32_t faces = 200001;
  many.append(reinterpret_cast<const char*>(&faces), 4);
  many.append(50 * static_cast<size_t>(faces), '\0');
  testing::WriteText(dir / "many.stl", many);
  EXPECT_NE(error_of("many.stl").find("many.stl: triangles: 200001 faces; MuJoCo takes 1 to 200000"), std::string::npos)
      << error_of("many.stl");
  WriteCubeStlMm(dir / "open.stl", 2);  // the cube without one side
  EXPECT_NE(error_of("open.stl").find("open.stl: triangles: not closed: the edge from"), std::string::npos)
      << error_of("open.stl");
  WriteCubeStlMm(dir / "cube.stl");
  EXPECT_EQ(error_of("cube.stl"), "");
}

TEST(WorldTest, SuctionGripHoldsAnObjectAndReleaseDropsIt) {
  WorldOptions options;
  options.objects.push_back(MakeObject(ObjectKind::kPillBox, 1));
  World world(options);
  World::ArmVector q;
  q << 0.0, 0.3, 0.9, 0.0, 0.37, 0.0;
  world.SetArmQ(q);
  // Put the box just under the cup, touching it (the cup's 2 mm contact margin sees it).
  const Pose T_W_tip = world.SitePose_W(ArmSite::kSuctionTip);
  Pose T_W_O = Pose::Identity();
  T_W_O.translation() = T_W_tip.translation() - Eigen::Vector3d(0, 0, 0.0165);  // box top 16 mm above O
  world.SetObjectPose(0, T_W_O);
  world.Step();
  ASSERT_EQ(world.SuctionContact(), std::optional<int>(0));
  world.Grip(0);
  const Pose T_tip_O = T_W_tip.inverse() * world.T_W_O(0);
  world.Step(500);  // 1 s: the weld holds it against gravity, to 0.1 mm (a stiff weld)
  EXPECT_TRUE(
      testing::PosesNear(world.SitePose_W(ArmSite::kSuctionTip).inverse() * world.T_W_O(0), T_tip_O, 1e-3, 1e-4));
  world.Release();
  world.Step(100);  // 0.2 s of free fall would be 20 cm; it lands on the bin or table sooner
  EXPECT_LT(world.T_W_O(0).translation().z(), T_W_O.translation().z() - 0.05);
}

}  // namespace
}  // namespace romunect::sim
