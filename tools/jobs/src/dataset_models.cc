// The dataset's settings (parsed and validated options) and its object models (PLY and
// models_info.json, BOP's model files).
#include <errno.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

#include "dataset_scene.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/tools/jobs/rig_argument.h"

namespace romunect::jobs::dataset {
namespace {

constexpr double kPi = 3.14159265358979323846;
// A symmetry holds when every transformed vertex lands this close to a vertex (m): the
// generators' vertices are exact to float rounding, so a real symmetry is far below it.
constexpr double kSymmetryToleranceM = 1e-5;

void Require(bool ok, const std::string& option, const std::string& value, const std::string& rule) {
  if (!ok) throw InputError(option, "", "'" + value + "': " + rule);
}

int ParseInt(const std::string& text, const std::string& option, const std::string& value) {
  size_t used = 0;
  int n = 0;
  try {
    n = std::stoi(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  Require(used == text.size() && !text.empty(), option, value, "expected a whole number");
  return n;
}

}  // namespace

Settings ParseSettings(const DatasetOptions& o) {
  Settings s;
  s.seed = o.seed;
  Require(!o.kinds.empty(), "--kinds", "", "expected at least one kind");
  for (const std::string& k : o.kinds) {
    const sim::ObjectKind kind = sim::GeneratedKindFromName(k, "--kinds");
    if (std::find(s.kinds.begin(), s.kinds.end(), kind) == s.kinds.end()) s.kinds.push_back(kind);
  }
  std::sort(s.kinds.begin(), s.kinds.end());  // the same settings however they are listed
  const size_t dash = o.objects.find('-');
  s.objects_min = ParseInt(o.objects.substr(0, dash), "--objects", o.objects);
  s.objects_max = dash == std::string::npos ? s.objects_min
                                            : ParseInt(o.objects.substr(dash + 1), "--objects", o.objects);
  Require(s.objects_min >= 1 && s.objects_min <= s.objects_max, "--objects", o.objects,
          "expected A-B with 1 <= A <= B");
  Require(o.variants >= 1 && o.variants <= 100, "--variants", std::to_string(o.variants), "expected 1..100");
  s.variants = o.variants;
  Require(o.views == "approach" || o.views == "random" || o.views == "both", "--views", o.views,
          "expected approach, random or both");
  s.approach = o.views != "random";
  s.random = o.views != "approach";
  Require(o.views_per_scene >= (s.random ? 1 : 0) && o.views_per_scene <= 10000, "--views-per-scene",
          std::to_string(o.views_per_scene), "expected 1..10000 random views");
  s.views_per_scene = s.random ? o.views_per_scene : 0;
  Require(o.every >= 1 && o.every <= 10000, "--every", std::to_string(o.every), "expected 1..10000");
  s.every = s.approach ? o.every : 1;
  s.rig_name = o.rig;
  try {
    s.rig = LoadRigArgument(o.rig);
  } catch (const InputError& e) {
    throw InputError("--rig", "", e.what());
  }
  return s;
}

nlohmann::json Settings::ToJson() const {
  nlohmann::json kinds_json = nlohmann::json::array();
  for (sim::ObjectKind k : kinds) kinds_json.push_back(sim::ToString(k));
  // A rig file is recorded by its content: the same file name with other content is another rig.
  nlohmann::json rig_json = rig_name;
  if (rig_name != "romunect" && rig_name != "kinect-v1") {
    std::ostringstream text;
    text << std::ifstream(rig_name).rdbuf();
    rig_json = {{"file", rig_name}, {"content", nlohmann::json::parse(text.str(), nullptr, false)}};
  }
  return {{"seed", seed},
          {"rig", rig_json},
          {"kinds", kinds_json},
          {"objects", std::to_string(objects_min) + "-" + std::to_string(objects_max)},
          {"variants", variants},
          {"views", approach && random ? "both"
                    : approach         ? "approach"
                                       : "random"},
          {"views_per_scene", views_per_scene},
          {"every", every}};
}

std::vector<std::vector<double>> DiscreteSymmetries(const Model& model) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = -lo;
  for (const auto& p : model.vertices_O) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  // vertices sorted for lookups: a transformed vertex must find one within the tolerance
  std::vector<Eigen::Vector3d> sorted = model.vertices_O;
  auto by_x = [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) { return a.x() < b.x(); };
  std::sort(sorted.begin(), sorted.end(), by_x);
  auto maps_onto_itself = [&](const Eigen::Matrix3d& R) {
    for (const auto& p : model.vertices_O) {
      const Eigen::Vector3d q = centre + R * (p - centre);
      auto it = std::lower_bound(sorted.begin(), sorted.end(), Eigen::Vector3d(q.x() - kSymmetryToleranceM, 0, 0),
                                 by_x);
      bool hit = false;
      for (; it != sorted.end() && it->x() <= q.x() + kSymmetryToleranceM && !hit; ++it) {
        hit = (*it - q).norm() <= kSymmetryToleranceM;
      }
      if (!hit) return false;
    }
    return true;
  };
  std::vector<Eigen::Matrix3d> candidates;
  for (int a = 0; a < 2; ++a) {
    candidates.push_back(Eigen::AngleAxisd(kPi, Eigen::Vector3d::Unit(a)).toRotationMatrix());
  }
  // turns about z: the smallest that holds and its multiples (a gear's teeth, a box's half turn)
  for (int n = 64; n >= 2; --n) {
    if (!maps_onto_itself(Eigen::AngleAxisd(2 * kPi / n, Eigen::Vector3d::UnitZ()).toRotationMatrix())) continue;
    for (int k = 1; k < n; ++k)
      candidates.push_back(Eigen::AngleAxisd(2 * kPi * k / n, Eigen::Vector3d::UnitZ()).toRotationMatrix());
    break;
  }
  std::vector<std::vector<double>> out;
  for (const Eigen::Matrix3d& R : candidates) {
    if (!maps_onto_itself(R)) continue;
    const Eigen::Vector3d t_mm = 1e3 * (centre - R * centre);
    std::vector<double> m;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) m.push_back(std::abs(R(i, j)) < 1e-12 ? 0.0 : R(i, j));
      m.push_back(std::abs(t_mm(i)) < 1e-9 ? 0.0 : t_mm(i));
    }
    for (double x : {0.0, 0.0, 0.0, 1.0}) m.push_back(x);
    out.push_back(m);
  }
  return out;
}

