// Tests of sensor/mesh.h: loaders, validation, built-in targets and the bin scene.
#include "romunect/sensor/mesh.h"

#include <cmath>
#include <cstring>
#include <fstream>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

using testing::ScratchDir;
using testing::WriteText;

// Loaders convert through double and back to float: a round trip keeps the float exactly.
constexpr float kExactFloat = 0.0f;

TriangleMesh Tetrahedron() {
  TriangleMesh mesh;
  mesh.vertices_O = {{0, 0, 0}, {0.01f, 0, 0}, {0, 0.02f, 0}, {0, 0, 0.03f}};
  mesh.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return mesh;
}

// The triangle corners of a mesh as a flat list (loaders may duplicate shared vertices).
std::vector<Eigen::Vector3f> Corners(const TriangleMesh& mesh) {
  std::vector<Eigen::Vector3f> corners;
  for (const auto& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) corners.push_back(mesh.vertices_O[t[k]]);
  }
  return corners;
}

TEST(MeshTest, BinaryStlRoundTripKeepsEveryCorner) {
  ScratchDir dir("stl");
  const TriangleMesh mesh = Tetrahedron();
  SaveStl(dir / "t.stl", mesh);
  const TriangleMesh loaded = LoadMesh(dir / "t.stl");
  ASSERT_EQ(loaded.triangle_count(), 4u);
  const auto a = Corners(mesh), b = Corners(loaded);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) EXPECT_LE((a[i] - b[i]).norm(), kExactFloat) << i;
}

TEST(MeshTest, AsciiStlInMillimetresIsScaledToMetres) {
  ScratchDir dir("stl");
  WriteText(dir / "a.STL", "solid part\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 10 0 0\n"
                           "   vertex 0 20 0\n  endloop\n endfacet\nendsolid part\n");
  const TriangleMesh mesh = LoadMesh(dir / "a.STL", 0.001);
  ASSERT_EQ(mesh.triangle_count(), 1u);
  EXPECT_FLOAT_EQ(mesh.vertices_O[1].x(), 0.010f);
  EXPECT_FLOAT_EQ(mesh.vertices_O[2].y(), 0.020f);
}

TEST(MeshTest, ObjFansPolygonsAndResolvesNegativeAndSlashIndices) {
  ScratchDir dir("obj");
  WriteText(dir / "q.obj", "# a quad and a triangle\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\n"
                           "f 1//1 2//1 3//1 4//1\nf -1 -2 -3\n");
  const TriangleMesh mesh = LoadMesh(dir / "q.obj");
  ASSERT_EQ(mesh.vertices_O.size(), 4u);
  ASSERT_EQ(mesh.triangle_count(), 3u);
  EXPECT_EQ(mesh.triangles[0], Eigen::Vector3i(0, 1, 2));
  EXPECT_EQ(mesh.triangles[1], Eigen::Vector3i(0, 2, 3));
  EXPECT_EQ(mesh.triangles[2], Eigen::Vector3i(3, 2, 1));
}

// Loading `text` as `name` must throw an InputError naming the file and `field_part`.
void ExpectLoadError(const std::string& name, const std::string& text, const std::string& message_part) {
  ScratchDir dir("bad");
  WriteText(dir / name, text);
  try {
    LoadMesh(dir / name);
    ADD_FAILURE() << name << " loaded without error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), (dir / name).string());
    EXPECT_NE(std::string(e.what()).find(message_part), std::string::npos) << e.what();
  }
}

