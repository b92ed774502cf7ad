// World's MuJoCo state (private to sim/src): RAII handles for mjModel and mjData, and the ids
// and addresses the sim uses, resolved once by name when the world is loaded.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <mujoco/mujoco.h>

#include "romunect/sim/world.h"

namespace romunect::sim {

struct MjModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
struct MjDataDeleter {
  void operator()(mjData* d) const { mj_deleteData(d); }
};
using MjModelPtr = std::unique_ptr<mjModel, MjModelDeleter>;
using MjDataPtr = std::unique_ptr<mjData, MjDataDeleter>;

// MuJoCo's pose arrays -> Pose. xmat is row-major 3x3 (MuJoCo's layout).
Pose PoseFromMujoco(const mjtNum* xpos, const mjtNum* xmat);

// MuJoCo camera frame M (looks down -z, y up) <-> OpenCV camera frame C (looks down +z,
// y down): a half turn about x. The only place the two meet.
Pose T_M_C();

// The radius about the geom's origin of a mesh geom's compiled vertices (MuJoCo's geom_rbound
// of a mesh is larger: it bounds the mesh's inertia box).
double MeshGeomRadius(const mjModel* m, int geom);

struct ObjectIds {
  int body = -1;
  int qpos_adr = -1;  // 7 numbers: position, w-first quaternion
  int dof_adr = -1;   // 6 numbers
  int weld = -1;      // equality id of the weld "grip_<i>"
  std::vector<int> geoms;
};

struct World::Impl {
  WorldOptions options;
  std::string composed_xml;
  MjModelPtr model;
  MjDataPtr data;
  MjDataPtr scratch;  // kinematics and IK, never stepped

  std::array<int, kArmDof> arm_qpos_adr{};
  std::array<int, kArmDof> arm_dof_adr{};
  std::array<int, kArmDof> arm_actuator{};
  int base_body = -1, hand_body = -1, bin_body = -1, suction_body = -1;
  int camera_site = -1, projector_site = -1, suction_tip_site = -1;
  // The bin's collision aids (world.h, SetSettlingWalls): wall planes, and the bin's boxes
  // with their compiled conaffinity.
  std::vector<int> bin_wall_planes, bin_boxes;
  std::vector<int> bin_wall_plane_contype, bin_wall_plane_conaffinity, bin_box_conaffinity;
  bool settling_walls = false;
  std::vector<int> suction_geoms;
  std::vector<int> suction_contype, suction_conaffinity;  // as compiled (Grip turns them off)
  std::vector<ObjectIds> objects;

  ArmVector qdot_des = ArmVector::Zero();
  ArmVector qddot_des = ArmVector::Zero();
  std::vector<mjtNum> accel_nv, force_nv;  // M * qddot_des over all dofs (the arm's only non-zero)
  bool target_set = false;
  bool frozen = false;
  std::vector<double> frozen_qpos;
  std::optional<int> gripped;

  std::vector<GeomInfo> geoms;  // what Geoms() returns
  std::vector<int> geom_ids;    // MuJoCo id of each entry of geoms

  int SiteOrBody(ArmSite site, bool* is_body) const;
  Pose SitePose(const mjData* d, ArmSite site) const;
  void SetScratchQ(const ArmVector& q) const;
};

}  // namespace romunect::sim
