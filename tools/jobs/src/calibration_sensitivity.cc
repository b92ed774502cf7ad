#include "romunect/tools/jobs/calibration_sensitivity.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sim/ik.h"
#include "romunect/sim/pick.h"
#include "romunect/sim/pile.h"
#include "romunect/tools/jobs/fuse.h"
#include "romunect/tools/jobs/perturbation.h"
#include "romunect/tools/jobs/run_folder.h"
#include "romunect/tools/jobs/scan.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;

// Default sweeps: a few values from well inside to beyond what the paper's 0.1 mm allows.
const std::vector<std::string> kDefaultSweeps = {
    "hand_eye_deg=0.05:0.1:0.2:0.5", "hand_eye_mm=0.05:0.1:0.2:0.5",      "focal_pct=0.05:0.1:0.2:0.5",
    "principal_px=0.5:1:2:5",        "depth_scale_pct=0.02:0.05:0.1:0.2", "depth_offset_mm=0.05:0.1:0.2:0.5"};

struct Sweep {
  std::string name;
  std::vector<double> values;
};

Sweep ParseSweep(const std::string& text) {
  const size_t eq = text.find('=');
  Sweep sweep;
  sweep.name = text.substr(0, eq);
  if (eq == std::string::npos) throw InputError("--sweep", text, "expected NAME=V1:V2:..., e.g. hand_eye_deg=0.1:0.5");
  std::istringstream values(text.substr(eq + 1));
  std::string value;
  while (std::getline(values, value, ':')) {
    ParsePerturbation(sweep.name + "=" + value, "--sweep");  // the name and the number, checked
    sweep.values.push_back(std::stod(value));
  }
  if (sweep.values.empty()) throw InputError("--sweep", text, "no values");
  std::sort(sweep.values.begin(), sweep.values.end());
  return sweep;
}

const char* PickText(int pick) { return pick < 0 ? "-" : pick == 1 ? "succeeded" : "failed"; }

// The pick from a fused map in a fresh copy of the scan's settled pile, the arm where the scan
// ended (its last frame's hand pose): 1 succeeded, 0 failed, -1 when it could not be set up.
int PickFrom(const fs::path& scan, const fs::path& map) {
  const std::optional<HeightMapGeometry> geometry = ReadHeightMapGeometry(map);
  if (!fs::exists(scan / "scene.json") || !geometry) return -1;
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(scan / "frames");
  if (manifest.frames.empty() || !manifest.frames.back().T_B_H) return -1;
  sim::World world = sim::LoadSettledScene(scan / "scene.json");
  const sim::IkResult ik = sim::SolveIk(world, sim::ArmSite::kHand, world.T_W_B() * *manifest.frames.back().T_B_H,
                                        world.arm_q());
  if (!ik.converged) return -1;
  world.SetArmQ(ik.q);
  const sim::PickResult pick = sim::Pick(&world, ReadDepthExr(map), *geometry);
  if (!pick.success) std::fprintf(stderr, "sensitivity: the pick failed: %s\n", pick.failure.c_str());
  return pick.success ? 1 : 0;
}

// Fuses the scan's frames with one perturbation; the fuse's own outputs are dropped.
SensitivityPoint FusePoint(const fs::path& scan, double voxel_m, int threads, const fs::path& work,
                           const std::string& name, double value) {
  FuseOptions o;
  o.source = (scan / "frames").string();
  o.gt = (scan / "gt_height.exr").string();
  o.out = (work / "fuse").string();
  o.voxel_m = voxel_m;
  o.threads = threads;
  if (!name.empty()) o.perturb = name + "=" + Format("%.17g", value);
  const FuseJobSummary s = RunFuse(o);
  const fusion::HeightMapMetrics& m = *s.report.metrics;
  SensitivityPoint point{name, value, m.mae_mm, m.rmse_mm, m.within_1mm, s.report.completeness};
  point.pick = PickFrom(scan, fs::path(o.out) / "fused_depth.exr");
  fs::remove_all(o.out);
  std::fprintf(stderr, "sensitivity: %s = %g: MAE %.3f mm, within 1 mm %.1f %%, pick %s\n",
               name.empty() ? "none" : name.c_str(), value, m.mae_mm, 100.0 * m.within_1mm, PickText(point.pick));
  return point;
}