TEST(MeshTest, BadFilesThrowInputErrorNamingFileAndField) {
  ExpectLoadError("empty.stl", "solid nothing\nendsolid nothing\n", "triangles: the mesh is empty");
  ExpectLoadError("empty.obj", "# nothing\nv 0 0 0\n", "the mesh is empty");
  ExpectLoadError("nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "vertices[0]");
  ExpectLoadError("index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 5\n", "line 4");
  ExpectLoadError("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4");
  ExpectLoadError("short.stl",
                  "solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n"
                  " vertex 1 0 0\n endloop\n endfacet\nendsolid\n",
                  "2 vertices");
  ExpectLoadError("garbage.stl", "this is not a mesh", "neither a binary STL");
  ExpectLoadError("model.ply", "ply\n", "unknown mesh format");
  ExpectLoadError("nan.stl",
                  "solid x\n facet normal 0 0 1\n outer loop\n vertex 0 0 nan\n vertex 1 0 0\n"
                  " vertex 0 1 0\n endloop\n endfacet\nendsolid\n",
                  "vertices[0]");
  EXPECT_THROW(LoadMesh("/nonexistent/mesh.stl"), InputError);
}

TEST(MeshTest, ValidateNamesTheBadIndex) {
  TriangleMesh mesh = Tetrahedron();
  mesh.triangles[2][1] = 4;
  EXPECT_EQ(mesh.Problem(), "triangles[2]: vertex index 4 is outside [0, 4)");
  try {
    ValidateMesh(mesh, "scene.json");
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "scene.json");
    EXPECT_EQ(e.field(), "triangles[2]");
  }
  EXPECT_EQ(Tetrahedron().Problem(), "");
  EXPECT_NE(TriangleMesh().Problem(), "");
}

// Icosphere vertices are normalized in double and stored as float.
constexpr double kFloatVertexTolM = 1e-7;

TEST(MeshTest, TargetsHaveTheirDocumentedGeometry) {
  const TriangleMesh plane = MakePlaneTarget(0.2, 0.1);
  for (const auto& p : plane.vertices_O) {
    EXPECT_FLOAT_EQ(p.z(), 0.2f);
    EXPECT_FLOAT_EQ(std::abs(p.x()), 0.05f);
  }
  const TriangleMesh tilted = MakeTiltedPlaneTarget(0.2, 0.1, 0.3);
  for (const auto& p : tilted.vertices_O) {
    EXPECT_NEAR(p.z(), 0.2 + p.x() * std::tan(0.3), kFloatVertexTolM);
  }
  const TriangleMesh sphere = MakeSphereTarget(0.2, 0.02, 3);
  EXPECT_EQ(sphere.triangle_count(), 20u * 64u);
  for (const auto& p : sphere.vertices_O) {
    EXPECT_NEAR((p.cast<double>() - Eigen::Vector3d(0, 0, 0.22)).norm(), 0.02, kFloatVertexTolM);
  }
  for (const auto& name : BuiltinTargetNames()) {
    EXPECT_EQ(MakeBuiltinTarget(name, 0.2, 0.06).Problem(), "") << name;
  }
  EXPECT_THROW(MakeBuiltinTarget("donut", 0.2, 0.06), InputError);
  EXPECT_THROW(MakeBuiltinTarget("plane", -0.2, 0.06), InputError);
}

TEST(MeshTest, BinSceneHasTheRequestedSizeAndDependsOnlyOnItsSeed) {
  BinSceneOptions options;
  options.triangle_count = 20000;
  const TriangleMesh a = MakeBinScene(options), b = MakeBinScene(options);
  EXPECT_EQ(a.Problem(), "");
  // Objects have 1280 triangles each: the count is met within one object.
  EXPECT_LE(a.triangle_count(), 20000u);
  EXPECT_GT(a.triangle_count(), 20000u - 1280u);
  ASSERT_EQ(a.vertices_O.size(), b.vertices_O.size());
  EXPECT_EQ(std::memcmp(a.vertices_O.data(), b.vertices_O.data(), a.vertices_O.size() * sizeof(Eigen::Vector3f)), 0);
  options.seed = 2;
  const TriangleMesh c = MakeBinScene(options);
  ASSERT_EQ(a.vertices_O.size(), c.vertices_O.size());
  EXPECT_NE(std::memcmp(a.vertices_O.data(), c.vertices_O.data(), a.vertices_O.size() * sizeof(Eigen::Vector3f)), 0);
  // Everything lies behind the camera's near side and inside the bin's rim.
  for (const auto& p : a.vertices_O) {
    EXPECT_GT(p.z(), 0.0f);
    EXPECT_LE(p.z(), static_cast<float>(options.distance_m) + 1e-6f);
  }
  BinSceneOptions bad;
  bad.max_object_radius_m = 0.001;
  EXPECT_NE(bad.Problem().find("max_object_radius_m"), std::string::npos);
}

}  // namespace
}  // namespace romunect
