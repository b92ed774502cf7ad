#include "romunect/sensor/mesh.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <utility>

#include <Eigen/Geometry>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect {
namespace fs = std::filesystem;

namespace {

// (field, problem) of the first thing wrong with a mesh, or empty strings.
std::pair<std::string, std::string> FindProblem(const TriangleMesh& mesh) {
  if (mesh.triangles.empty()) return {"triangles", "the mesh is empty (no triangles)"};
  for (size_t i = 0; i < mesh.vertices_O.size(); ++i) {
    if (!mesh.vertices_O[i].allFinite()) {
      std::ostringstream s;
      s << "vertex (" << mesh.vertices_O[i].transpose() << ") is not finite";
      return {"vertices[" + std::to_string(i) + "]", s.str()};
    }
  }
  const int64_t n = static_cast<int64_t>(mesh.vertices_O.size());
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      const int index = mesh.triangles[i][k];
      if (index < 0 || index >= n) {
        return {"triangles[" + std::to_string(i) + "]",
                "vertex index " + std::to_string(index) + " is outside [0, " + std::to_string(n) + ")"};
      }
    }
  }
  return {"", ""};
}

void AddQuad(TriangleMesh* mesh, const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
             const Eigen::Vector3d& d) {
  const int base = static_cast<int>(mesh->vertices_O.size());
  for (const auto* p : {&a, &b, &c, &d}) mesh->vertices_O.push_back(p->cast<float>());
  mesh->triangles.emplace_back(base, base + 1, base + 2);
  mesh->triangles.emplace_back(base, base + 2, base + 3);
}

// An axis-aligned rectangle in the plane z = z_m, x in [x0, x1], y in [y0, y1].
void AddRectZ(TriangleMesh* mesh, double x0, double x1, double y0, double y1, double z_m) {
  AddQuad(mesh, {x0, y0, z_m}, {x1, y0, z_m}, {x1, y1, z_m}, {x0, y1, z_m});
}

TriangleMesh LoadStl(const fs::path& path, double unit_m) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string(), "", "file not found or not readable");
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  TriangleMesh mesh;
  // Binary when the size matches the triangle count in the header (ascii files may also start
  // with "solid", binary ones sometimes do too).
  if (bytes.size() >= 84) {
    uint32_t count = 0;
    std::memcpy(&count, bytes.data() + 80, 4);
    if (bytes.size() == 84 + 50ull * count) {
      mesh.vertices_O.reserve(3ull * count);
      mesh.triangles.reserve(count);
      for (uint32_t t = 0; t < count; ++t) {
        const char* record = bytes.data() + 84 + 50ull * t;
        for (int k = 0; k < 3; ++k) {
          float xyz[3];
          std::memcpy(xyz, record + 12 + 12 * k, 12);
          mesh.vertices_O.emplace_back(static_cast<float>(xyz[0] * unit_m), static_cast<float>(xyz[1] * unit_m),
                                       static_cast<float>(xyz[2] * unit_m));
        }
        const int base = static_cast<int>(3 * t);
        mesh.triangles.emplace_back(base, base + 1, base + 2);
      }
      return mesh;
    }
  }
  std::istringstream text(bytes);
  std::string word;
  if (!(text >> word) || word != "solid") {
    throw InputError(path.string(), "",
                     "neither a binary STL (size does not match the "
                     "triangle count) nor an ascii STL (no 'solid')");
  }
  std::string line;
  int line_number = 1;
  std::getline(text, line);
  int in_facet = 0;
  while (std::getline(text, line)) {
    ++line_number;
    std::istringstream tokens(line);
    if (!(tokens >> word)) continue;
    if (word == "vertex") {
      double x, y, z;
      std::string sx, sy, sz;
      if (!(tokens >> sx >> sy >> sz)) {
        throw InputError(path.string(), "line " + std::to_string(line_number), "expected 'vertex x y z'");
      }
      try {  // std::stod, unlike operator>>, reads "nan" and "inf": validation reports them
        x = std::stod(sx), y = std::stod(sy), z = std::stod(sz);
      } catch (const std::exception&) {
        throw InputError(path.string(), "line " + std::to_string(line_number), "vertex coordinates are not numbers");
      }
      mesh.vertices_O.emplace_back(static_cast<float>(x * unit_m), static_cast<float>(y * unit_m),
                                   static_cast<float>(z * unit_m));
      ++in_facet;
    } else if (word == "endfacet") {
      if (in_facet != 3) {
        throw InputError(path.string(), "line " + std::to_string(line_number),
                         "a facet has " + std::to_string(in_facet) + " vertices, expected 3");
      }
      const int base = static_cast<int>(mesh.vertices_O.size()) - 3;
      mesh.triangles.emplace_back(base, base + 1, base + 2);
      in_facet = 0;
    }
  }
  if (in_facet != 0) throw InputError(path.string(), "", "truncated: last facet is not closed");
  return mesh;
}

