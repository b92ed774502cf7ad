#include "romunect/sim/pile.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <type_traits>

#include <nlohmann/json.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/input_limits.h"
#include "world_impl.h"

namespace romunect::sim {
namespace {

constexpr const char* kSceneFormat = "romunect-scene";
constexpr int kSceneVersion = 2;  // 1: scene_file and mesh files only as absolute paths
constexpr const char* kInScenes = "romunect scenes";
// Objects waiting for their drop are held far from everything, out of every collision.
constexpr double kParkX = 5.0, kParkY = 5.0, kParkZ = 1.0;

// The bounding box of a generated object's parts, in O.
Eigen::AlignedBox3d PartsBox(const ObjectSpec& spec) {
  Eigen::AlignedBox3d box;
  for (const Mesh& part : spec.parts_O) {
    for (const auto& v : part.vertices) box.extend(v);
  }
  ROMUNECT_CHECK(!box.isEmpty());
  return box;
}

// A sphere about the centre of the object's bounding box that holds all its parts, in O. A user
// mesh has its part in its file: a sphere about its compiled geom's origin.
void BoundingSphere(const World::Impl& w, int object, Eigen::Vector3d* centre_O, double* radius_m) {
  const ObjectSpec& spec = w.options.objects[object];
  if (spec.kind == ObjectKind::kUserMesh) {
    const int g = w.objects[object].geoms.at(0);
    *centre_O = Eigen::Vector3d(w.model->geom_pos[3 * g], w.model->geom_pos[3 * g + 1], w.model->geom_pos[3 * g + 2]);
    *radius_m = MeshGeomRadius(w.model.get(), g);
    return;
  }
  *centre_O = PartsBox(spec).center();
  *radius_m = 0.0;
  for (const Mesh& part : spec.parts_O) {
    for (const auto& v : part.vertices) *radius_m = std::max(*radius_m, (v - *centre_O).norm());
  }
}

// The object's bounding box in O: its parts' (a user mesh: the cube about its bounding sphere).
Eigen::AlignedBox3d BoundingBox(const World::Impl& w, int object) {
  const ObjectSpec& spec = w.options.objects[object];
  if (spec.kind == ObjectKind::kUserMesh) {
    Eigen::Vector3d centre_O;
    double radius_m = 0.0;
    BoundingSphere(w, object, &centre_O, &radius_m);
    return Eigen::AlignedBox3d(centre_O.array() - radius_m, centre_O.array() + radius_m);
  }
  return PartsBox(spec);
}

// An object's footprint on the bin floor: a rectangle (bin frame, metres).
struct Footprint {
  Eigen::Vector2d centre, half;
  Eigen::Matrix2d axes;  // columns: the rectangle's own x and y
};

// Whether two rectangles come closer than `gap` (separating axes: the four edge normals).
bool TooClose(const Footprint& a, const Footprint& b, double gap) {
  const Eigen::Vector2d d = b.centre - a.centre;
  for (const Footprint* f : {&a, &b}) {
    for (int k = 0; k < 2; ++k) {
      const Eigen::Vector2d n = f->axes.col(k);
      const double ra = a.half.x() * std::abs(n.dot(a.axes.col(0))) + a.half.y() * std::abs(n.dot(a.axes.col(1)));
      const double rb = b.half.x() * std::abs(n.dot(b.axes.col(0))) + b.half.y() * std::abs(n.dot(b.axes.col(1)));
      if (std::abs(n.dot(d)) >= ra + rb + gap) return false;
    }
  }
  return true;
}

// The lowest point of a one-layer drop lies this far above the floor: the object settles flat.
constexpr double kOneLayerDropM = 0.002;
// One-layer objects lie square to the walls within this (a narrow bin turns them so).
constexpr double kOneLayerYawJitterRad = 3.0 * M_PI / 180.0;
// Random spots tried per object before it is dropped onto the others.
constexpr int kOneLayerTries = 2000;

// A one-layer drop pose in the bin frame (PileOptions::one_layer), or nothing when none of the
// spots tried is free. Of the free spots tried, the one nearest a wall (or the ends of its
// room) is taken, as objects slide to the side of a bin: random spots in mid-floor would leave
// gaps too narrow for the next ones. Appends the footprint to `placed`.
std::optional<Pose> OneLayerDrop(const World::Impl& w, int object, const Eigen::Vector3d& inner, double gap_m,
                                 std::mt19937& rng, std::vector<Footprint>* placed) {
  const Eigen::AlignedBox3d box = BoundingBox(w, object);
  int thin = 0;
  box.sizes().minCoeff(&thin);
  // the thinnest axis up: a quarter turn about y (x up) or x (y up)
  const Eigen::Matrix3d lay = thin == 2   ? Eigen::Matrix3d::Identity()
                              : thin == 0 ? Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix()
                                          : Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Eigen::Vector3d half = (lay.cwiseAbs() * box.sizes()) / 2;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::optional<Footprint> best;
  double best_score = 0.0;
  bool best_flip = false;
  for (int attempt = 0; attempt < kOneLayerTries; ++attempt) {
    // about square to the walls (a narrow bin turns its objects so), a few degrees off
    const double yaw = 0.5 * M_PI * std::floor(4 * u(rng)) + kOneLayerYawJitterRad * (2 * u(rng) - 1);
    const bool flip = u(rng) < 0.5;
    Footprint f;
    f.axes = Eigen::Rotation2Dd(yaw).toRotationMatrix();
    f.half = half.head<2>();
    const Eigen::Vector2d room = inner.head<2>() / 2 - f.axes.cwiseAbs() * f.half - Eigen::Vector2d::Constant(gap_m);
    const double x = 2 * u(rng) - 1, y = 2 * u(rng) - 1;
    if (room.minCoeff() < 0) continue;  // this yaw does not fit between the walls
    f.centre = Eigen::Vector2d(x * room.x(), y * room.y());
    const double score = (room.x() - std::abs(f.centre.x())) + (room.y() - std::abs(f.centre.y()));
    if (best && score >= best_score) continue;
    bool free = true;
    for (const Footprint& other : *placed) free = free && !TooClose(f, other, gap_m);
    if (!free) continue;
    best = f;
    best_flip = flip;
    best_score = score;
  }
  if (!best) return std::nullopt;
  placed->push_back(*best);
  const Eigen::Matrix3d flip = best_flip ? Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix()
                                         : Eigen::Matrix3d::Identity();
  Eigen::Matrix3d yaw = Eigen::Matrix3d::Identity();
  yaw.topLeftCorner<2, 2>() = best->axes;
  const Eigen::Matrix3d R = yaw * flip * lay;
  Pose T_Bin_O = Pose::Identity();
  T_Bin_O.linear() = R;
  const Eigen::Vector3d centre_Bin(best->centre.x(), best->centre.y(), half.z() + kOneLayerDropM);
  T_Bin_O.translation() = centre_Bin - R * box.center();
  return T_Bin_O;
}

void Park(World::Impl& w, int object) {
  mjtNum* q = w.data->qpos + w.objects[object].qpos_adr;
  q[0] = kParkX + 0.2 * object;
  q[1] = kParkY;
  q[2] = kParkZ;
  q[3] = 1.0;
  q[4] = q[5] = q[6] = 0.0;
  mju_zero(w.data->qvel + w.objects[object].dof_adr, 6);
}

// A uniformly random rotation (Shoemake's method), from the seeded generator.
Eigen::Quaterniond RandomRotation(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double u1 = u(rng), u2 = 2 * M_PI * u(rng), u3 = 2 * M_PI * u(rng);
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  return Eigen::Quaterniond(b * std::cos(u3), a * std::sin(u2), a * std::cos(u2), b * std::sin(u3));
}

nlohmann::json PoseJson(const Pose& T) {
  const auto rows = PoseToRowMajor(T);
  return nlohmann::json(std::vector<double>(rows.begin(), rows.end()));
}

Pose PoseFromJson(const nlohmann::json& j, const std::string& source, const std::string& field) {
  if (!j.is_array() || j.size() != 16) throw InputError(source, field, "expected 16 numbers (row-major 4x4)");
  std::array<double, 16> rows;
  Eigen::Matrix4d M;
  for (int i = 0; i < 16; ++i) {
    if (!j[i].is_number()) throw InputError(source, field, "expected numbers");
    rows[i] = j[i].get<double>();
    M(i / 4, i % 4) = rows[i];
  }
  const std::string problem = RigidityProblem(M);
  if (!problem.empty()) throw InputError(source, field, problem);
  return PoseFromRowMajor(rows);
}

// A value as an error message shows it: a number in full, anything else by its type (a string may be long).
std::string Found(const nlohmann::json& v) { return v.is_number() ? v.dump() : std::string("a ") + v.type_name(); }

template <typename T>
T Get(const nlohmann::json& j, const char* key, const std::string& source, const std::string& where) {
  if (!j.contains(key)) throw InputError(source, where + "." + key, "missing");
  const nlohmann::json& v = j.at(key);
  // A number that T cannot hold (1e30 as a seed, 1e300 as a float) converts with undefined behaviour.
  if constexpr (std::is_integral_v<T>) {
    const bool fits = v.is_number_unsigned() ? v.get<uint64_t>() <= uint64_t{std::numeric_limits<T>::max()}
                      : v.is_number_integer()
                          ? v.get<int64_t>() >= int64_t{std::numeric_limits<T>::min()} &&
                                (std::is_unsigned_v<T> || v.get<int64_t>() <= int64_t{std::numeric_limits<T>::max()})
                          : false;
    if (!fits) {
      throw InputError(source, where + "." + key,
                       "expected a whole number in [" + std::to_string(std::numeric_limits<T>::min()) + ", " +
                           std::to_string(std::numeric_limits<T>::max()) + "], found " + Found(v));
    }
  } else if constexpr (std::is_floating_point_v<T>) {
    if (!v.is_number() || !(std::abs(v.get<double>()) <= std::numeric_limits<T>::max())) {
      throw InputError(source, where + "." + key, "expected a finite number, found " + Found(v));
    }
  }
  try {
    return v.get<T>();
  } catch (const nlohmann::json::exception&) {
    throw InputError(source, where + "." + key, "has the wrong type");
  }
}

}  // namespace

std::string PileOptions::Problem() const {
  auto num = [](double v) { return std::to_string(v); };
  if (num_objects < 0 || num_objects > 60)
    return "num_objects = " + std::to_string(num_objects) + ": must be in [0, 60]";
  for (ObjectKind k : kinds) {
    if (k == ObjectKind::kUserMesh) return "kinds: user_mesh cannot be generated; add user meshes as ObjectSpecs";
  }
  if (!(drop_interval_s > 0)) return "drop_interval_s = " + num(drop_interval_s) + ": must be > 0";
  if (!(max_drop_speed_m_s > 0)) return "max_drop_speed_m_s = " + num(max_drop_speed_m_s) + ": must be > 0";
  if (!(drop_height_m >= 0)) return "drop_height_m = " + num(drop_height_m) + ": must be >= 0";
  if (!(one_layer_gap_m >= 0 && one_layer_gap_m <= 0.05))
    return "one_layer_gap_m = " + num(one_layer_gap_m) + ": must be in [0, 0.05]";
  if (!(kinetic_energy_threshold_j > 0))
    return "kinetic_energy_threshold_j = " + num(kinetic_energy_threshold_j) + ": must be > 0";
  if (!(quiet_time_s >= 0)) return "quiet_time_s = " + num(quiet_time_s) + ": must be >= 0";
  if (!(timestep_s > 0 && timestep_s <= 0.01)) return "timestep_s = " + num(timestep_s) + ": must be in (0, 0.01]";
  if (!(max_settle_time_s > 0)) return "max_settle_time_s = " + num(max_settle_time_s) + ": must be > 0";
  return "";
}

std::vector<ObjectSpec> MakePileObjects(const PileOptions& options) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  std::vector<ObjectKind> kinds = options.kinds;
  if (kinds.empty()) {
    kinds = {ObjectKind::kKey, ObjectKind::kPillBox, ObjectKind::kPuzzlePiece, ObjectKind::kLegoBrick,
             ObjectKind::kGear};
  }
  std::mt19937 rng(options.seed);
  std::vector<ObjectSpec> objects;
  for (int i = 0; i < options.num_objects; ++i) {
    const ObjectKind kind = kinds[std::uniform_int_distribution<size_t>(0, kinds.size() - 1)(rng)];
    objects.push_back(MakeObject(kind, static_cast<uint32_t>(rng())));
  }
  return objects;
}

