// The slow, obvious reference for the Embree renderer: Moller-Trumbore against every triangle
// in double precision, with a flag for rays whose answer a float tracer may legitimately
// answer either way (grazing an edge, two surfaces at the same distance).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "romunect/sensor/mesh.h"
#include "romunect/sensor/pose.h"

namespace romunect::testing {

struct WorldTriangle {
  Eigen::Vector3d a, b, c;  // vertices in W
  int object_id = -1;
};

// Appends mesh_O placed at T_W_O to a triangle soup in W.
void AppendWorldTriangles(const TriangleMesh& mesh_O, const Pose& T_W_O, int object_id,
                          std::vector<WorldTriangle>* soup);

struct ReferenceHit {
  bool hit = false;
  double t = 0.0;                                    // along the (unnormalized) direction
  int triangle = -1;                                 // index into the soup
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();  // unit, unoriented
  bool ambiguous = false;                            // an edge within edge_margin or a rival surface within t_margin
};

// Nearest hit with t in (t_min, t_max) over all triangles; skip_triangle is ignored (-1: none).
// A triangle whose barycentric coordinates all lie within edge_margin of [0, 1], or whose hit
// lies within t_margin (relative) of the nearest, makes the answer ambiguous.
ReferenceHit IntersectBruteForce(const std::vector<WorldTriangle>& soup, const Eigen::Vector3d& o,
                                 const Eigen::Vector3d& d, double t_min, double t_max, int skip_triangle = -1,
                                 double edge_margin = 1e-4, double t_margin = 1e-5);

}  // namespace romunect::testing
