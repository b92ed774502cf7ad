#include "tessellate.h"

#include <cmath>

namespace romunect::sim {
namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr int kSegments = 48;
// A plane of size 0 is infinite in MuJoCo; drawn as this half size (m), far beyond any view.
constexpr double kInfinitePlaneHalfSizeM = 5.0;
}  // namespace

Mesh RoundedMesh(double r, double half_length, const Eigen::Vector3d& scale, int segments) {
  Mesh mesh;
  const int rings = segments / 2;  // latitude rings from pole to pole, the equator doubled
  // Rings 0..rings/2 belong to the top hemisphere, the rest to the bottom one.
  std::vector<std::pair<double, double>> lat;  // (polar angle, z offset)
  for (int i = 0; i <= rings / 2; ++i) lat.emplace_back(kPi * i / rings, half_length);
  for (int i = rings / 2; i <= rings; ++i) lat.emplace_back(kPi * i / rings, -half_length);
  mesh.vertices.emplace_back(0, 0, (r + half_length) * scale.z());
  for (size_t i = 1; i + 1 < lat.size(); ++i) {
    const double theta = lat[i].first, z = r * std::cos(theta) + lat[i].second;
    for (int k = 0; k < segments; ++k) {
      const double phi = 2.0 * kPi * k / segments;
      mesh.vertices.emplace_back(r * std::sin(theta) * std::cos(phi) * scale.x(),
                                 r * std::sin(theta) * std::sin(phi) * scale.y(), z * scale.z());
    }
  }
  mesh.vertices.emplace_back(0, 0, -(r + half_length) * scale.z());
  const int inner_rings = static_cast<int>(lat.size()) - 2;
  const int bottom = static_cast<int>(mesh.vertices.size()) - 1;
  for (int k = 0; k < segments; ++k) {
    const int k1 = (k + 1) % segments;
    mesh.triangles.emplace_back(0, 1 + k, 1 + k1);
    const int last = 1 + (inner_rings - 1) * segments;
    mesh.triangles.emplace_back(bottom, last + k1, last + k);
  }
  for (int i = 0; i + 1 < inner_rings; ++i) {
    for (int k = 0; k < segments; ++k) {
      const int k1 = (k + 1) % segments;
      const int a = 1 + i * segments + k, b = 1 + i * segments + k1;
      const int c = 1 + (i + 1) * segments + k, e = 1 + (i + 1) * segments + k1;
      mesh.triangles.emplace_back(a, c, e);
      mesh.triangles.emplace_back(a, e, b);
    }
  }
  return mesh;
}

Mesh TessellateGeom(const mjModel* m, int g) {
  const mjtNum* size = m->geom_size + 3 * g;
  switch (m->geom_type[g]) {
    case mjGEOM_MESH: {
      Mesh mesh;
      const int id = m->geom_dataid[g];
      const float* v = m->mesh_vert + 3 * m->mesh_vertadr[id];
      for (int i = 0; i < m->mesh_vertnum[id]; ++i) mesh.vertices.emplace_back(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
      const int* f = m->mesh_face + 3 * m->mesh_faceadr[id];
      for (int i = 0; i < m->mesh_facenum[id]; ++i) mesh.triangles.emplace_back(f[3 * i], f[3 * i + 1], f[3 * i + 2]);
      return mesh;
    }
    case mjGEOM_BOX: return Box(Eigen::Vector3d::Zero(), Eigen::Vector3d(size[0], size[1], size[2]));
    case mjGEOM_CYLINDER: return Cylinder(0, 0, size[0], -size[1], size[1], kSegments);
    case mjGEOM_SPHERE: return RoundedMesh(size[0], 0.0, Eigen::Vector3d::Ones(), kSegments);
    case mjGEOM_CAPSULE: return RoundedMesh(size[0], size[1], Eigen::Vector3d::Ones(), kSegments);
    case mjGEOM_ELLIPSOID: return RoundedMesh(1.0, 0.0, Eigen::Vector3d(size[0], size[1], size[2]), kSegments);
    case mjGEOM_PLANE: {
      const double hx = size[0] > 0 ? size[0] : kInfinitePlaneHalfSizeM;
      const double hy = size[1] > 0 ? size[1] : kInfinitePlaneHalfSizeM;
      Mesh mesh;
      mesh.vertices = {{-hx, -hy, 0}, {hx, -hy, 0}, {hx, hy, 0}, {-hx, hy, 0}};
      mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
      return mesh;
    }
    default: return Mesh{};
  }
}

}  // namespace romunect::sim
