#include "romunect/sim/objects.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <random>
#include <sstream>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/mesh.h"

namespace romunect::sim {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Scales every size of a generated object by a seeded factor in [0.95, 1.05], so two objects
// of a kind are not identical (the seed is the object's own, not the pile's).
double SizeFactor(uint32_t seed) {
  std::mt19937 rng(seed);
  return std::uniform_real_distribution<double>(0.95, 1.05)(rng);
}

std::vector<Eigen::Vector2d> Rectangle(double x0, double y0, double x1, double y1) {
  return {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
}

std::vector<Eigen::Vector2d> RegularPolygon(double cx, double cy, double r, int segments) {
  std::vector<Eigen::Vector2d> outline;
  for (int i = 0; i < segments; ++i) {
    const double a = 2.0 * kPi * i / segments;
    outline.emplace_back(cx + r * std::cos(a), cy + r * std::sin(a));
  }
  return outline;
}

// An annular sector (convex for spans below pi) between radii r0 < r1, angles a0 < a1.
std::vector<Eigen::Vector2d> RingSegment(double cx, double cy, double r0, double r1, double a0, double a1) {
  return {{cx + r0 * std::cos(a0), cy + r0 * std::sin(a0)},
          {cx + r1 * std::cos(a0), cy + r1 * std::sin(a0)},
          {cx + r1 * std::cos(a1), cy + r1 * std::sin(a1)},
          {cx + r0 * std::cos(a1), cy + r0 * std::sin(a1)}};
}

ObjectSpec MakeKey(uint32_t seed) {
  const double s = SizeFactor(seed);
  const double t = 0.003 * s;
  ObjectSpec spec;
  // Seen: a bow (a ring around the key hole, as convex sectors), shoulder, blade and teeth.
  const double bow_x = -0.014 * s, r_in = 0.0035 * s, r_out = 0.011 * s;
  const int kSegments = 10;
  for (int i = 0; i < kSegments; ++i) {
    const double a0 = 2.0 * kPi * i / kSegments, a1 = 2.0 * kPi * (i + 1) / kSegments;
    spec.visual_O.push_back(ConvexPrism(RingSegment(bow_x, 0, r_in, r_out, a0, a1), 0, t));
  }
  spec.visual_O.push_back(ConvexPrism(Rectangle(-0.004 * s, -0.005 * s, 0.003 * s, 0.005 * s), 0, t));
  spec.visual_O.push_back(ConvexPrism(Rectangle(0.003 * s, -0.0035 * s, 0.036 * s, 0.0035 * s), 0, t));
  for (int i = 0; i < 4; ++i) {
    const double x = (0.010 + 0.0065 * i) * s;
    spec.visual_O.push_back(
        ConvexPrism({{x - 0.0025 * s, -0.0035 * s}, {x, -0.0065 * s}, {x + 0.0025 * s, -0.0035 * s}}, 0, t));
  }
  // Collides as a disc and a bar.
  spec.parts_O.push_back(ConvexPrism(RegularPolygon(bow_x, 0, r_out, 12), 0, t));
  spec.parts_O.push_back(ConvexPrism(Rectangle(-0.004 * s, -0.005 * s, 0.036 * s, 0.005 * s), 0, t));
  spec.density_kg_m3 = 8500.0;  // brass
  spec.material = ShinyMaterial();
  return spec;
}

ObjectSpec MakePillBox(uint32_t seed) {
  const double s = SizeFactor(seed);
  ObjectSpec spec;
  spec.visual_O.push_back(Box({0, 0, 0.006 * s}, {0.020 * s, 0.011 * s, 0.006 * s}));
  spec.visual_O.push_back(Box({0, 0, 0.014 * s}, {0.0205 * s, 0.0115 * s, 0.002 * s}));  // lid
  spec.parts_O.push_back(Box({0, 0, 0.008 * s}, {0.0205 * s, 0.0115 * s, 0.008 * s}));
  spec.density_kg_m3 = 300.0;  // a hollow plastic box with a few pills
  spec.material = BrightMaterial();
  return spec;
}

ObjectSpec MakePuzzlePiece(uint32_t seed) {
  const double s = SizeFactor(seed);
  const double t = 0.004 * s, h = 0.009 * s;
  ObjectSpec spec;
  spec.visual_O.push_back(ConvexPrism(Rectangle(-h, -h, h, h), 0, t));
  // Two knobs (on +x and +y), each a neck and a round head.
  spec.visual_O.push_back(ConvexPrism(Rectangle(h, -0.0018 * s, h + 0.002 * s, 0.0018 * s), 0, t));
  spec.visual_O.push_back(Cylinder(h + 0.0045 * s, 0, 0.0035 * s, 0, t, 12));
  spec.visual_O.push_back(ConvexPrism(Rectangle(-0.0018 * s, h, 0.0018 * s, h + 0.002 * s), 0, t));
  spec.visual_O.push_back(Cylinder(0, h + 0.0045 * s, 0.0035 * s, 0, t, 12));
  // Collides as the square and the two heads, each convex.
  spec.parts_O.push_back(ConvexPrism(Rectangle(-h, -h, h, h), 0, t));
  spec.parts_O.push_back(Cylinder(h + 0.0045 * s, 0, 0.0035 * s, 0, t, 8));
  spec.parts_O.push_back(Cylinder(0, h + 0.0045 * s, 0.0035 * s, 0, t, 8));
  spec.density_kg_m3 = 700.0;  // pressed cardboard
  spec.material = IrMaterial{0.55f, 0.05f, 10.0f};
  return spec;
}

ObjectSpec MakeLegoBrick(uint32_t seed) {
  const double s = SizeFactor(seed);
  ObjectSpec spec;
  const double hx = 0.0159 * s, hy = 0.0079 * s, hz = 0.0048 * s;
  spec.parts_O.push_back(Box({0, 0, hz}, {hx, hy, hz}));  // collides without its studs
  spec.visual_O.push_back(Box({0, 0, hz}, {hx, hy, hz}));
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 2; ++j) {
      spec.visual_O.push_back(
          Cylinder((-0.012 + 0.008 * i) * s, (-0.004 + 0.008 * j) * s, 0.0024 * s, 2 * hz, 2 * hz + 0.0017 * s, 12));
    }
  }
  spec.density_kg_m3 = 500.0;  // ABS, hollow underneath
  spec.material = IrMaterial{0.7f, 0.15f, 30.0f};
  return spec;
}

