// Triangle meshes in an object frame O (metres), their loaders (STL ascii and binary, OBJ) and
// the built-in test targets. Geometry back ends (the Embree renderer) place a mesh in the world
// with a pose T_W_O.
//
// Built-in targets are built in a frame O with the camera's axes (x right, y down, z forward):
// a camera at O's origin with T_W_C = T_W_O sees them head on, at z = distance_m.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "romunect/sensor/pose.h"

namespace romunect {

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices_O;  // vertex positions in O, metres
  std::vector<Eigen::Vector3i> triangles;   // indices into vertices_O, one row per triangle

  // Why the mesh is unusable, or "" when it is valid: at least one triangle, every vertex
  // finite, every index in [0, vertices_O.size()). The text starts with the field
  // ("vertices[3]: ...", "triangles[7]: ...").
  std::string Problem() const;

  // Appends `other`, moved into this mesh's frame by T_this_other.
  void Append(const TriangleMesh& other, const Pose& T_this_other = Pose::Identity());

  size_t triangle_count() const { return triangles.size(); }
};

// Throws InputError(source, field, problem) when mesh.Problem() is not "".
void ValidateMesh(const TriangleMesh& mesh, const std::string& source);

// Loads an STL (ascii or binary, detected from the content) or Wavefront OBJ (v and f lines;
// polygons are fanned into triangles, negative indices count from the end) file by extension.
// Coordinates are multiplied by unit_m (0.001 for files in millimetres). Throws InputError
// naming the file (and line or field) for an unknown extension, unreadable or malformed file,
// an empty mesh, NaN vertices or bad indices.
TriangleMesh LoadMesh(const std::filesystem::path& path, double unit_m = 1.0);

// Writes a binary STL (for tests and for exporting generated scenes), atomically.
void SaveStl(const std::filesystem::path& path, const TriangleMesh& mesh);

// ---- Built-in targets (frame O = camera axes, see above) ----------------------------------

// A square plane of side size_m at z = distance_m, facing the camera.
TriangleMesh MakePlaneTarget(double distance_m, double size_m);
// A square plane of side size_m through (0, 0, distance_m), tilted about O's y axis by
// tilt_rad: z = distance_m + x tan(tilt_rad).
TriangleMesh MakeTiltedPlaneTarget(double distance_m, double size_m, double tilt_rad);
// A step: the half x < 0 at z = distance_m - step_m (nearer), the half x >= 0 at
// z = distance_m, joined by a riser in the plane x = 0. Side size_m.
TriangleMesh MakeStepTarget(double distance_m, double step_m, double size_m);
// A plane of side size_m at z = distance_m with a box (box_size_m square, box_height_m high)
// standing on it at the centre, its top face at z = distance_m - box_height_m.
TriangleMesh MakeBoxOnPlaneTarget(double distance_m, double size_m, double box_size_m, double box_height_m);
// An icosphere centred at (0, 0, distance_m + radius_m) (its front at distance_m) whose
// vertices lie on the sphere; 20 * 4^subdivisions triangles.
TriangleMesh MakeSphereTarget(double distance_m, double radius_m, int subdivisions = 4);
// An icosphere of radius_m centred at centre_O.
TriangleMesh MakeIcosphere(const Eigen::Vector3d& centre_O, double radius_m, int subdivisions);

// Names of the built-in targets: "plane", "tilted-plane", "step", "box", "sphere".
std::vector<std::string> BuiltinTargetNames();
// The named target at distance_m with a footprint of size_m, default proportions (tilt 30
// degrees, step size_m / 10 with its near half on +x, box size_m / 3 wide and size_m / 10
// high, sphere radius size_m / 4). Throws InputError(source, "target", ...) for an unknown name.
TriangleMesh MakeBuiltinTarget(const std::string& name, double distance_m, double size_m,
                               const std::string& source = "target");

// ---- Procedural bin scene for benchmarks --------------------------------------------------

struct BinSceneOptions {
  uint32_t seed = 1;
  int triangle_count = 300000;   // approximate total (within one object's triangles)
  double distance_m = 0.2;       // z of the bin floor in O (camera axes, looking into the bin)
  double inner_width_m = 0.08;   // bin inner size along x
  double inner_height_m = 0.06;  // bin inner size along y
  double wall_height_m = 0.04;   // walls rise from the floor towards the camera (-z)
  double min_object_radius_m = 0.003;
  double max_object_radius_m = 0.008;
  int object_subdivisions = 3;  // icosphere level of each object: 20 * 4^level triangles

  // Why the options are unusable, or "" (names the field, its value and the rule).
  std::string Problem() const;
};

// A bin (floor, four walls and a rim) holding a random pile of ellipsoids (scaled, rotated
// icospheres) resting in it, as one mesh. The same options give the same bytes.
TriangleMesh MakeBinScene(const BinSceneOptions& options);

}  // namespace romunect
