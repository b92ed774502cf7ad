#include "romunect/sensor/embree/ray_scene.h"

#include <cstdio>
#include <string>

#include "ray_scene_impl.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"

namespace romunect::embree {
namespace {

void ErrorCallback(void* /*user*/, RTCError code, const char* message) {
  std::fprintf(stderr, "embree error %d: %s\n", static_cast<int>(code), message ? message : "");
}

ScenePtr NewScene(RTCDevice device, RTCBuildQuality quality, RTCSceneFlags flags) {
  ScenePtr scene(rtcNewScene(device));
  CheckDevice(device, "rtcNewScene");
  rtcSetSceneBuildQuality(scene.get(), quality);
  rtcSetSceneFlags(scene.get(), flags);
  return scene;
}

// Attaches a triangle geometry holding mesh_O moved by T_S_O into `scene`; returns its id.
unsigned AttachMesh(RTCDevice device, RTCScene scene, const TriangleMesh& mesh_O, const Pose& T_S_O) {
  RTCGeometry geometry = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  CheckDevice(device, "rtcNewGeometry");
  rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
  auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                               3 * sizeof(float), mesh_O.vertices_O.size()));
  auto* indices = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                 3 * sizeof(unsigned), mesh_O.triangles.size()));
  CheckDevice(device, "rtcSetNewGeometryBuffer");
  const bool identity = T_S_O.isApprox(Pose::Identity(), 0.0);
  const Eigen::Isometry3d T = T_S_O;
  for (size_t i = 0; i < mesh_O.vertices_O.size(); ++i) {
    Eigen::Vector3f p = mesh_O.vertices_O[i];
    if (!identity) p = (T * p.cast<double>()).cast<float>();
    vertices[3 * i + 0] = p.x();
    vertices[3 * i + 1] = p.y();
    vertices[3 * i + 2] = p.z();
  }
  for (size_t i = 0; i < mesh_O.triangles.size(); ++i) {
    for (int k = 0; k < 3; ++k) indices[3 * i + k] = static_cast<unsigned>(mesh_O.triangles[i][k]);
  }
  rtcCommitGeometry(geometry);
  const unsigned id = rtcAttachGeometry(scene, geometry);
  rtcReleaseGeometry(geometry);  // the scene holds it now
  CheckDevice(device, "rtcAttachGeometry");
  return id;
}

void SetInstancePose(RTCScene top, unsigned instance_id, const Pose& T_W_O) {
  // Column-major 3 x 4 [R | t], as Embree's RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR wants.
  float xfm[12];
  const Eigen::Matrix<double, 3, 4> m = T_W_O.matrix().topRows<3>();
  for (int c = 0; c < 4; ++c) {
    for (int r = 0; r < 3; ++r) xfm[3 * c + r] = static_cast<float>(m(r, c));
  }
  RTCGeometry instance = rtcGetGeometry(top, instance_id);
  rtcSetGeometryTransform(instance, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, xfm);
  rtcCommitGeometry(instance);
}

unsigned AttachInstance(RTCDevice device, RTCScene top, RTCScene instanced, const Pose& T_W_O) {
  RTCGeometry instance = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
  CheckDevice(device, "rtcNewGeometry(instance)");
  rtcSetGeometryInstancedScene(instance, instanced);
  rtcSetGeometryTimeStepCount(instance, 1);
  const unsigned id = rtcAttachGeometry(top, instance);
  rtcReleaseGeometry(instance);
  SetInstancePose(top, id, T_W_O);
  CheckDevice(device, "instance");
  return id;
}

}  // namespace

void CheckDevice(RTCDevice device, const char* what) {
  const RTCError error = rtcGetDeviceError(device);
  if (error != RTC_ERROR_NONE) {
    std::fprintf(stderr, "embree: %s failed with error %d\n", what, static_cast<int>(error));
    ROMUNECT_CHECK_MSG(error == RTC_ERROR_NONE, what);
  }
}

std::string RaySceneOptions::Problem() const {
  if (build_threads < 0) {
    return "build_threads = " + std::to_string(build_threads) + ": must be >= 0 (0 = all cores)";
  }
  return "";
}

RayScene::RayScene(const RaySceneOptions& options) : impl_(std::make_unique<Impl>()) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  impl_->options = options;
  const std::string config = options.build_threads > 0 ? "threads=" + std::to_string(options.build_threads) : "";
  impl_->device.reset(rtcNewDevice(config.c_str()));
  ROMUNECT_CHECK_MSG(impl_->device != nullptr, "rtcNewDevice failed");
  rtcSetDeviceErrorFunction(impl_->device.get(), ErrorCallback, nullptr);
  RTCDevice device = impl_->device.get();
  // The top level holds a handful of instances and changes every frame: fast build.
  impl_->top = NewScene(device, RTC_BUILD_QUALITY_LOW, RTC_SCENE_FLAG_DYNAMIC);
  impl_->static_part.scene = NewScene(device, RTC_BUILD_QUALITY_HIGH, RTC_SCENE_FLAG_NONE);
}