ObjectSpec MakeGear(uint32_t seed) {
  const double s = SizeFactor(seed);
  const double t = 0.007 * s, r = 0.013 * s, r_tip = 0.016 * s;
  ObjectSpec spec;
  spec.visual_O.push_back(ConvexPrism(RegularPolygon(0, 0, r, 24), 0, t));
  // Collides as one disc between root and tip radius.
  spec.parts_O.push_back(ConvexPrism(RegularPolygon(0, 0, 0.5 * (r + r_tip), 24), 0, t));
  const int kTeeth = 12;
  for (int i = 0; i < kTeeth; ++i) {
    const double a = 2.0 * kPi * i / kTeeth;
    const Eigen::Vector2d radial(std::cos(a), std::sin(a)), tangent(-std::sin(a), std::cos(a));
    const double base = 0.0022 * s, tip = 0.0012 * s, r0 = r - 0.0005 * s;
    spec.visual_O.push_back(ConvexPrism({r0 * radial - base * tangent, r_tip * radial - tip * tangent,
                                         r_tip * radial + tip * tangent, r0 * radial + base * tangent},
                                        0, t));
  }
  spec.density_kg_m3 = 7800.0;  // steel
  spec.material = DarkMaterial();
  return spec;
}

}  // namespace

const char* ToString(ObjectKind kind) {
  switch (kind) {
    case ObjectKind::kKey: return "key";
    case ObjectKind::kPillBox: return "pill_box";
    case ObjectKind::kPuzzlePiece: return "puzzle_piece";
    case ObjectKind::kLegoBrick: return "lego_brick";
    case ObjectKind::kGear: return "gear";
    case ObjectKind::kUserMesh: return "user_mesh";
  }
  return "?";
}

ObjectKind ObjectKindFromString(const std::string& name, const std::string& source) {
  for (ObjectKind kind : {ObjectKind::kKey, ObjectKind::kPillBox, ObjectKind::kPuzzlePiece, ObjectKind::kLegoBrick,
                          ObjectKind::kGear, ObjectKind::kUserMesh}) {
    if (name == ToString(kind)) return kind;
  }
  throw InputError(source, "object kind",
                   "'" + name + "' is not one of key, pill_box, puzzle_piece, lego_brick, gear, user_mesh");
}

ObjectKind GeneratedKindFromName(const std::string& name, const std::string& source) {
  static const std::pair<const char*, ObjectKind> kNames[] = {{"key", ObjectKind::kKey},
                                                              {"keys", ObjectKind::kKey},
                                                              {"pill_box", ObjectKind::kPillBox},
                                                              {"pillbox", ObjectKind::kPillBox},
                                                              {"puzzle_piece", ObjectKind::kPuzzlePiece},
                                                              {"puzzle", ObjectKind::kPuzzlePiece},
                                                              {"lego_brick", ObjectKind::kLegoBrick},
                                                              {"lego", ObjectKind::kLegoBrick},
                                                              {"gear", ObjectKind::kGear}};
  for (const auto& [n, kind] : kNames) {
    if (name == n) return kind;
  }
  throw InputError(source, "object kind", "'" + name + "' is not one of key, pillbox, puzzle, lego, gear");
}

