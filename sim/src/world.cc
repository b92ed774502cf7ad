#include "romunect/sim/world.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frames.h"
#include "tessellate.h"
#include "world_impl.h"

#ifndef ROMUNECT_SCENES_DIR
#error "ROMUNECT_SCENES_DIR must name the project's scenes folder"
#endif

namespace romunect::sim {
namespace {

constexpr const char* kArmJoints[World::kArmDof] = {"j1", "j2", "j3", "j4", "j5", "j6"};
constexpr const char* kArmActuators[World::kArmDof] = {"a1", "a2", "a3", "a4", "a5", "a6"};
// Objects wait in a column above the bin until a pile drops them: this far above its floor,
// this far apart.
constexpr double kParkHeightM = 0.08;
constexpr double kParkSpacingM = 0.04;

std::string ReadFileText(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string(), "", "cannot open the scene file");
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

std::string Num(double v) {
  char s[40];
  std::snprintf(s, sizeof s, "%.9g", v);
  return s;
}

// The MJCF for the objects: a material, meshes and a free body with one geom per convex part,
// and an inactive weld to the suction cup, for each object.
// A value for a double-quoted XML attribute: a user's path may hold the markup characters.
std::string XmlAttribute(const std::string& value) {
  std::string out;
  for (const char c : value) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string ObjectsXml(const std::vector<ObjectSpec>& objects) {
  std::string assets, bodies, welds;
  for (size_t i = 0; i < objects.size(); ++i) {
    const ObjectSpec& o = objects[i];
    const std::string name = "obj_" + std::to_string(i);
    const IrMaterial& mat = o.material;
    // MuJoCo's shininess is in [0, 1] and scales OpenGL's exponent by 128 (mjvisualize).
    assets += "<material name=\"" + name + "_mat\" rgba=\"" + Num(mat.albedo) + " " + Num(mat.albedo) + " " +
              Num(mat.albedo) + " 1\" specular=\"" + Num(mat.specular) + "\" shininess=\"" +
              Num(std::min(1.0, mat.shininess / 128.0)) + "\"/>\n";
    bodies += "<body name=\"" + name + "\" pos=\"0 0 " + Num(1.0 + 0.1 * i) + "\">\n<freejoint name=\"" + name +
              "_joint\"/>\n";
    // Small objects: torsional friction keeps a settled pile still, and stiff contacts
    // (time constant 2 ms, two steps of the pile's settle) keep millimetre parts from sinking
    // into each other.
    const std::string geom_attrs = "\" material=\"" + name + "_mat\" density=\"" + Num(o.density_kg_m3) +
                                   "\" contype=\"1\" conaffinity=\"3\" condim=\"4\" friction=\"0.8 0.005 0.0001\"" +
                                   " solref=\"0.002 1\"/>\n";
    if (o.kind == ObjectKind::kUserMesh) {
      const std::string s = Num(o.mesh_scale);
      assets += "<mesh name=\"" + name + "_p0\" file=\"" + XmlAttribute(o.mesh_file.string()) + "\" scale=\"" + s +
                " " + s + " " + s + "\"/>\n";
      bodies += "<geom name=\"" + name + "_p0\" type=\"mesh\" mesh=\"" + name + "_p0" + geom_attrs;
    } else {
      auto add_mesh = [&](const std::string& mesh_name, const Mesh& mesh) {
        std::string vertex, face;
        for (const auto& v : mesh.vertices) vertex += Num(v.x()) + " " + Num(v.y()) + " " + Num(v.z()) + " ";
        for (const auto& t : mesh.triangles) {
          face += std::to_string(t[0]) + " " + std::to_string(t[1]) + " " + std::to_string(t[2]) + " ";
        }
        assets += "<mesh name=\"" + mesh_name + "\" vertex=\"" + vertex + "\" face=\"" + face + "\"/>\n";
      };
      // With separate render geometry, the collision parts are invisible (alpha 0, no
      // material) and the render parts massless and contact-free.
      const bool separate = !o.visual_O.empty();
      for (size_t p = 0; p < o.parts_O.size(); ++p) {
        const std::string part = name + "_p" + std::to_string(p);
        add_mesh(part, o.parts_O[p]);
        bodies += "<geom name=\"" + part + "\" type=\"mesh\" mesh=\"" + part +
                  (separate ? "\" rgba=\"0 0 0 0\" group=\"3\" density=\"" + Num(o.density_kg_m3) +
                                  "\" contype=\"1\" conaffinity=\"3\" condim=\"4\" friction=\"0.8 0.005 0.0001\"" +
                                  " solref=\"0.002 1\"/>\n"
                            : geom_attrs);
      }
      for (size_t p = 0; p < o.visual_O.size(); ++p) {
        const std::string part = name + "_v" + std::to_string(p);
        add_mesh(part, o.visual_O[p]);
        bodies += "<geom name=\"" + part + "\" type=\"mesh\" mesh=\"" + part + "\" material=\"" + name +
                  "_mat\" contype=\"0\" conaffinity=\"0\" mass=\"0\"/>\n";
      }
    }
    bodies += "</body>\n";
    welds += "<weld name=\"grip_" + std::to_string(i) + "\" body1=\"suction\" body2=\"" + name +
             "\" active=\"false\" solref=\"0.004 1\"/>\n";
  }
  if (objects.empty()) return "";
  // Constraint buffers sized for the pile: MuJoCo's defaults (njmax 500, nconmax 100) overflow
  // at about 30 objects, and efc arrays grow as njmax^2, so they scale with the pile.
  const size_t n = objects.size();
  const std::string size = "<size njmax=\"" + std::to_string(500 + 100 * n) + "\" nconmax=\"" +
                           std::to_string(100 + 30 * n) + "\" nstack=\"" + std::to_string(1000000 + 100000 * n) +
                           "\"/>\n";
  return "<!-- romunect: generated objects -->\n" + size + "<asset>\n" + assets + "</asset>\n<worldbody>\n" + bodies +
         "</worldbody>\n<equality>\n" + welds + "</equality>\n";
}

int RequireId(const mjModel* m, mjtObj type, const char* name, const std::string& source, const char* what) {
  const int id = mj_name2id(m, type, name);
  if (id < 0) {
    throw InputError(source, name,
                     std::string("the scene has no ") + what + " '" + name +
                         "' (include scenes/arm/arm.xml and add a body 'bin')");
  }
  return id;
}

void CheckRigFits(const Pose& T, const std::string& field) {
  if (!T.matrix().allFinite() || T.translation().norm() > WorldOptions::kMaxRigOffsetM) {
    throw InputError("rig", field,
                     "offset " + Num(T.translation().norm()) + " m does not fit on the hand (at most " +
                         Num(WorldOptions::kMaxRigOffsetM) + " m from the flange)");
  }
}

void SetLocalPose(const Pose& T, mjtNum* pos, mjtNum* quat_wxyz) {
  for (int k = 0; k < 3; ++k) pos[k] = T.translation()[k];
  const auto q = QuaternionToWxyz(Eigen::Quaterniond(T.rotation()));
  for (int k = 0; k < 4; ++k) quat_wxyz[k] = q[k];
}

IrMaterial MaterialOfGeom(const mjModel* m, int g) {
  IrMaterial mat;
  const int matid = m->geom_matid[g];
  const float* rgba = matid >= 0 ? m->mat_rgba + 4 * matid : m->geom_rgba + 4 * g;
  mat.albedo = (rgba[0] + rgba[1] + rgba[2]) / 3.0f;
  if (matid >= 0) {
    mat.specular = m->mat_specular[matid];
    mat.shininess = std::max(1.0f, m->mat_shininess[matid] * 128.0f);
  }
  return mat;
}

// MuJoCo's default warning handler also appends to MUJOCO_LOG.TXT in the working folder;
// warnings (a full contact buffer, say) go to stderr only. Installed once, process-wide.
void WarnToStderr(const char* message) { std::fprintf(stderr, "MuJoCo warning: %s\n", message); }

}  // namespace

std::filesystem::path ScenesDir() { return ROMUNECT_SCENES_DIR; }
std::filesystem::path DefaultSceneFile() { return ScenesDir() / "default" / "scene.xml"; }

Pose PoseFromMujoco(const mjtNum* xpos, const mjtNum* xmat) {
  Eigen::Matrix3d R;
  R << xmat[0], xmat[1], xmat[2], xmat[3], xmat[4], xmat[5], xmat[6], xmat[7], xmat[8];
  return MakePose(R, Eigen::Vector3d(xpos[0], xpos[1], xpos[2]));
}

Pose T_M_C() {
  Pose T = Pose::Identity();
  T.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  return T;
}

int World::Impl::SiteOrBody(ArmSite site, bool* is_body) const {
  *is_body = false;
  switch (site) {
    case ArmSite::kHand: *is_body = true; return hand_body;
    case ArmSite::kCamera: return camera_site;
    case ArmSite::kProjector: return projector_site;
    case ArmSite::kSuctionTip: return suction_tip_site;
  }
  return -1;
}

Pose World::Impl::SitePose(const mjData* d, ArmSite site) const {
  bool is_body = false;
  const int id = SiteOrBody(site, &is_body);
  return is_body ? PoseFromMujoco(d->xpos + 3 * id, d->xmat + 9 * id)
                 : PoseFromMujoco(d->site_xpos + 3 * id, d->site_xmat + 9 * id);
}

void World::Impl::SetScratchQ(const ArmVector& q) const {
  for (int j = 0; j < kArmDof; ++j) scratch->qpos[arm_qpos_adr[j]] = q[j];
  mj_kinematics(model.get(), scratch.get());
  mj_comPos(model.get(), scratch.get());
}

double MeshGeomRadius(const mjModel* m, int geom) {
  ROMUNECT_CHECK(m->geom_type[geom] == mjGEOM_MESH);
  const int mesh = m->geom_dataid[geom];
  const float* v = m->mesh_vert + 3 * m->mesh_vertadr[mesh];
  double radius = 0.0;
  for (int i = 0; i < m->mesh_vertnum[mesh]; ++i) {
    radius = std::max(radius, std::sqrt(double{v[3 * i]} * v[3 * i] + double{v[3 * i + 1]} * v[3 * i + 1] +
                                        double{v[3 * i + 2]} * v[3 * i + 2]));
  }
  return radius;
}

namespace {

// The scene file with the objects inserted before its closing tag.
std::string ComposeSceneXml(const std::filesystem::path& scene, const std::vector<ObjectSpec>& objects) {
  std::string xml = ReadFileText(scene);
  const size_t close = xml.rfind("</mujoco>");
  if (close == std::string::npos) throw InputError(scene.string(), "<mujoco>", "not an MJCF file (no </mujoco>)");
  xml.insert(close, ObjectsXml(objects));
  return xml;
}

// Compiles the composed text from a virtual file in the scene's folder, so its includes and mesh
// paths resolve as they would from the scene file itself.
MjModelPtr LoadComposedScene(const std::filesystem::path& scene, const std::string& xml) {
  mjVFS vfs;
  mj_defaultVFS(&vfs);
  const std::string virtual_name = (scene.parent_path() / ("__romunect_" + scene.filename().string())).string();
  ROMUNECT_CHECK(mj_makeEmptyFileVFS(&vfs, virtual_name.c_str(), static_cast<int>(xml.size())) == 0);
  const int file = mj_findFileVFS(&vfs, virtual_name.c_str());
  ROMUNECT_CHECK(file >= 0);
  std::memcpy(vfs.filedata[file], xml.data(), xml.size());
  char error[1024] = "";
  MjModelPtr model(mj_loadXML(virtual_name.c_str(), &vfs, error, sizeof error));
  mj_deleteVFS(&vfs);
  if (!model) throw InputError(scene.string(), "MJCF", std::string("MuJoCo cannot load the scene: ") + error);
  return model;
}

// The arm's joints and actuators, its bodies and sensor sites, and the suction cup's geoms.
void FindArm(const mjModel* m, const std::string& source, World::Impl* w) {
  for (int j = 0; j < World::kArmDof; ++j) {
    const int joint = RequireId(m, mjOBJ_JOINT, kArmJoints[j], source, "arm joint");
    w->arm_qpos_adr[j] = m->jnt_qposadr[joint];
    w->arm_dof_adr[j] = m->jnt_dofadr[joint];
    w->arm_actuator[j] = RequireId(m, mjOBJ_ACTUATOR, kArmActuators[j], source, "arm actuator");
  }
  w->base_body = RequireId(m, mjOBJ_BODY, "base", source, "body");
  w->hand_body = RequireId(m, mjOBJ_BODY, "hand", source, "body");
  w->suction_body = RequireId(m, mjOBJ_BODY, "suction", source, "body");
  w->bin_body = RequireId(m, mjOBJ_BODY, "bin", source, "body");
  w->camera_site = RequireId(m, mjOBJ_SITE, "camera", source, "site");
  w->projector_site = RequireId(m, mjOBJ_SITE, "projector", source, "site");
  w->suction_tip_site = RequireId(m, mjOBJ_SITE, "suction_tip", source, "site");
  if (m->site_bodyid[w->camera_site] != w->hand_body || m->site_bodyid[w->projector_site] != w->hand_body) {
    throw InputError(source, "camera", "the sites 'camera' and 'projector' must be on the body 'hand'");
  }
  for (int g = 0; g < m->ngeom; ++g) {
    if (m->geom_bodyid[g] != w->suction_body) continue;
    w->suction_geoms.push_back(g);
    w->suction_contype.push_back(m->geom_contype[g]);
    w->suction_conaffinity.push_back(m->geom_conaffinity[g]);
  }
}

// The bin's walls: boxes (seen, collide by default) and planes (settling aids, off).
void FindBinWalls(const mjModel* m, World::Impl* w) {
  for (int g = 0; g < m->ngeom; ++g) {
    if (m->geom_bodyid[g] != w->bin_body) continue;
    if (m->geom_type[g] == mjGEOM_BOX) {
      // The floor (thin in z) is left to the floor plane, always.
      const mjtNum* size = m->geom_size + 3 * g;
      if (size[2] < size[0] && size[2] < size[1]) continue;
      w->bin_boxes.push_back(g);
      w->bin_box_conaffinity.push_back(m->geom_conaffinity[g]);
    } else if (m->geom_type[g] == mjGEOM_PLANE) {
      mjtNum normal[3], z[3] = {0, 0, 1};
      mju_rotVecQuat(normal, z, m->geom_quat + 4 * g);
      if (std::abs(normal[2]) < 0.5) {
        w->bin_wall_planes.push_back(g);
        w->bin_wall_plane_contype.push_back(m->geom_contype[g]);
        w->bin_wall_plane_conaffinity.push_back(m->geom_conaffinity[g]);
      }
    }
  }
}

// Each object's body, joint addresses, grip weld and geoms.
void FindObjects(const mjModel* m, size_t count, const std::string& source, World::Impl* w) {
  for (size_t i = 0; i < count; ++i) {
    ObjectIds ids;
    const std::string name = "obj_" + std::to_string(i);
    ids.body = RequireId(m, mjOBJ_BODY, name.c_str(), source, "object body");
    const int joint = m->body_jntadr[ids.body];
    ids.qpos_adr = m->jnt_qposadr[joint];
    ids.dof_adr = m->jnt_dofadr[joint];
    ids.weld = RequireId(m, mjOBJ_EQUALITY, ("grip_" + std::to_string(i)).c_str(), source, "weld");
    for (int g = 0; g < m->ngeom; ++g) {
      if (m->geom_bodyid[g] == ids.body) ids.geoms.push_back(g);
    }
    w->objects.push_back(ids);
  }
}

// A user mesh must be able to lie in the bin: not wider than its inner diagonal (too small a
// mesh is refused by MakeUserMeshObject).
void CheckUserMeshesFit(const mjModel* m, const World::Impl& w, const Eigen::Vector3d& bin_inner_m) {
  for (size_t i = 0; i < w.options.objects.size(); ++i) {
    const ObjectSpec& o = w.options.objects[i];
    if (o.kind != ObjectKind::kUserMesh) continue;
    const double across_m = 2.0 * MeshGeomRadius(m, w.objects[i].geoms.at(0));
    const double diagonal_m = std::hypot(bin_inner_m.x(), bin_inner_m.y());
    if (!(across_m <= diagonal_m)) {
      char why[200];
      std::snprintf(why, sizeof why,
                    "%.4g mm across at %g m per file unit: wider than the bin's inner diagonal, "
                    "%.0f mm",
                    across_m * 1e3, o.mesh_scale, diagonal_m * 1e3);
      throw InputError(o.mesh_file.string(), "size", why);
    }
  }
}

// Geometry for renderers: every visible geom with triangles, tagged arm, moving or object.
void CollectRenderGeoms(const mjModel* m, World::Impl* w) {
  for (int g = 0; g < m->ngeom; ++g) {
    if (m->geom_rgba[4 * g + 3] <= 0.0f && m->geom_matid[g] < 0) continue;
    GeomInfo info;
    const char* name = mj_id2name(m, mjOBJ_GEOM, g);
    info.name = name ? name : "geom_" + std::to_string(g);
    const int body = m->geom_bodyid[g];
    info.moving = m->body_weldid[body] != 0;
    info.arm = m->body_rootid[body] == w->base_body;
    for (size_t i = 0; i < w->objects.size(); ++i) {
      if (w->objects[i].body == body) info.object = static_cast<int>(i);
    }
    info.mesh_G = TessellateGeom(m, g);
    info.material = MaterialOfGeom(m, g);
    if (info.mesh_G.triangles.empty()) continue;
    w->geoms.push_back(std::move(info));
    w->geom_ids.push_back(g);
  }
}

}  // namespace

World::World(const WorldOptions& options) : impl_(std::make_unique<Impl>()) {
  static const bool handler_installed = [] {
    mju_user_warning = WarnToStderr;
    return true;
  }();
  (void)handler_installed;
  Impl& w = *impl_;
  w.options = options;
  std::filesystem::path scene = options.scene_file.empty() ? DefaultSceneFile() : options.scene_file;
  scene = std::filesystem::absolute(scene);
  w.options.scene_file = scene;
  const std::string source = scene.string();
  if (options.T_H_C) CheckRigFits(*options.T_H_C, "T_H_C");
  if (options.T_H_C || options.T_C_P) {
    CheckRigFits((options.T_H_C ? *options.T_H_C : Pose::Identity()) *
                     (options.T_C_P ? *options.T_C_P : Pose::Identity()),
                 "T_H_P");
  }

  w.composed_xml = ComposeSceneXml(scene, options.objects);
  w.model = LoadComposedScene(scene, w.composed_xml);
  mjModel* m = w.model.get();
  FindArm(m, source, &w);
  FindBinWalls(m, &w);
  w.settling_walls = true;
  SetSettlingWalls(false);

  // The rig replaces the scene's sensor sites (and the viewer's camera, through M).
  if (options.T_H_C) {
    SetLocalPose(*options.T_H_C, m->site_pos + 3 * w.camera_site, m->site_quat + 4 * w.camera_site);
    const int cam = mj_name2id(m, mjOBJ_CAMERA, "sensor_camera");
    if (cam >= 0) SetLocalPose(*options.T_H_C * T_M_C().inverse(), m->cam_pos + 3 * cam, m->cam_quat + 4 * cam);
  }
  if (options.T_C_P) {
    SetLocalPose(T_H_C() * *options.T_C_P, m->site_pos + 3 * w.projector_site, m->site_quat + 4 * w.projector_site);
  }

  w.data.reset(mj_makeData(m));
  w.scratch.reset(mj_makeData(m));
  ROMUNECT_CHECK(w.data && w.scratch);
  FindObjects(m, options.objects.size(), source, &w);
  CheckUserMeshesFit(m, w, bin_inner_size_m());

  // The arm starts at its zero configuration, held there; the objects wait parked above the bin.
  for (int j = 0; j < kArmDof; ++j) w.data->ctrl[w.arm_actuator[j]] = w.data->qpos[w.arm_qpos_adr[j]];
  mj_forward(m, w.data.get());
  const Pose T_W_Bin_now = T_W_Bin();
  for (int i = 0; i < num_objects(); ++i) {
    Pose T = Pose::Identity();
    T.translation() = T_W_Bin_now * Eigen::Vector3d(0, 0, kParkHeightM + kParkSpacingM * i);
    SetObjectPose(i, T);
  }
  mju_copy(w.scratch->qpos, w.data->qpos, m->nq);
  CollectRenderGeoms(m, &w);
}

World::~World() = default;
World::World(World&&) noexcept = default;
World& World::operator=(World&&) noexcept = default;

const WorldOptions& World::options() const { return impl_->options; }
const std::string& World::composed_xml() const { return impl_->composed_xml; }
double World::time_s() const { return impl_->data->time; }
double World::timestep_s() const { return impl_->model->opt.timestep; }
int World::num_objects() const { return static_cast<int>(impl_->objects.size()); }

Pose World::T_W_B() const {
  return PoseFromMujoco(impl_->data->xpos + 3 * impl_->base_body, impl_->data->xmat + 9 * impl_->base_body);
}
Pose World::T_W_Bin() const {
  return PoseFromMujoco(impl_->data->xpos + 3 * impl_->bin_body, impl_->data->xmat + 9 * impl_->bin_body);
}

Eigen::Vector3d World::bin_inner_size_m() const {
  // The inner size is the bounding box of the bin's walls (seen from the bin frame) minus one
  // wall thickness per side; measured once from the geoms, so any bin of boxes works.
  const mjModel* m = impl_->model.get();
  Eigen::Vector3d inner_lo(-1e9, -1e9, 0), inner_hi(1e9, 1e9, 0);
  double top = 0.0;
  for (int g = 0; g < m->ngeom; ++g) {
    if (m->geom_bodyid[g] != impl_->bin_body || m->geom_type[g] != mjGEOM_BOX) continue;
    const Eigen::Vector3d c(m->geom_pos[3 * g], m->geom_pos[3 * g + 1], m->geom_pos[3 * g + 2]);
    const Eigen::Vector3d h(m->geom_size[3 * g], m->geom_size[3 * g + 1], m->geom_size[3 * g + 2]);
    top = std::max(top, c.z() + h.z());
    // A wall is thin in x or y; its inner face bounds the inside.
    if (h.x() < h.y() && h.x() < h.z()) {
      if (c.x() < 0) inner_lo.x() = std::max(inner_lo.x(), c.x() + h.x());
      else inner_hi.x() = std::min(inner_hi.x(), c.x() - h.x());
    } else if (h.y() < h.x() && h.y() < h.z()) {
      if (c.y() < 0) inner_lo.y() = std::max(inner_lo.y(), c.y() + h.y());
      else inner_hi.y() = std::min(inner_hi.y(), c.y() - h.y());
    }
  }
  Eigen::Vector3d size = inner_hi - inner_lo;
  size.z() = top;
  return size;
}

World::ArmVector World::arm_q() const {
  ArmVector q;
  for (int j = 0; j < kArmDof; ++j) q[j] = impl_->data->qpos[impl_->arm_qpos_adr[j]];
  return q;
}
World::ArmVector World::arm_qdot() const {
  ArmVector v;
  for (int j = 0; j < kArmDof; ++j) v[j] = impl_->data->qvel[impl_->arm_dof_adr[j]];
  return v;
}
World::ArmVector World::arm_lower_rad() const {
  ArmVector v;
  const mjModel* m = impl_->model.get();
  for (int j = 0; j < kArmDof; ++j) v[j] = m->jnt_range[2 * mj_name2id(m, mjOBJ_JOINT, kArmJoints[j])];
  return v;
}
World::ArmVector World::arm_upper_rad() const {
  ArmVector v;
  const mjModel* m = impl_->model.get();
  for (int j = 0; j < kArmDof; ++j) v[j] = m->jnt_range[2 * mj_name2id(m, mjOBJ_JOINT, kArmJoints[j]) + 1];
  return v;
}

void World::SetArmQ(const ArmVector& q) {
  Impl& w = *impl_;
  for (int j = 0; j < kArmDof; ++j) {
    w.data->qpos[w.arm_qpos_adr[j]] = q[j];
    w.data->qvel[w.arm_dof_adr[j]] = 0.0;
    w.data->ctrl[w.arm_actuator[j]] = q[j];
  }
  w.qdot_des.setZero();
  w.target_set = true;
  mj_forward(w.model.get(), w.data.get());
}

Pose World::SitePose_W(ArmSite site) const { return impl_->SitePose(impl_->data.get(), site); }
Pose World::T_B_H() const { return T_W_B().inverse() * SitePose_W(ArmSite::kHand); }

Pose World::T_H_C() const {
  const mjModel* m = impl_->model.get();
  const int s = impl_->camera_site;
  return MakePoseWxyz({m->site_quat[4 * s], m->site_quat[4 * s + 1], m->site_quat[4 * s + 2], m->site_quat[4 * s + 3]},
                      Eigen::Vector3d(m->site_pos[3 * s], m->site_pos[3 * s + 1], m->site_pos[3 * s + 2]));
}
Pose World::T_C_P() const {
  const mjModel* m = impl_->model.get();
  const int s = impl_->projector_site;
  const Pose T_H_P =
      MakePoseWxyz({m->site_quat[4 * s], m->site_quat[4 * s + 1], m->site_quat[4 * s + 2], m->site_quat[4 * s + 3]},
                   Eigen::Vector3d(m->site_pos[3 * s], m->site_pos[3 * s + 1], m->site_pos[3 * s + 2]));
  return T_H_C().inverse() * T_H_P;
}

Pose World::ForwardKinematics(const ArmVector& q, ArmSite site) const {
  impl_->SetScratchQ(q);
  return impl_->SitePose(impl_->scratch.get(), site);
}

World::Jacobian World::SiteJacobian(const ArmVector& q, ArmSite site) const {
  const Impl& w = *impl_;
  const mjModel* m = w.model.get();
  w.SetScratchQ(q);
  std::vector<mjtNum> jacp(3 * m->nv), jacr(3 * m->nv);
  bool is_body = false;
  const int id = w.SiteOrBody(site, &is_body);
  if (is_body) {
    mj_jacBody(m, w.scratch.get(), jacp.data(), jacr.data(), id);
  } else {
    mj_jacSite(m, w.scratch.get(), jacp.data(), jacr.data(), id);
  }
  Jacobian J;
  for (int r = 0; r < 3; ++r) {
    for (int j = 0; j < kArmDof; ++j) {
      J(r, j) = jacp[r * m->nv + w.arm_dof_adr[j]];
      J(r + 3, j) = jacr[r * m->nv + w.arm_dof_adr[j]];
    }
  }
  return J;
}

void World::SetArmTarget(const ArmVector& q_des, const ArmVector& qdot_des, const ArmVector& qddot_des) {
  Impl& w = *impl_;
  for (int j = 0; j < kArmDof; ++j) w.data->ctrl[w.arm_actuator[j]] = q_des[j];
  w.qdot_des = qdot_des;
  w.qddot_des = qddot_des;
  w.target_set = true;
}

void World::Step(int n) {
  Impl& w = *impl_;
  const mjModel* m = w.model.get();
  mjData* d = w.data.get();
  for (int i = 0; i < n; ++i) {
    mj_step1(m, d);
    if (w.target_set) {
      // Gravity (and Coriolis) compensation, plus the damping the motion itself will meet and
      // the force its acceleration takes (M qddot; mj_step1 has computed the inertia M).
      w.accel_nv.assign(m->nv, 0.0);
      w.force_nv.resize(m->nv);
      for (int j = 0; j < kArmDof; ++j) w.accel_nv[w.arm_dof_adr[j]] = w.qddot_des[j];
      mj_mulM(m, d, w.force_nv.data(), w.accel_nv.data());
      for (int j = 0; j < kArmDof; ++j) {
        const int dof = w.arm_dof_adr[j];
        d->qfrc_applied[dof] = d->qfrc_bias[dof] + m->dof_damping[dof] * w.qdot_des[j] + w.force_nv[dof];
      }
    }
    mj_step2(m, d);
    if (w.frozen) {
      for (size_t o = 0; o < w.objects.size(); ++o) {
        mju_copy(d->qpos + w.objects[o].qpos_adr, w.frozen_qpos.data() + 7 * o, 7);
        mju_zero(d->qvel + w.objects[o].dof_adr, 6);
      }
    }
  }
  mj_kinematics(m, d);  // poses reported between steps match qpos
}

void World::SetPileFrozen(bool frozen) {
  Impl& w = *impl_;
  if (frozen == w.frozen) return;
  if (frozen) w.frozen_qpos = ObjectQpos();  // before the flag: ObjectQpos reads it
  w.frozen = frozen;
  if (frozen) {
    w.model->opt.disableflags |= mjDSBL_CONTACT;
  } else {
    w.model->opt.disableflags &= ~mjDSBL_CONTACT;
  }
  for (const auto& o : w.objects) mju_zero(w.data->qvel + o.dof_adr, 6);
  mj_forward(w.model.get(), w.data.get());
}

bool World::pile_frozen() const { return impl_->frozen; }

void World::SetSettlingWalls(bool on) {
  Impl& w = *impl_;
  if (on == w.settling_walls || w.bin_wall_planes.empty()) return;
  w.settling_walls = on;
  mjModel* m = w.model.get();
  for (size_t k = 0; k < w.bin_wall_planes.size(); ++k) {
    m->geom_contype[w.bin_wall_planes[k]] = on ? w.bin_wall_plane_contype[k] : 0;
    m->geom_conaffinity[w.bin_wall_planes[k]] = on ? w.bin_wall_plane_conaffinity[k] : 0;
  }
  // Objects have contype 1: the boxes take them on unless the planes do.
  for (size_t k = 0; k < w.bin_boxes.size(); ++k) {
    m->geom_conaffinity[w.bin_boxes[k]] = on ? w.bin_box_conaffinity[k] : (w.bin_box_conaffinity[k] | 1);
  }
}

Pose World::T_W_O(int object) const {
  ROMUNECT_CHECK(object >= 0 && object < num_objects());
  const int b = impl_->objects[object].body;
  return PoseFromMujoco(impl_->data->xpos + 3 * b, impl_->data->xmat + 9 * b);
}

void World::SetObjectPose(int object, const Pose& T_W_O) {
  ROMUNECT_CHECK(object >= 0 && object < num_objects());
  const ObjectIds& o = impl_->objects[object];
  mjData* d = impl_->data.get();
  SetLocalPose(T_W_O, d->qpos + o.qpos_adr, d->qpos + o.qpos_adr + 3);
  mju_zero(d->qvel + o.dof_adr, 6);
  if (impl_->frozen) mju_copy(impl_->frozen_qpos.data() + 7 * object, d->qpos + o.qpos_adr, 7);
  mj_kinematics(impl_->model.get(), d);
}

double World::ObjectKineticEnergyJ() const {
  const Impl& w = *impl_;
  const mjModel* m = w.model.get();
  mjData* d = w.data.get();
  if (w.objects.empty()) return 0.0;
  // 0.5 v' M v over the objects' dofs; M is block-diagonal between free bodies and the arm.
  std::vector<mjtNum> v(m->nv, 0.0), Mv(m->nv, 0.0);
  for (const auto& o : w.objects) mju_copy(v.data() + o.dof_adr, d->qvel + o.dof_adr, 6);
  mj_mulM(m, d, Mv.data(), v.data());
  return 0.5 * mju_dot(v.data(), Mv.data(), m->nv);
}

std::vector<double> World::ObjectQpos() const {
  if (impl_->frozen) return impl_->frozen_qpos;
  std::vector<double> qpos;
  for (const auto& o : impl_->objects)
    qpos.insert(qpos.end(), impl_->data->qpos + o.qpos_adr, impl_->data->qpos + o.qpos_adr + 7);
  return qpos;
}

void World::SetObjectQpos(const std::vector<double>& qpos) {
  Impl& w = *impl_;
  ROMUNECT_CHECK(qpos.size() == 7 * w.objects.size());
  for (size_t i = 0; i < w.objects.size(); ++i) {
    mju_copy(w.data->qpos + w.objects[i].qpos_adr, qpos.data() + 7 * i, 7);
    mju_zero(w.data->qvel + w.objects[i].dof_adr, 6);
  }
  if (w.frozen) w.frozen_qpos = qpos;
  mj_forward(w.model.get(), w.data.get());
  // MuJoCo renormalizes quaternions in place, and renormalizing is not idempotent in the last
  // bit: put the given numbers back, so a restored pile holds exactly the saved doubles.
  for (size_t i = 0; i < w.objects.size(); ++i) mju_copy(w.data->qpos + w.objects[i].qpos_adr, qpos.data() + 7 * i, 7);
}

std::optional<int> World::SuctionContact(double max_distance_m) const {
  const Impl& w = *impl_;
  const mjModel* m = w.model.get();
  const mjData* d = w.data.get();
  for (int c = 0; c < d->ncon; ++c) {
    const mjContact& con = d->contact[c];
    if (con.dist > max_distance_m) continue;
    for (int side = 0; side < 2; ++side) {
      const int mine = side == 0 ? con.geom1 : con.geom2, other = side == 0 ? con.geom2 : con.geom1;
      if (m->geom_bodyid[mine] != w.suction_body) continue;
      for (size_t o = 0; o < w.objects.size(); ++o) {
        if (m->geom_bodyid[other] == w.objects[o].body) return static_cast<int>(o);
      }
    }
  }
  return std::nullopt;
}

void World::Grip(int object) {
  Impl& w = *impl_;
  ROMUNECT_CHECK(object >= 0 && object < num_objects());
  Release();
  mjModel* m = w.model.get();
  const mjData* d = w.data.get();
  // The weld holds the object where it is now: relpose is body2 (object) in body1 (suction).
  const Pose T_W_S = PoseFromMujoco(d->xpos + 3 * w.suction_body, d->xmat + 9 * w.suction_body);
  const Pose T_S_O = T_W_S.inverse() * T_W_O(object);
  mjtNum* data = m->eq_data + mjNEQDATA * w.objects[object].weld;
  mju_zero(data, mjNEQDATA);
  SetLocalPose(T_S_O, data + 3, data + 6);
  data[10] = 1.0;  // torquescale
  m->eq_active[w.objects[object].weld] = 1;
  // While it holds, the cup's own contacts are off: they would only push the welded object
  // away from the cup (the object itself still collides with everything else).
  for (int g : w.suction_geoms) m->geom_contype[g] = m->geom_conaffinity[g] = 0;
  w.gripped = object;
}

void World::Release() {
  Impl& w = *impl_;
  if (w.gripped) {
    w.model->eq_active[w.objects[*w.gripped].weld] = 0;
    for (size_t k = 0; k < w.suction_geoms.size(); ++k) {
      w.model->geom_contype[w.suction_geoms[k]] = w.suction_contype[k];
      w.model->geom_conaffinity[w.suction_geoms[k]] = w.suction_conaffinity[k];
    }
  }
  w.gripped.reset();
}

std::optional<int> World::gripped() const { return impl_->gripped; }

const std::vector<GeomInfo>& World::Geoms() const { return impl_->geoms; }

void World::GeomPoses(std::vector<Pose>* T_W_G) const {
  const Impl& w = *impl_;
  T_W_G->resize(w.geom_ids.size());
  for (size_t i = 0; i < w.geom_ids.size(); ++i) {
    const int g = w.geom_ids[i];
    (*T_W_G)[i] = PoseFromMujoco(w.data->geom_xpos + 3 * g, w.data->geom_xmat + 9 * g);
  }
}

}  // namespace romunect::sim