std::string SettleSummary::BriefReport() const {
  char s[200];
  if (!loaded_from.empty()) {
    std::snprintf(s, sizeof s, "%d objects in the bin", objects_in_bin);
    return "pile loaded from " + loaded_from + " (settled by an earlier run), " + s;
  }
  std::snprintf(s, sizeof s,
                "pile %s after %.2f s simulated (%.2f s wall), kinetic energy %.2g J, %d objects in the bin",
                converged ? "settled" : "NOT settled", simulated_s, wall_s, kinetic_energy_j, objects_in_bin);
  if (not_in_one_layer == 0) return s;
  return s + (", " + std::to_string(not_in_one_layer) + " of them on others (no room on the floor)");
}

bool ObjectInBin(const World& world, int object) {
  const Eigen::Vector3d p = world.T_W_Bin().inverse() * world.T_W_O(object).translation();
  const Eigen::Vector3d inner = world.bin_inner_size_m();
  // Above the rim counts while the object is over the bin: a full small bin piles up high.
  return std::abs(p.x()) < inner.x() / 2 && std::abs(p.y()) < inner.y() / 2 && p.z() > -1e-3 &&
         p.z() < inner.z() + 0.03;
}

SettleSummary DropAndSettle(World* world, const PileOptions& options) {
  ROMUNECT_CHECK(world != nullptr);
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  const Stopwatch wall;
  World::Impl& w = world->impl();
  world->SetPileFrozen(false);
  world->Release();
  world->SetArmTarget(world->arm_q(), World::ArmVector::Zero());
  world->SetSettlingWalls(true);
  const int n = world->num_objects();
  for (int i = 0; i < n; ++i) Park(w, i);

  const Pose T_W_Bin = world->T_W_Bin();
  const Eigen::Vector3d inner = world->bin_inner_size_m();
  std::mt19937 rng(options.seed);
  std::vector<Pose> drops;
  std::vector<Footprint> placed;
  SettleSummary summary;
  for (int i = 0; i < n; ++i) {
    if (options.one_layer) {
      if (const std::optional<Pose> T_Bin_O = OneLayerDrop(w, i, inner, options.one_layer_gap_m, rng, &placed)) {
        drops.push_back(T_W_Bin * *T_Bin_O);
        continue;
      }
      ++summary.not_in_one_layer;
    }
    // The object's bounding sphere starts wholly above the bin's inner floor (as far as the bin
    // is wide enough), its lowest point drop_height_m above the rim.
    Eigen::Vector3d centre_O;
    double radius_m = 0.0;
    BoundingSphere(w, i, &centre_O, &radius_m);
    const double mx = std::clamp(radius_m, 0.0, inner.x() / 2 - 0.002);
    const double my = std::clamp(radius_m, 0.0, inner.y() / 2 - 0.002);
    const Eigen::Vector3d centre_Bin(
        std::uniform_real_distribution<double>(-inner.x() / 2 + mx, inner.x() / 2 - mx)(rng),
        std::uniform_real_distribution<double>(-inner.y() / 2 + my, inner.y() / 2 - my)(rng),
        inner.z() + options.drop_height_m + radius_m);
    Pose T_Bin_O = Pose::Identity();
    T_Bin_O.linear() = RandomRotation(rng).toRotationMatrix();
    T_Bin_O.translation() = centre_Bin - T_Bin_O.linear() * centre_O;
    drops.push_back(T_W_Bin * T_Bin_O);
  }

  const double scene_timestep_s = w.model->opt.timestep;
  w.model->opt.timestep = options.timestep_s;
  const double dt = options.timestep_s;
  const int steps_per_drop = std::max(1, static_cast<int>(std::lround(options.drop_interval_s / dt)));
  const int max_steps = steps_per_drop * n + static_cast<int>(std::lround(options.max_settle_time_s / dt));
  const int quiet_steps = static_cast<int>(std::lround(options.quiet_time_s / dt));
  int dropped = 0, quiet = 0, step = 0;
  for (; step < max_steps; ++step) {
    if (dropped < n && step == dropped * steps_per_drop) {
      world->SetObjectPose(dropped, drops[dropped]);
      ++dropped;
    }
    world->Step();
    for (int i = dropped; i < n; ++i) Park(w, i);
    for (int i = 0; i < dropped; ++i) {
      mjtNum* v = w.data->qvel + w.objects[i].dof_adr;
      const double speed = mju_norm3(v);
      if (speed > options.max_drop_speed_m_s) mju_scl3(v, v, options.max_drop_speed_m_s / speed);
    }
    if (dropped == n) {
      summary.kinetic_energy_j = world->ObjectKineticEnergyJ();
      quiet = summary.kinetic_energy_j < options.kinetic_energy_threshold_j ? quiet + 1 : 0;
      if (quiet > quiet_steps) {
        summary.converged = true;
        ++step;
        break;
      }
    }
  }
  w.model->opt.timestep = scene_timestep_s;
  world->SetSettlingWalls(false);
  // The settled state is these doubles; the world holds them exactly as a reload would.
  world->SetObjectQpos(world->ObjectQpos());
  summary.simulated_s = step * dt;
  for (int i = 0; i < n; ++i) summary.objects_in_bin += ObjectInBin(*world, i) ? 1 : 0;
  summary.wall_s = wall.seconds();
  return summary;
}