TriangleMesh LoadObj(const fs::path& path, double unit_m) {
  std::ifstream in(path);
  if (!in) throw InputError(path.string(), "", "file not found or not readable");
  TriangleMesh mesh;
  std::string line, word;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    std::istringstream tokens(line);
    if (!(tokens >> word)) continue;
    const std::string where = "line " + std::to_string(line_number);
    if (word == "v") {
      double x, y, z;
      std::string sx, sy, sz;
      if (!(tokens >> sx >> sy >> sz)) throw InputError(path.string(), where, "expected 'v x y z'");
      try {
        x = std::stod(sx), y = std::stod(sy), z = std::stod(sz);
      } catch (const std::exception&) {
        throw InputError(path.string(), where, "vertex coordinates are not numbers");
      }
      mesh.vertices_O.emplace_back(static_cast<float>(x * unit_m), static_cast<float>(y * unit_m),
                                   static_cast<float>(z * unit_m));
    } else if (word == "f") {
      std::vector<int> face;
      std::string corner;
      const int n = static_cast<int>(mesh.vertices_O.size());
      while (tokens >> corner) {
        int index = 0;
        try {
          index = std::stoi(corner.substr(0, corner.find('/')));
        } catch (const std::exception&) {
          throw InputError(path.string(), where, "face index '" + corner + "' is not a number");
        }
        // OBJ counts from 1; negative indices count back from the latest vertex.
        const int zero_based = index > 0 ? index - 1 : n + index;
        if (index == 0 || zero_based < 0 || zero_based >= n) {
          throw InputError(path.string(), where,
                           "face index " + std::to_string(index) + " refers to no vertex (" + std::to_string(n) +
                               " defined so far)");
        }
        face.push_back(zero_based);
      }
      if (face.size() < 3) throw InputError(path.string(), where, "a face needs 3 or more vertices");
      for (size_t k = 1; k + 1 < face.size(); ++k) {
        mesh.triangles.emplace_back(face[0], face[k], face[k + 1]);
      }
    }
  }
  return mesh;
}

}  // namespace

std::string TriangleMesh::Problem() const {
  const auto [field, problem] = FindProblem(*this);
  return field.empty() ? "" : field + ": " + problem;
}

void TriangleMesh::Append(const TriangleMesh& other, const Pose& T_this_other) {
  const int base = static_cast<int>(vertices_O.size());
  const Eigen::Isometry3f T = T_this_other.cast<float>();
  vertices_O.reserve(vertices_O.size() + other.vertices_O.size());
  for (const auto& p : other.vertices_O) vertices_O.push_back(T * p);
  triangles.reserve(triangles.size() + other.triangles.size());
  for (const auto& t : other.triangles) triangles.push_back(t + Eigen::Vector3i::Constant(base));
}

void ValidateMesh(const TriangleMesh& mesh, const std::string& source) {
  const auto [field, problem] = FindProblem(mesh);
  if (!field.empty()) throw InputError(source, field, problem);
}