IrMaterial BrightMaterial() { return IrMaterial{0.8f, 0.05f, 10.0f}; }
IrMaterial DarkMaterial() { return IrMaterial{0.05f, 0.1f, 20.0f}; }
IrMaterial ShinyMaterial() { return IrMaterial{0.35f, 0.8f, 120.0f}; }

Mesh ConvexPrism(const std::vector<Eigen::Vector2d>& outline_xy, double z0, double z1) {
  ROMUNECT_CHECK(outline_xy.size() >= 3 && z1 > z0);
  const int n = static_cast<int>(outline_xy.size());
  Mesh mesh;
  for (const auto& p : outline_xy) mesh.vertices.emplace_back(p.x(), p.y(), z0);
  for (const auto& p : outline_xy) mesh.vertices.emplace_back(p.x(), p.y(), z1);
  for (int i = 1; i + 1 < n; ++i) {
    mesh.triangles.emplace_back(0, i + 1, i);          // bottom, facing -z
    mesh.triangles.emplace_back(n, n + i, n + i + 1);  // top, facing +z
  }
  for (int i = 0; i < n; ++i) {
    const int j = (i + 1) % n;
    mesh.triangles.emplace_back(i, j, n + j);
    mesh.triangles.emplace_back(i, n + j, n + i);
  }
  return mesh;
}

Mesh Cylinder(double cx, double cy, double r, double z0, double z1, int segments) {
  return ConvexPrism(RegularPolygon(cx, cy, r, segments), z0, z1);
}

Mesh Box(const Eigen::Vector3d& centre, const Eigen::Vector3d& half_size) {
  return ConvexPrism(Rectangle(centre.x() - half_size.x(), centre.y() - half_size.y(), centre.x() + half_size.x(),
                               centre.y() + half_size.y()),
                     centre.z() - half_size.z(), centre.z() + half_size.z());
}

double MeshVolume(const Mesh& mesh) {
  double six_v = 0.0;
  for (const auto& t : mesh.triangles) {
    six_v += mesh.vertices[t[0]].dot(mesh.vertices[t[1]].cross(mesh.vertices[t[2]]));
  }
  return six_v / 6.0;
}

ObjectSpec MakeObject(ObjectKind kind, uint32_t seed) {
  ObjectSpec spec;
  switch (kind) {
    case ObjectKind::kKey: spec = MakeKey(seed); break;
    case ObjectKind::kPillBox: spec = MakePillBox(seed); break;
    case ObjectKind::kPuzzlePiece: spec = MakePuzzlePiece(seed); break;
    case ObjectKind::kLegoBrick: spec = MakeLegoBrick(seed); break;
    case ObjectKind::kGear: spec = MakeGear(seed); break;
    case ObjectKind::kUserMesh: ROMUNECT_CHECK_MSG(false, "user meshes come from MakeUserMeshObject");
  }
  spec.kind = kind;
  spec.seed = seed;
  return spec;
}

