// Triangle meshes of MuJoCo geoms, in the geom's frame G, for the renderer (private to sim).
#pragma once

#include <mujoco/mujoco.h>

#include "romunect/sim/objects.h"

namespace romunect::sim {

// Meshes as compiled (MuJoCo's mesh frame is the geom frame); primitives tessellated finely
// enough for 0.1 mm work on objects of centimetres (sphere/capsule/cylinder: 48 segments).
// Height fields and unknown types give an empty mesh.
Mesh TessellateGeom(const mjModel* m, int geom);

// A UV sphere of radius r whose two hemispheres are pulled apart by +-half_length along z
// (half_length 0: a sphere; > 0: a capsule), scaled per axis by `scale`.
Mesh RoundedMesh(double r, double half_length, const Eigen::Vector3d& scale, int segments);

}  // namespace romunect::sim