TriangleMesh LoadMesh(const fs::path& path, double unit_m) {
  if (!(unit_m > 0.0) || !std::isfinite(unit_m)) {
    throw InputError(path.string(), "unit_m", "must be a positive number, got " + std::to_string(unit_m));
  }
  std::string extension = path.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  TriangleMesh mesh;
  if (extension == ".stl") {
    mesh = LoadStl(path, unit_m);
  } else if (extension == ".obj") {
    mesh = LoadObj(path, unit_m);
  } else {
    throw InputError(path.string(), "", "unknown mesh format '" + extension + "' (expected .stl or .obj)");
  }
  ValidateMesh(mesh, path.string());
  return mesh;
}

void SaveStl(const fs::path& path, const TriangleMesh& mesh) {
  ROMUNECT_CHECK_MSG(mesh.Problem().empty(), mesh.Problem().c_str());
  WriteAtomically(path, [&](const fs::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    char header[80] = "romunect binary STL, metres";
    out.write(header, 80);
    const uint32_t count = static_cast<uint32_t>(mesh.triangles.size());
    out.write(reinterpret_cast<const char*>(&count), 4);
    for (const auto& t : mesh.triangles) {
      const Eigen::Vector3f& a = mesh.vertices_O[t[0]];
      const Eigen::Vector3f& b = mesh.vertices_O[t[1]];
      const Eigen::Vector3f& c = mesh.vertices_O[t[2]];
      const Eigen::Vector3f n = (b - a).cross(c - a).normalized();
      float record[12] = {n.x(), n.y(), n.z(), a.x(), a.y(), a.z(), b.x(), b.y(), b.z(), c.x(), c.y(), c.z()};
      out.write(reinterpret_cast<const char*>(record), sizeof(record));
      const uint16_t attributes = 0;
      out.write(reinterpret_cast<const char*>(&attributes), 2);
    }
    out.close();
    if (!out) throw InputError(path.string(), "", "cannot write file");
  });
}

TriangleMesh MakePlaneTarget(double distance_m, double size_m) {
  TriangleMesh mesh;
  const double h = 0.5 * size_m;
  AddRectZ(&mesh, -h, h, -h, h, distance_m);
  return mesh;
}

TriangleMesh MakeTiltedPlaneTarget(double distance_m, double size_m, double tilt_rad) {
  TriangleMesh plane = MakePlaneTarget(0.0, size_m);
  // Rotating about y by -tilt maps (x, 0, 0) to (x cos, 0, x sin): z = x tan(tilt) in-plane.
  const Pose T = MakePose(Eigen::AngleAxisd(-tilt_rad, Eigen::Vector3d::UnitY()).toRotationMatrix(),
                          Eigen::Vector3d(0, 0, distance_m));
  TriangleMesh mesh;
  mesh.Append(plane, T);
  return mesh;
}

TriangleMesh MakeStepTarget(double distance_m, double step_m, double size_m) {
  TriangleMesh mesh;
  const double h = 0.5 * size_m;
  AddRectZ(&mesh, -h, 0.0, -h, h, distance_m - step_m);
  AddRectZ(&mesh, 0.0, h, -h, h, distance_m);
  AddQuad(&mesh, {0, -h, distance_m - step_m}, {0, h, distance_m - step_m}, {0, h, distance_m}, {0, -h, distance_m});
  return mesh;
}

TriangleMesh MakeBoxOnPlaneTarget(double distance_m, double size_m, double box_size_m, double box_height_m) {
  TriangleMesh mesh = MakePlaneTarget(distance_m, size_m);
  const double b = 0.5 * box_size_m;
  const double z0 = distance_m, z1 = distance_m - box_height_m;
  AddRectZ(&mesh, -b, b, -b, b, z1);  // top
  AddQuad(&mesh, {-b, -b, z1}, {b, -b, z1}, {b, -b, z0}, {-b, -b, z0});
  AddQuad(&mesh, {-b, b, z1}, {b, b, z1}, {b, b, z0}, {-b, b, z0});
  AddQuad(&mesh, {-b, -b, z1}, {-b, b, z1}, {-b, b, z0}, {-b, -b, z0});
  AddQuad(&mesh, {b, -b, z1}, {b, b, z1}, {b, b, z0}, {b, -b, z0});
  return mesh;
}