// A plot of MAE (mm, left axis) and within 1 mm (%, right axis) against the injected error.
std::string PlotSvg(const std::string& name, const SensitivityPoint& baseline, const std::vector<SensitivityPoint>& p) {
  const double w = 480, h = 300, left = 60, right = 60, top = 30, bottom = 50;
  double max_x = 0, max_mae = 0;
  for (const SensitivityPoint& q : p) max_x = std::max(max_x, q.value), max_mae = std::max(max_mae, q.mae_mm);
  max_mae = std::max(max_mae, baseline.mae_mm) * 1.1;
  const auto X = [&](double v) { return left + (w - left - right) * v / max_x; };
  const auto Ym = [&](double v) { return h - bottom - (h - top - bottom) * v / max_mae; };
  const auto Yp = [&](double v) { return h - bottom - (h - top - bottom) * v; };
  std::string mae = Format("%.1f,%.1f", X(0), Ym(baseline.mae_mm)),
              within = Format("%.1f,%.1f", X(0), Yp(baseline.within_1mm));
  for (const SensitivityPoint& q : p) {
    mae += Format(" %.1f,%.1f", X(q.value), Ym(q.mae_mm));
    within += Format(" %.1f,%.1f", X(q.value), Yp(q.within_1mm));
  }
  std::string svg = Format("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
                           "font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%%\" height=\"100%%\" "
                           "fill=\"white\"/>\n",
                           w, h);
  svg += Format("<line x1=\"%.0f\" y1=\"%.0f\" x2=\"%.0f\" y2=\"%.0f\" stroke=\"black\"/>\n", left, h - bottom,
                w - right, h - bottom);
  svg += Format("<line x1=\"%.0f\" y1=\"%.0f\" x2=\"%.0f\" y2=\"%.0f\" stroke=\"black\"/>\n", left, top, left,
                h - bottom);
  svg += Format("<polyline points=\"%s\" fill=\"none\" stroke=\"#c03030\" stroke-width=\"2\"/>\n", mae.c_str());
  svg += Format("<polyline points=\"%s\" fill=\"none\" stroke=\"#3050c0\" stroke-width=\"2\"/>\n", within.c_str());
  svg += Format("<text x=\"%.0f\" y=\"%.0f\" text-anchor=\"middle\">injected %s (0 .. %g)</text>\n", w / 2, h - 15,
                name.c_str(), max_x);
  svg += Format("<text x=\"%.0f\" y=\"20\" fill=\"#c03030\">MAE (0 .. %.2f mm)</text>\n", left, max_mae);
  svg += Format("<text x=\"%.0f\" y=\"20\" fill=\"#3050c0\" text-anchor=\"end\">within 1 mm (0 .. 100 %%)</text>\n",
                w - 10);
  return svg + "</svg>\n";
}

// The scan to re-fuse, its voxel; scans first when none is given.
fs::path ScanToUse(const SensitivityOptions& o, const fs::path& work, double* voxel_m) {
  fs::path scan = o.scan;
  if (scan.empty()) {
    ScanJobOptions s;
    s.out = (work / "scan").string();
    s.seed = o.seed;
    s.objects = o.objects;
    s.threads = o.threads;
    scan = RunScan(s).run_dir;
  }
  for (const char* need : {"frames/frames.json", "gt_height.exr", "report.json"}) {
    if (!fs::exists(scan / need)) throw InputError(scan.string(), need, "missing: give a scan run folder");
  }
  std::ifstream in(scan / "report.json");
  const nlohmann::json report = nlohmann::json::parse(in, nullptr, false);
  const nlohmann::json::json_pointer voxel("/options/voxel_m");
  if (!report.is_object() || !report.contains(voxel) || !report[voxel].is_number() || !(report[voxel] > 0.0)) {
    throw InputError((scan / "report.json").string(), "options.voxel_m", "expected a positive number");
  }
  *voxel_m = report[voxel].get<double>();
  return scan;
}

}  // namespace