namespace {

// ASCII PLY in millimetres with area-weighted vertex normals (BOP's models carry normals).
std::string PlyText(const Model& m) {
  std::vector<Eigen::Vector3d> normals(m.vertices_O.size(), Eigen::Vector3d::Zero());
  for (const auto& t : m.triangles) {
    const Eigen::Vector3d n = (m.vertices_O[t[1]] - m.vertices_O[t[0]]).cross(m.vertices_O[t[2]] - m.vertices_O[t[0]]);
    for (int k = 0; k < 3; ++k) normals[t[k]] += n;
  }
  std::string out = "ply\nformat ascii 1.0\ncomment romunect " + std::string(sim::ToString(m.kind)) + " variant " +
                    std::to_string(m.variant) + ", millimetres\nelement vertex " + std::to_string(m.vertices_O.size()) +
                    "\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float "
                    "ny\nproperty float nz\nelement face " +
                    std::to_string(m.triangles.size()) + "\nproperty list uchar int vertex_indices\nend_header\n";
  char line[200];
  for (size_t i = 0; i < m.vertices_O.size(); ++i) {
    const Eigen::Vector3d p = 1e3 * m.vertices_O[i];
    const Eigen::Vector3d n = normals[i].norm() > 0 ? normals[i].normalized() : Eigen::Vector3d::UnitZ();
    std::snprintf(line, sizeof line, "%.9g %.9g %.9g %.6f %.6f %.6f\n", static_cast<float>(p.x()),
                  static_cast<float>(p.y()), static_cast<float>(p.z()), n.x(), n.y(), n.z());
    out += line;
  }
  for (const auto& t : m.triangles) {
    std::snprintf(line, sizeof line, "3 %d %d %d\n", t[0], t[1], t[2]);
    out += line;
  }
  return out;
}

nlohmann::json ModelInfo(const Model& m) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e9), hi = -lo;
  for (const auto& p : m.vertices_O) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  double diameter = 0.0;  // the largest distance between two vertices
  for (size_t i = 0; i < m.vertices_O.size(); ++i) {
    for (size_t j = i + 1; j < m.vertices_O.size(); ++j) {
      diameter = std::max(diameter, (m.vertices_O[i] - m.vertices_O[j]).squaredNorm());
    }
  }
  nlohmann::json info = {{"diameter", 1e3 * std::sqrt(diameter)},
                         {"min_x", 1e3 * lo.x()},
                         {"min_y", 1e3 * lo.y()},
                         {"min_z", 1e3 * lo.z()},
                         {"size_x", 1e3 * (hi - lo).x()},
                         {"size_y", 1e3 * (hi - lo).y()},
                         {"size_z", 1e3 * (hi - lo).z()}};
  const auto symmetries = DiscreteSymmetries(m);
  if (!symmetries.empty()) info["symmetries_discrete"] = symmetries;
  return info;
}

}  // namespace