RayScene::~RayScene() = default;
RayScene::RayScene(RayScene&&) noexcept = default;
RayScene& RayScene::operator=(RayScene&&) noexcept = default;

void RayScene::AddStatic(const TriangleMesh& mesh_O, const Pose& T_W_O, const IrMaterial& material, int object_id) {
  ROMUNECT_CHECK_MSG(mesh_O.Problem().empty(), mesh_O.Problem().c_str());
  Impl& s = *impl_;
  // Static meshes are placed in W once: no per-hit transform for the part rays hit most.
  const unsigned id = AttachMesh(s.device.get(), s.static_part.scene.get(), mesh_O, T_W_O);
  if (s.static_part.geometries.size() <= id) s.static_part.geometries.resize(id + 1);
  s.static_part.geometries[id] = {static_cast<int>(s.materials.size()), object_id};
  s.materials.push_back(material);
  s.stats.static_triangles += mesh_O.triangles.size();
  s.static_dirty = true;
  s.top_dirty = true;
}

int RayScene::AddMoving(const TriangleMesh& mesh_O, const Pose& T_W_O, const IrMaterial& material, int object_id) {
  ROMUNECT_CHECK_MSG(mesh_O.Problem().empty(), mesh_O.Problem().c_str());
  Impl& s = *impl_;
  RTCDevice device = s.device.get();
  Part part;
  part.scene = NewScene(device, RTC_BUILD_QUALITY_HIGH, RTC_SCENE_FLAG_NONE);
  const unsigned id = AttachMesh(device, part.scene.get(), mesh_O, Pose::Identity());
  part.geometries.resize(id + 1);
  part.geometries[id] = {static_cast<int>(s.materials.size()), object_id};
  s.materials.push_back(material);
  rtcCommitScene(part.scene.get());  // built once; only its pose changes later
  CheckDevice(device, "rtcCommitScene(moving part)");
  part.T_W_O = T_W_O;
  for (const Eigen::Vector3f& v : mesh_O.vertices_O) part.bounds_O.extend(v.cast<double>());
  part.instance_id = AttachInstance(device, s.top.get(), part.scene.get(), T_W_O);
  const int index = static_cast<int>(s.moving.size());
  // The top level holds only moving parts, attached in order and never detached: the renderer
  // finds a hit's part by its instance id.
  ROMUNECT_CHECK(part.instance_id == static_cast<unsigned>(index));
  s.moving.push_back(std::move(part));
  s.stats.moving_triangles += mesh_O.triangles.size();
  s.stats.moving_parts = static_cast<int>(s.moving.size());
  s.top_dirty = true;
  return index;
}

void RayScene::SetPose(int moving, const Pose& T_W_O) {
  Impl& s = *impl_;
  ROMUNECT_CHECK(moving >= 0 && moving < static_cast<int>(s.moving.size()));
  Part& part = s.moving[moving];
  part.T_W_O = T_W_O;
  SetInstancePose(s.top.get(), part.instance_id, T_W_O);
  s.top_dirty = true;
}

const Pose& RayScene::pose(int moving) const {
  ROMUNECT_CHECK(moving >= 0 && moving < static_cast<int>(impl_->moving.size()));
  return impl_->moving[moving].T_W_O;
}

int RayScene::moving_count() const { return static_cast<int>(impl_->moving.size()); }

void RayScene::Commit() {
  Impl& s = *impl_;
  const Stopwatch stopwatch;
  if (s.static_dirty) {
    rtcCommitScene(s.static_part.scene.get());
    CheckDevice(s.device.get(), "rtcCommitScene(static)");
    s.static_dirty = false;
    ++s.stats.static_builds;
    s.stats.static_build_s = stopwatch.seconds();
  }
  if (s.top_dirty) {
    rtcCommitScene(s.top.get());
    CheckDevice(s.device.get(), "rtcCommitScene(top)");
    s.top_dirty = false;
  }
  s.stats.last_commit_s = stopwatch.seconds();
}

bool RayScene::committed() const { return !impl_->static_dirty && !impl_->top_dirty; }

const std::vector<IrMaterial>& RayScene::materials() const { return impl_->materials; }

const RaySceneStats& RayScene::stats() const { return impl_->stats; }

}  // namespace romunect::embree