TriangleMesh MakeIcosphere(const Eigen::Vector3d& centre_O, double radius_m, int subdivisions) {
  ROMUNECT_CHECK(subdivisions >= 0 && subdivisions <= 8 && radius_m > 0.0);
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                                    {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<Eigen::Vector3i> f = {{0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                    {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                                    {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int level = 0; level < subdivisions; ++level) {
    std::map<std::pair<int, int>, int> midpoints;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      const auto it = midpoints.find(key);
      if (it != midpoints.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      const int index = static_cast<int>(v.size()) - 1;
      midpoints.emplace(key, index);
      return index;
    };
    std::vector<Eigen::Vector3i> next;
    next.reserve(4 * f.size());
    for (const auto& tri : f) {
      const int ab = midpoint(tri[0], tri[1]), bc = midpoint(tri[1], tri[2]), ca = midpoint(tri[2], tri[0]);
      next.emplace_back(tri[0], ab, ca);
      next.emplace_back(tri[1], bc, ab);
      next.emplace_back(tri[2], ca, bc);
      next.emplace_back(ab, bc, ca);
    }
    f = std::move(next);
  }
  TriangleMesh mesh;
  mesh.vertices_O.reserve(v.size());
  for (const auto& p : v) mesh.vertices_O.push_back((centre_O + radius_m * p).cast<float>());
  mesh.triangles = std::move(f);
  return mesh;
}

TriangleMesh MakeSphereTarget(double distance_m, double radius_m, int subdivisions) {
  return MakeIcosphere(Eigen::Vector3d(0, 0, distance_m + radius_m), radius_m, subdivisions);
}

std::vector<std::string> BuiltinTargetNames() { return {"plane", "tilted-plane", "step", "box", "sphere"}; }

TriangleMesh MakeBuiltinTarget(const std::string& name, double distance_m, double size_m, const std::string& source) {
  if (!(distance_m > 0.0) || !(size_m > 0.0)) {
    throw InputError(source, "distance/size",
                     "must be positive, got distance " + std::to_string(distance_m) + " m, size " +
                         std::to_string(size_m) + " m");
  }
  if (name == "plane") return MakePlaneTarget(distance_m, size_m);
  if (name == "tilted-plane") return MakeTiltedPlaneTarget(distance_m, size_m, M_PI / 6.0);
  if (name == "step") {
    // Near half on +x, the side of both presets' projectors, so its shadow shows.
    TriangleMesh step;
    step.Append(MakeStepTarget(distance_m, 0.1 * size_m, size_m),
                MakePose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitZ()).toRotationMatrix(),
                         Eigen::Vector3d::Zero()));
    return step;
  }
  if (name == "box") return MakeBoxOnPlaneTarget(distance_m, size_m, size_m / 3.0, 0.1 * size_m);
  if (name == "sphere") return MakeSphereTarget(distance_m, 0.25 * size_m, 5);
  std::string names;
  for (const auto& n : BuiltinTargetNames()) names += (names.empty() ? "" : ", ") + n;
  throw InputError(source, "target", "unknown target '" + name + "' (expected one of " + names + ")");
}

std::string BinSceneOptions::Problem() const {
  auto positive = [](const char* field, double value) -> std::string {
    if (value > 0.0 && std::isfinite(value)) return "";
    return std::string(field) + " = " + std::to_string(value) + ": must be positive";
  };
  for (const auto& p : {positive("distance_m", distance_m), positive("inner_width_m", inner_width_m),
                        positive("inner_height_m", inner_height_m), positive("wall_height_m", wall_height_m),
                        positive("min_object_radius_m", min_object_radius_m)}) {
    if (!p.empty()) return p;
  }
  if (!(max_object_radius_m >= min_object_radius_m)) {
    return "max_object_radius_m = " + std::to_string(max_object_radius_m) + ": must be >= min_object_radius_m";
  }
  if (2.0 * max_object_radius_m >= std::min(inner_width_m, inner_height_m)) {
    return "max_object_radius_m = " + std::to_string(max_object_radius_m) + ": objects must fit in the bin";
  }
  if (object_subdivisions < 0 || object_subdivisions > 6) {
    return "object_subdivisions = " + std::to_string(object_subdivisions) + ": must be in [0, 6]";
  }
  if (triangle_count < 0) return "triangle_count = " + std::to_string(triangle_count) + ": must be >= 0";
  return "";
}

TriangleMesh MakeBinScene(const BinSceneOptions& o) {
  ROMUNECT_CHECK_MSG(o.Problem().empty(), o.Problem().c_str());
  TriangleMesh mesh;
  const double w = 0.5 * o.inner_width_m, h = 0.5 * o.inner_height_m;
  const double z_floor = o.distance_m, z_rim = o.distance_m - o.wall_height_m;
  const double rim = 0.01;  // the rim around the walls, so the camera sees a frame
  AddRectZ(&mesh, -w, w, -h, h, z_floor);
  AddQuad(&mesh, {-w, -h, z_rim}, {w, -h, z_rim}, {w, -h, z_floor}, {-w, -h, z_floor});
  AddQuad(&mesh, {-w, h, z_rim}, {w, h, z_rim}, {w, h, z_floor}, {-w, h, z_floor});
  AddQuad(&mesh, {-w, -h, z_rim}, {-w, h, z_rim}, {-w, h, z_floor}, {-w, -h, z_floor});
  AddQuad(&mesh, {w, -h, z_rim}, {w, h, z_rim}, {w, h, z_floor}, {w, -h, z_floor});
  AddRectZ(&mesh, -w - rim, w + rim, -h - rim, -h, z_rim);
  AddRectZ(&mesh, -w - rim, w + rim, h, h + rim, z_rim);
  AddRectZ(&mesh, -w - rim, -w, -h, h, z_rim);
  AddRectZ(&mesh, w, w + rim, -h, h, z_rim);

  // Ellipsoids (icospheres of object_subdivisions), piled in layers from the floor: each
  // rests at a random x-y, on top of whatever it overlaps (a bounding-sphere pile).
  const TriangleMesh unit = MakeIcosphere(Eigen::Vector3d::Zero(), 1.0, o.object_subdivisions);
  const int count = std::max(0, (o.triangle_count - static_cast<int>(mesh.triangles.size())) /
                                    static_cast<int>(unit.triangles.size()));
  std::mt19937 rng(o.seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  struct Placed {
    Eigen::Vector3d centre;
    double radius;
  };
  std::vector<Placed> placed;
  for (int i = 0; i < count; ++i) {
    const Eigen::Vector3d axes(o.min_object_radius_m + uniform(rng) * (o.max_object_radius_m - o.min_object_radius_m),
                               o.min_object_radius_m + uniform(rng) * (o.max_object_radius_m - o.min_object_radius_m),
                               o.min_object_radius_m + uniform(rng) * (o.max_object_radius_m - o.min_object_radius_m));
    const double radius = axes.maxCoeff();
    const Eigen::Quaterniond q =
        Eigen::Quaterniond(uniform(rng) - 0.5, uniform(rng) - 0.5, uniform(rng) - 0.5, uniform(rng) - 0.5).normalized();
    const double x = -w + radius + uniform(rng) * (2.0 * (w - radius));
    const double y = -h + radius + uniform(rng) * (2.0 * (h - radius));
    // Rest on the floor or on the highest (smallest z) sphere below, touching it.
    double z = z_floor - radius;
    for (const Placed& p : placed) {
      const double dx = x - p.centre.x(), dy = y - p.centre.y(), r = radius + p.radius;
      const double d2 = dx * dx + dy * dy;
      if (d2 < r * r) z = std::min(z, p.centre.z() - std::sqrt(r * r - d2));
    }
    placed.push_back({Eigen::Vector3d(x, y, z), radius});
    TriangleMesh object = unit;
    for (auto& v : object.vertices_O) v = (v.cast<double>().cwiseProduct(axes)).cast<float>();
    mesh.Append(object, MakePose(q.toRotationMatrix(), Eigen::Vector3d(x, y, z)));
  }
  return mesh;
}

}  // namespace romunect