namespace {

std::string HostName() {
  char name[256] = {};
  gethostname(name, sizeof name - 1);
  return name;
}

constexpr const char* kTemporary = ".tmp-";

}  // namespace

void WriteShared(const std::filesystem::path& path, const std::string& text) {
  static std::atomic<int> counter{0};
  std::string name = ".";
  name += path.filename().string();
  name += kTemporary;
  name += HostName();
  char suffix[48];
  std::snprintf(suffix, sizeof suffix, "-%d-%d", static_cast<int>(getpid()), counter++);
  name += suffix;
  const std::filesystem::path tmp = path.parent_path() / name;
  {
    std::ofstream out(tmp, std::ios::binary);
    out << text;
    out.close();
    if (!out) {
      std::error_code ignored;
      std::filesystem::remove(tmp, ignored);
      throw std::runtime_error(path.string() + ": cannot write file (disk full?)");
    }
  }
  std::filesystem::rename(tmp, path);
}

void RemoveStaleTemporaries(const std::filesystem::path& dir) {
  if (!std::filesystem::exists(dir)) return;
  const std::string host = HostName();
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    // ".<name>.tmp-<host>-<pid>-<n>": host names may hold '-', so read from the end
    const std::string name = entry.path().filename().string();
    const size_t at = name.rfind(kTemporary), last = name.rfind('-'), before = name.rfind('-', last - 1);
    if (name.empty() || name[0] != '.' || at == std::string::npos || before == std::string::npos || before < at + 5) {
      continue;
    }
    const std::string writer_host = name.substr(at + 5, before - at - 5);
    const int pid = std::atoi(name.c_str() + before + 1);
    if (writer_host == host && pid > 0 && kill(pid, 0) != 0 && errno == ESRCH) {
      std::error_code ignored;  // another process may have removed it meanwhile
      std::filesystem::remove(entry.path(), ignored);
    }
  }
}

void WriteModels(const std::filesystem::path& models_dir, const std::vector<Model>& models) {
  std::filesystem::create_directories(models_dir);
  nlohmann::json info = nlohmann::json::object();
  // keys sorted as numbers would be: BOP's toolkit reads them back with int()
  std::map<int, nlohmann::json> by_id;
  for (const Model& m : models) {
    WriteShared(models_dir / ("obj_" + Id6(m.obj_id) + ".ply"), PlyText(m));
    by_id[m.obj_id] = ModelInfo(m);
  }
  std::string text = "{";
  for (const auto& [id, model_info] : by_id) {
    text += (text.size() > 1 ? ",\n  \"" : "\n  \"") + std::to_string(id) + "\": " + model_info.dump();
  }
  text += "\n}\n";
  WriteShared(models_dir / "models_info.json", text);
}

}  // namespace romunect::jobs::dataset