namespace {

// A file of the project's scenes folder is saved relative to it, marked `<key>_relative_to`, so a
// moved or re-cloned checkout still reloads it; any other file by its absolute path, so it
// reloads from any working directory.
void SaveFilePath(const std::filesystem::path& file, const char* key, nlohmann::ordered_json* j) {
  const std::filesystem::path absolute = std::filesystem::absolute(file).lexically_normal();
  const std::filesystem::path in_scenes = std::filesystem::weakly_canonical(absolute).lexically_relative(
      std::filesystem::weakly_canonical(ScenesDir()));
  if (!in_scenes.empty() && *in_scenes.begin() != "..") {
    (*j)[key] = in_scenes.generic_string();
    (*j)[std::string(key) + "_relative_to"] = kInScenes;
  } else {
    (*j)[key] = absolute.string();
  }
}

// The file SaveFilePath wrote; it must exist (a message naming the field, not MuJoCo's parse
// error). With `empty_is_default`, "" stands for the default and is returned as is.
std::filesystem::path LoadFilePath(const nlohmann::json& j, const char* key, const std::string& source,
                                   const std::string& where, bool empty_is_default) {
  std::filesystem::path file = Get<std::string>(j, key, source, where);
  if (file.empty() && empty_is_default) return file;
  const std::string field = where.empty() ? key : where + "." + key;
  const std::string relative_key = std::string(key) + "_relative_to";
  if (j.contains(relative_key)) {
    if (!j[relative_key].is_string() || j[relative_key].get<std::string>() != kInScenes) {
      throw InputError(source, field + "_relative_to", std::string("expected '") + kInScenes + "'");
    }
    if (file.is_absolute())
      throw InputError(source, field, "expected a path within the scenes folder, got an absolute one");
    file = ScenesDir() / file;
  } else if (!file.is_absolute()) {
    throw InputError(source, field, "expected an absolute path (or " + relative_key + ")");
  }
  std::error_code error;
  if (!std::filesystem::is_regular_file(file, error)) {
    throw InputError(source, field, "names '" + file.string() + "', which is not a file (moved or deleted?)");
  }
  return file;
}

}  // namespace