SensitivityTolerance ToleranceOf(const std::string& name, const std::vector<SensitivityPoint>& sweep,
                                 double baseline_mae_mm) {
  SensitivityTolerance t{name, -1.0, -1.0};
  for (double* limit : {&t.within_0_1mm, &t.within_1mm}) {
    const double allowed = limit == &t.within_0_1mm ? 0.1 : 1.0;
    double previous_value = 0.0, previous_excess = 0.0;
    *limit = sweep.empty() ? -1.0 : sweep.back().value;  // none exceeds: at least the largest swept
    for (const SensitivityPoint& p : sweep) {
      const double excess = p.mae_mm - baseline_mae_mm;
      if (excess > allowed) {
        *limit = previous_value + (p.value - previous_value) * (allowed - previous_excess) / (excess - previous_excess);
        break;
      }
      previous_value = p.value, previous_excess = excess;
    }
  }
  return t;
}

SensitivitySummary RunCalibrationSensitivity(const SensitivityOptions& o) {
  std::vector<Sweep> sweeps;
  for (const std::string& text : o.sweeps.empty() ? kDefaultSweeps : o.sweeps) sweeps.push_back(ParseSweep(text));
  if (!o.scan.empty() && !fs::is_directory(o.scan)) throw InputError(o.scan, "", "not a scan run folder");
  RunFolder run(o.out, "--out", "experiment");
  run.Begin();
  SensitivitySummary s;
  double voxel_m = 0.0;
  const fs::path scan = ScanToUse(o, run.work_dir(), &voxel_m);
  s.baseline = FusePoint(scan, voxel_m, o.threads, run.work_dir(), "", 0.0);
  std::string csv = "name,value,mae_mm,rmse_mm,within_1mm,completeness,pick\n";
  csv += Format("none,0,%.6f,%.6f,%.6f,%.6f,%d\n", s.baseline.mae_mm, s.baseline.rmse_mm, s.baseline.within_1mm,
                s.baseline.completeness, s.baseline.pick);
  s.table = Format("Unperturbed: MAE %.3f mm, RMSE %.3f mm, within 1 mm %.1f %%, completeness %.1f %%, pick %s.\n\n",
                   s.baseline.mae_mm, s.baseline.rmse_mm, 100 * s.baseline.within_1mm, 100 * s.baseline.completeness,
                   PickText(s.baseline.pick));
  s.table += "| injected | value | MAE mm | RMSE mm | within 1 mm | completeness | pick |\n"
             "| --- | --- | --- | --- | --- | --- | --- |\n";
  for (const Sweep& sweep : sweeps) {
    std::vector<SensitivityPoint> points;
    for (double v : sweep.values) {
      points.push_back(FusePoint(scan, voxel_m, o.threads, run.work_dir(), sweep.name, v));
      const SensitivityPoint& p = points.back();
      csv += Format("%s,%g,%.6f,%.6f,%.6f,%.6f,%d\n", p.name.c_str(), p.value, p.mae_mm, p.rmse_mm, p.within_1mm,
                    p.completeness, p.pick);
      s.table += Format("| %s | %g | %.3f | %.3f | %.1f %% | %.1f %% | %s |\n", p.name.c_str(), p.value, p.mae_mm,
                        p.rmse_mm, 100 * p.within_1mm, 100 * p.completeness, PickText(p.pick));
    }
    WriteTextAtomically(run.work_dir() / (sweep.name + ".svg"), PlotSvg(sweep.name, s.baseline, points));
    s.tolerances.push_back(ToleranceOf(sweep.name, points, s.baseline.mae_mm));
    s.points.insert(s.points.end(), points.begin(), points.end());
  }
  s.table += "\nTolerance: the largest injected error that keeps the map's MAE within 0.1 mm / 1 mm of the "
             "unperturbed map's (linear between swept values; the largest swept when none exceeds).\n\n"
             "| injected | within 0.1 mm | within 1 mm |\n| --- | --- | --- |\n";
  for (const SensitivityTolerance& t : s.tolerances) {
    s.table += Format("| %s | %g | %g |\n", t.name.c_str(), t.within_0_1mm, t.within_1mm);
  }
  WriteTextAtomically(run.work_dir() / "sensitivity.csv", csv);
  WriteTextAtomically(run.work_dir() / "sensitivity.md", "# Calibration sensitivity\n\n" + s.table);
  run.Commit();
  s.out = run.dir();
  return s;
}

}  // namespace romunect::jobs
