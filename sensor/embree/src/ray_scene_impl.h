// Embree handles behind RayScene (private to the Embree back end): RAII owners with
// unique_ptr deleters, and the tables that map an Embree hit (instance id, geometry id) back to
// a material, an object id and the rotation of the hit part.
#pragma once

#include <memory>
#include <vector>

#include <embree3/rtcore.h>
#include <Eigen/Geometry>

#include "romunect/sensor/embree/ray_scene.h"

namespace romunect::embree {

struct DeviceDeleter {
  void operator()(RTCDeviceTy* device) const { rtcReleaseDevice(device); }
};
struct SceneDeleter {
  void operator()(RTCSceneTy* scene) const { rtcReleaseScene(scene); }
};
using DevicePtr = std::unique_ptr<RTCDeviceTy, DeviceDeleter>;
using ScenePtr = std::unique_ptr<RTCSceneTy, SceneDeleter>;

struct GeometryInfo {
  int material = -1;  // index into RayScene::materials()
  int object_id = -1;
};

// The static part (meshes pre-placed in W, traced directly) or a moving part (one mesh in O,
// pose T_W_O, an instance in the top level).
struct Part {
  ScenePtr scene;  // its own BVH
  Pose T_W_O = Pose::Identity();
  std::vector<GeometryInfo> geometries;            // by geometry id within `scene`
  unsigned instance_id = RTC_INVALID_GEOMETRY_ID;  // moving parts: geometry id of the instance in top
  Eigen::AlignedBox3d bounds_O;                    // moving parts: the box of the mesh's vertices in O
};

struct RayScene::Impl {
  RaySceneOptions options;
  DevicePtr device;
  // Instances of the moving parts only: cheap to re-commit when poses change. The static part
  // is not instanced: rays meet it first, directly, and coherent occlusion rays work there.
  ScenePtr top;
  Part static_part;
  std::vector<Part> moving;  // index = the instance's geometry id in top
  std::vector<IrMaterial> materials;
  bool static_dirty = true;
  bool top_dirty = true;
  RaySceneStats stats;
};

// Aborts with Embree's message when the device holds an error (a bug or out of memory).
void CheckDevice(RTCDevice device, const char* what);

}  // namespace romunect::embree