void SaveSettledScene(const World& world, const std::filesystem::path& path) {
  nlohmann::ordered_json j;
  j["format"] = kSceneFormat;
  j["version"] = kSceneVersion;
  SaveFilePath(world.options().scene_file, "scene_file", &j);
  if (world.options().T_H_C) j["T_H_C"] = PoseJson(*world.options().T_H_C);
  if (world.options().T_C_P) j["T_C_P"] = PoseJson(*world.options().T_C_P);
  nlohmann::ordered_json objects = nlohmann::ordered_json::array();
  for (const ObjectSpec& o : world.options().objects) {
    nlohmann::ordered_json e;
    e["kind"] = ToString(o.kind);
    if (o.kind == ObjectKind::kUserMesh) {
      SaveFilePath(o.mesh_file, "file", &e);
      e["scale"] = o.mesh_scale;
    } else {
      e["seed"] = o.seed;
    }
    e["density_kg_m3"] = o.density_kg_m3;
    e["material"] = {
        {"albedo", o.material.albedo}, {"specular", o.material.specular}, {"shininess", o.material.shininess}};
    objects.push_back(e);
  }
  j["objects"] = objects;
  j["qpos_order"] = "per object: x y z (m, in W), quaternion w x y z";
  j["qpos"] = world.ObjectQpos();
  WriteTextAtomically(path, j.dump(2) + "\n");
}

