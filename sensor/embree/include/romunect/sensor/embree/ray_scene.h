// The ray-traced world of the Embree back end: triangle meshes (frame O, metres) placed in the
// world W with poses T_W_O, each with an IrMaterial and an object id. The static part (the
// bin) is built once with a high-quality BVH; moving parts are instances of their own BVHs,
// whose poses can be updated every frame at the cost of re-committing the small top level.
// Embree stays inside src/: this header holds no Embree type.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "romunect/sensor/geometry_buffer.h"
#include "romunect/sensor/mesh.h"
#include "romunect/sensor/pose.h"

namespace romunect::embree {

struct RaySceneOptions {
  // Threads Embree may use to build BVHs; 0 = one per core. Rendering threads are separate
  // (RenderOptions::threads).
  int build_threads = 0;

  // Why the options are unusable, or "" (names the field, its value and the rule).
  std::string Problem() const;
};

struct RaySceneStats {
  size_t static_triangles = 0;
  size_t moving_triangles = 0;
  int moving_parts = 0;
  int static_builds = 0;        // how often the static BVH was built (1 in normal use)
  double static_build_s = 0.0;  // wall time of the last static BVH build
  double last_commit_s = 0.0;   // wall time of the last Commit()
};

class GeometryRenderer;

class RayScene {
 public:
  explicit RayScene(const RaySceneOptions& options = {});
  ~RayScene();
  RayScene(RayScene&&) noexcept;
  RayScene& operator=(RayScene&&) noexcept;
  RayScene(const RayScene&) = delete;
  RayScene& operator=(const RayScene&) = delete;

  // Adds a mesh to the static part, placed with T_W_O once and for all. Its BVH is built at
  // the next Commit(); add every static mesh before the first Commit (a later one rebuilds the
  // whole static part). The mesh must be valid (mesh.Problem() == ""; loaders check it).
  void AddStatic(const TriangleMesh& mesh_O, const Pose& T_W_O, const IrMaterial& material, int object_id);

  // Adds a moving part (an instance with its own BVH) at pose T_W_O. Returns its handle for
  // SetPose(). The mesh must be valid.
  int AddMoving(const TriangleMesh& mesh_O, const Pose& T_W_O, const IrMaterial& material, int object_id);

  // Moves a moving part; takes effect at the next Commit(), which is cheap (top level only).
  void SetPose(int moving, const Pose& T_W_O);
  const Pose& pose(int moving) const;
  int moving_count() const;

  // Builds what changed: the static BVH on first use, the top level after pose updates.
  // Rendering needs a committed scene.
  void Commit();
  bool committed() const;

  // One material per added mesh, in the order added; GeometryLayer::material indexes this.
  const std::vector<IrMaterial>& materials() const;
  const RaySceneStats& stats() const;

  struct Impl;  // Embree handles, private to src/

 private:
  friend class GeometryRenderer;
  std::unique_ptr<Impl> impl_;
};

}  // namespace romunect::embree
