#include "brute_force.h"

#include <cmath>
#include <limits>

namespace romunect::testing {

void AppendWorldTriangles(const TriangleMesh& mesh_O, const Pose& T_W_O, int object_id,
                          std::vector<WorldTriangle>* soup) {
  for (const auto& t : mesh_O.triangles) {
    WorldTriangle w;
    w.a = T_W_O * mesh_O.vertices_O[t[0]].cast<double>();
    w.b = T_W_O * mesh_O.vertices_O[t[1]].cast<double>();
    w.c = T_W_O * mesh_O.vertices_O[t[2]].cast<double>();
    w.object_id = object_id;
    soup->push_back(w);
  }
}

ReferenceHit IntersectBruteForce(const std::vector<WorldTriangle>& soup, const Eigen::Vector3d& o,
                                 const Eigen::Vector3d& d, double t_min, double t_max, int skip_triangle,
                                 double edge_margin, double t_margin) {
  ReferenceHit best;
  best.t = std::numeric_limits<double>::infinity();
  std::vector<double> near_edge_t;  // hits of triangles the ray grazes
  std::vector<double> all_t;
  for (size_t i = 0; i < soup.size(); ++i) {
    if (static_cast<int>(i) == skip_triangle) continue;
    const WorldTriangle& tri = soup[i];
    const Eigen::Vector3d e1 = tri.b - tri.a, e2 = tri.c - tri.a;
    const Eigen::Vector3d p = d.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-300) continue;  // parallel
    const Eigen::Vector3d s = o - tri.a;
    const double u = s.dot(p) / det;
    const Eigen::Vector3d q = s.cross(e1);
    const double v = d.dot(q) / det;
    const double t = e2.dot(q) / det;
    if (!(t > t_min && t < t_max)) continue;
    const double w = 1.0 - u - v;
    const double lowest = std::min({u, v, w});
    if (lowest >= -edge_margin && lowest <= edge_margin) near_edge_t.push_back(t);
    if (lowest < 0.0) continue;
    all_t.push_back(t);
    if (t < best.t) {
      best.hit = true;
      best.t = t;
      best.triangle = static_cast<int>(i);
      best.normal = e1.cross(e2).normalized();
    }
  }
  if (!best.hit) {
    // A grazed triangle could be hit by a float tracer.
    best.ambiguous = !near_edge_t.empty();
    return best;
  }
  for (double t : near_edge_t) {
    if (t <= best.t * (1.0 + t_margin)) best.ambiguous = true;
  }
  int rivals = 0;
  for (double t : all_t) {
    if (std::abs(t - best.t) <= best.t * t_margin) ++rivals;
  }
  if (rivals > 1) best.ambiguous = true;
  return best;
}

}  // namespace romunect::testing