World LoadSettledScene(const std::filesystem::path& path) {
  const std::string source = path.string();
  const std::string text = ReadInputFile(path, kMaxTextFileBytes, "saved scene");
  CheckJsonNesting(text, source);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw InputError(source, "", std::string("not valid JSON: ") + e.what());
  }
  if (!j.is_object() || !j.contains("format") || j["format"] != kSceneFormat)
    throw InputError(source, "format", std::string("expected '") + kSceneFormat + "'");
  const int version = j.contains("version") && j["version"].is_number_integer() ? j["version"].get<int>() : 0;
  if (version != 1 && version != kSceneVersion) throw InputError(source, "version", "expected 1 or 2");
  WorldOptions options;
  options.scene_file = LoadFilePath(j, "scene_file", source, "", /*empty_is_default=*/true);
  if (j.contains("T_H_C")) options.T_H_C = PoseFromJson(j["T_H_C"], source, "T_H_C");
  if (j.contains("T_C_P")) options.T_C_P = PoseFromJson(j["T_C_P"], source, "T_C_P");
  if (!j.contains("objects") || !j["objects"].is_array()) throw InputError(source, "objects", "expected an array");
  for (size_t i = 0; i < j["objects"].size(); ++i) {
    const nlohmann::json& e = j["objects"][i];
    const std::string where = "objects[" + std::to_string(i) + "]";
    const ObjectKind kind = ObjectKindFromString(Get<std::string>(e, "kind", source, where), source + ": " + where);
    IrMaterial material;
    if (!e.contains("material")) throw InputError(source, where + ".material", "missing");
    material.albedo = Get<float>(e["material"], "albedo", source, where + ".material");
    material.specular = Get<float>(e["material"], "specular", source, where + ".material");
    material.shininess = Get<float>(e["material"], "shininess", source, where + ".material");
    const double density = Get<double>(e, "density_kg_m3", source, where);
    ObjectSpec spec = kind == ObjectKind::kUserMesh
                          ? MakeUserMeshObject(LoadFilePath(e, "file", source, where, /*empty_is_default=*/false),
                                               Get<double>(e, "scale", source, where), material, density)
                          : MakeObject(kind, Get<uint32_t>(e, "seed", source, where));
    spec.material = material;
    spec.density_kg_m3 = density;
    options.objects.push_back(std::move(spec));
  }
  const auto qpos = Get<std::vector<double>>(j, "qpos", source, "");
  if (qpos.size() != 7 * options.objects.size()) {
    throw InputError(source, "qpos",
                     "expected " + std::to_string(7 * options.objects.size()) + " numbers, got " +
                         std::to_string(qpos.size()));
  }
  for (double v : qpos) {
    if (!std::isfinite(v)) throw InputError(source, "qpos", "holds a number that is not finite");
  }
  World world(options);
  world.SetObjectQpos(qpos);
  return world;
}

}  // namespace romunect::sim
