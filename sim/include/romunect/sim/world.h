// The simulated world: a MuJoCo scene (the arm, the bin, the table) plus the pile's objects,
// behind an interface that uses only Eigen, OpenCV core and romunect types (MuJoCo stays in
// sim/src). Frames (frames.h): W world (z up), B robot base (body "base"), H hand (body
// "hand"), C camera (site "camera", OpenCV axes), P projector (site "projector"), O object
// (body "obj_<i>"), and the bin frame (body "bin": centre of the inner floor, z up).
// MuJoCo's camera frame M is converted in src/ and never appears here.
//
// A World is not thread-safe: one thread drives it (physics, kinematics and IK share buffers).
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "romunect/sensor/geometry_buffer.h"
#include "romunect/sensor/pose.h"
#include "romunect/sim/objects.h"

namespace romunect::sim {

// scenes/default/scene.xml of this source tree (the built-in default scene).
std::filesystem::path DefaultSceneFile();
// The folder that holds the project's scenes (scenes/).
std::filesystem::path ScenesDir();

struct WorldOptions {
  // An MJCF file (MuJoCo 2.2) that includes the romunect arm (bodies "base", "hand",
  // "suction", joints "j1".."j6", sites "camera", "projector", "suction_tip") and a body
  // "bin". Empty: DefaultSceneFile().
  std::filesystem::path scene_file;
  // Added to the scene as free bodies "obj_0", "obj_1", ... (initially parked above the bin).
  std::vector<ObjectSpec> objects;
  // The rig: camera in the hand frame and projector in the camera frame. When set, they
  // replace the scene's "camera" and "projector" sites. Must fit on the hand: both within
  // kMaxRigOffsetM of the flange.
  std::optional<Pose> T_H_C;
  std::optional<Pose> T_C_P;

  static constexpr double kMaxRigOffsetM = 0.25;
};

enum class ArmSite { kHand, kCamera, kProjector, kSuctionTip };

// One geom of the world, as a renderer needs it: triangles in the geom's frame G.
struct GeomInfo {
  std::string name;    // MuJoCo name, or "geom_<id>" when it has none
  bool moving = true;  // false: fixed to the world, so a renderer builds it once
  int object = -1;     // index into WorldOptions::objects; -1 for arm, bin, table
  bool arm = false;    // part of the arm (its body descends from "base")
  Mesh mesh_G;
  IrMaterial material;  // from the geom's MuJoCo material (rgba, specular, shininess)
};

class World {
 public:
  static constexpr int kArmDof = 6;
  using ArmVector = Eigen::Matrix<double, kArmDof, 1>;
  using Jacobian = Eigen::Matrix<double, 6, kArmDof>;  // rows: linear (3), angular (3), in W

  // Loads the scene and adds the objects. Throws InputError naming the file on invalid MJCF,
  // a missing mesh, a missing bin or arm part, a rig that does not fit on the hand, or a user
  // mesh wider than the bin's inner diagonal.
  explicit World(const WorldOptions& options);
  ~World();
  World(World&&) noexcept;
  World& operator=(World&&) noexcept;

  const WorldOptions& options() const;
  // The MJCF text that was compiled (the scene file plus the generated objects).
  const std::string& composed_xml() const;

  double time_s() const;
  double timestep_s() const;
  int num_objects() const;

  Pose T_W_B() const;    // robot base in the world
  Pose T_W_Bin() const;  // bin frame: centre of the bin's inner floor, z up
  // Inner size of the bin (x, y, z), m, measured from its geoms' bounding box.
  Eigen::Vector3d bin_inner_size_m() const;

  // --- Arm state (the executed state of the simulation) ---
  ArmVector arm_q() const;
  ArmVector arm_qdot() const;
  ArmVector arm_lower_rad() const;
  ArmVector arm_upper_rad() const;
  // Places the arm at q at rest (no dynamics), with its actuators holding q.
  void SetArmQ(const ArmVector& q);
  Pose SitePose_W(ArmSite site) const;
  Pose T_B_H() const;
  Pose T_W_C() const { return SitePose_W(ArmSite::kCamera); }
  Pose T_W_P() const { return SitePose_W(ArmSite::kProjector); }
  Pose T_H_C() const;  // the rig in use
  Pose T_C_P() const;

  // --- Kinematics at a given q (the simulation state is untouched) ---
  Pose ForwardKinematics(const ArmVector& q, ArmSite site) const;
  // The site's Jacobian at q, in W: d(p_W)/dq over d(omega_W)/dq.
  Jacobian SiteJacobian(const ArmVector& q, ArmSite site) const;

  // --- Control and physics ---
  // Position targets for the arm's actuators, with gravity compensation and a feed-forward of
  // the joint damping at qdot_des and of the arm's inertia at qddot_des (so tracking at speed
  // and through a path's corners does not lag), as a robot's own trajectory controller adds.
  void SetArmTarget(const ArmVector& q_des, const ArmVector& qdot_des,
                    const ArmVector& qddot_des = ArmVector::Zero());
  // Advances the physics by n time steps; poses are up to date afterwards.
  void Step(int n = 1);
  // While frozen the pile does not move and no contacts are computed (kinematic scanning);
  // unfreezing restores contacts and lets the objects move from where they were.
  void SetPileFrozen(bool frozen);
  bool pile_frozen() const;
  // Objects collide with the bin's walls either through its box geoms (the default: what is
  // seen), or, while a pile settles, through infinite planes on the walls' inner faces (the
  // bin's horizontal-normal plane geoms), because MuJoCo 2.2's convex collision gives wrong
  // depths between large thin boxes and centimetre meshes and throws parts out. The planes
  // would push anything outside the bin, so they are on only while settling.
  void SetSettlingWalls(bool on);

  // --- Objects ---
  Pose T_W_O(int object) const;
  void SetObjectPose(int object, const Pose& T_W_O);  // at rest
  // Kinetic energy of all objects, joules.
  double ObjectKineticEnergyJ() const;
  // Generalized positions of all objects (7 per object: position, w-first quaternion), for
  // saving and restoring a pile exactly.
  std::vector<double> ObjectQpos() const;
  void SetObjectQpos(const std::vector<double>& qpos);  // objects at rest

  // --- Suction gripper ---
  // The object the suction cup touches (or is within `max_distance_m` of), if any.
  std::optional<int> SuctionContact(double max_distance_m = 0.001) const;
  // Welds the object to the suction cup where it is now; Release() lets it go.
  void Grip(int object);
  void Release();
  std::optional<int> gripped() const;

  // --- Geometry for renderers ---
  // Every visible geom (alpha > 0), in MuJoCo geom order; built once per World.
  const std::vector<GeomInfo>& Geoms() const;
  // Current pose of each geom of Geoms(), same order: *T_W_G is resized.
  void GeomPoses(std::vector<Pose>* T_W_G) const;

  struct Impl;
  Impl& impl() { return *impl_; }
  const Impl& impl() const { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace romunect::sim