namespace {

// MuJoCo 2.2 reads binary STL only, of 1 to 200,000 faces, and refuses a file shorter than its
// face count says (user_mesh.cc). Checked here, so that the error names the user's file rather
// than the scene MuJoCo composes from it.
constexpr uint64_t kMuJoCoMaxStlFaces = 200000;

void CheckStlAsMuJoCoReadsIt(const std::filesystem::path& file) {
  const std::string source = file.string();
  std::ifstream in(file, std::ios::binary);
  char header[84] = {};
  in.read(header, sizeof(header));
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(file, ec);
  uint32_t faces = 0;
  for (int i = 3; i >= 0; --i) faces = (faces << 8) | static_cast<unsigned char>(header[80 + i]);
  const bool binary_size = !ec && size >= 84 && size - 84 >= 50ull * faces;
  if (std::string(header, 5) == "solid" && !(binary_size && size - 84 == 50ull * faces)) {
    throw InputError(source, "format", "an ASCII STL; MuJoCo reads binary STL only: save the mesh as binary STL");
  }
  if (!binary_size) {
    throw InputError(source, "format",
                     "not a binary STL: " + std::to_string(size) + " bytes, fewer than its header's " +
                         std::to_string(faces) + " faces need (84 + 50 per face)");
  }
  if (faces < 1 || faces > kMuJoCoMaxStlFaces) {
    throw InputError(source, "triangles",
                     std::to_string(faces) + " faces; MuJoCo takes 1 to " + std::to_string(kMuJoCoMaxStlFaces) +
                         " per STL: simplify the mesh");
  }
}

// A closed surface borders each of its edges with exactly two triangles. Vertices are welded by
// position first: an STL repeats them in every face.
void CheckClosedByEdges(const TriangleMesh& mesh, const std::filesystem::path& file) {
  struct Hash {
    size_t operator()(const Eigen::Vector3f& v) const {
      size_t h = 0;
      for (int k = 0; k < 3; ++k) h = h * 1000003u ^ std::hash<float>()(v[k]);
      return h;
    }
  };
  std::unordered_map<Eigen::Vector3f, int, Hash> ids;
  std::vector<int> welded(mesh.vertices_O.size());
  for (size_t i = 0; i < mesh.vertices_O.size(); ++i) {
    welded[i] = ids.emplace(mesh.vertices_O[i], static_cast<int>(ids.size())).first->second;
  }
  std::unordered_map<uint64_t, int> uses;  // undirected edge (low id, high id) -> triangles
  for (const Eigen::Vector3i& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      const int a = welded[t[k]], b = welded[t[(k + 1) % 3]];
      if (a != b) ++uses[(static_cast<uint64_t>(std::min(a, b)) << 32) | static_cast<uint32_t>(std::max(a, b))];
    }
  }
  std::vector<Eigen::Vector3f> positions(ids.size());
  for (const auto& [p, id] : ids) positions[id] = p;
  for (const auto& [edge, count] : uses) {
    if (count == 2) continue;
    const Eigen::Vector3f a = positions[edge >> 32], b = positions[edge & 0xffffffffu];
    std::ostringstream s;
    s << "not closed: the edge from (" << a.x() << ", " << a.y() << ", " << a.z() << ") to (" << b.x() << ", " << b.y()
      << ", " << b.z() << ") m borders " << count << " triangle(s); a closed mesh borders every edge with exactly two";
    throw InputError(file.string(), "triangles", s.str());
  }
}

}  // namespace

ObjectSpec MakeUserMeshObject(const std::filesystem::path& mesh_file, double scale_to_m, const IrMaterial& material,
                              double density_kg_m3) {
  std::string ext = mesh_file.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (ext != ".stl" && ext != ".obj") {
    throw InputError(mesh_file.string(), "extension", "expected a .stl or .obj mesh, got '" + ext + "'");
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(mesh_file, ec)) {
    throw InputError(mesh_file.string(), "", "mesh file not found");
  }
  if (!(scale_to_m > 0.0) || !std::isfinite(scale_to_m)) {
    throw InputError(mesh_file.string(), "scale", "must be a positive finite number");
  }
  // Read here too (MuJoCo reads it again), so a bad file is reported as the file's fault, not the
  // composed scene's: malformed content, a part whose unit is likely wrong, or no volume to give
  // it mass.
  if (ext == ".stl") CheckStlAsMuJoCoReadsIt(mesh_file);
  const TriangleMesh mesh = LoadMesh(mesh_file, scale_to_m);
  Eigen::AlignedBox3d box;
  double six_volume = 0.0;
  for (const Eigen::Vector3i& t : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices_O[t[0]].cast<double>(), b = mesh.vertices_O[t[1]].cast<double>(),
                          c = mesh.vertices_O[t[2]].cast<double>();
    box.extend(a).extend(b).extend(c);
    six_volume += a.dot(b.cross(c));
  }
  const double across_m = box.diagonal().norm();
  if (!(across_m >= 1e-3)) {
    throw InputError(mesh_file.string(), "size",
                     std::to_string(across_m * 1e3) + " mm across at " + std::to_string(scale_to_m) +
                         " m per file unit: below 1 mm; is the unit right?");
  }
  if (!(std::abs(six_volume) / 6.0 > 1e-6 * across_m * across_m * across_m)) {
    throw InputError(mesh_file.string(), "triangles", "the mesh encloses no volume (it must be closed to have a mass)");
  }
  CheckClosedByEdges(mesh, mesh_file);
  ObjectSpec spec;
  spec.kind = ObjectKind::kUserMesh;
  spec.mesh_file = std::filesystem::absolute(mesh_file);
  spec.mesh_scale = scale_to_m;
  spec.material = material;
  spec.density_kg_m3 = density_kg_m3;
  return spec;
}

}  // namespace romunect::sim
