#include "romunect/tools/jobs/table1.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <sstream>

#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sim/objects.h"
#include "romunect/tools/jobs/run_folder.h"
#include "romunect/tools/jobs/scan.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

const char* const kFrameKeys[] = {"1", "20", "50"};
const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd"};

std::string DefaultDir() {
  const std::time_t now = std::time(nullptr);
  char name[64];
  std::strftime(name, sizeof(name), "runs/table1-%Y%m%d-%H%M%S", std::localtime(&now));
  return name;
}

std::string Format(const char* format, double v) {
  char s[64];
  std::snprintf(s, sizeof s, format, v);
  return s;
}

struct Stats {
  double mean = 0.0, sd = 0.0;
};

// Mean and sample standard deviation of the finite values (NaN when there are none).
Stats MeanSd(const std::vector<double>& v) {
  std::vector<double> x;
  for (double a : v) {
    if (std::isfinite(a)) x.push_back(a);
  }
  Stats s;
  if (x.empty()) return {NAN, NAN};
  for (double a : x) s.mean += a / x.size();
  for (double a : x) s.sd += x.size() > 1 ? (a - s.mean) * (a - s.mean) / (x.size() - 1) : 0.0;
  s.sd = std::sqrt(s.sd);
  return s;
}

int ObjectsFor(const Table1Options& o, const std::string& kind) {
  if (kind == "keys") return o.keys;
  if (kind == "pillbox") return o.pillbox;
  if (kind == "puzzle") return o.puzzle;
  return o.lego;
}

Table1Run RunOne(const Table1Options& o, const std::string& kind, unsigned seed, const fs::path& dir) {
  ScanJobOptions scan;
  scan.kinds = {kind};
  scan.objects = ObjectsFor(o, kind);
  scan.one_layer = true;
  scan.seed = seed;
  scan.threads = o.threads;
  scan.rig = o.rig;
  scan.write_frames = false;
  scan.out = (dir / (kind + "-seed" + std::to_string(seed))).string();
  const ScanSummary summary = RunScan(scan);
  const ScanReport& r = summary.report;
  Table1Run run;
  run.kind = kind;
  run.seed = seed;
  for (int i = 0; i < 3; ++i) {
    const std::optional<double> c = Table1Completeness(r, kTable1Frames[i]);
    run.after_percent[i] = c ? 100.0 * *c : NAN;
  }
  const fusion::HeightMapMetrics& m = *r.fusion.metrics;
  run.completeness_percent = 100.0 * m.completeness;
  run.mae_mm = m.mae_mm;
  run.rmse_mm = m.rmse_mm;
  run.within_1mm_percent = 100.0 * m.within_1mm;
  run.frames = static_cast<int>(r.fusion.completeness_per_frame.size()) - Table1FirstFrame(r);
  for (size_t i = Table1FirstFrame(r); i < r.fusion.completeness_per_frame.size(); ++i) {
    run.curve_percent.push_back(100.0 * r.fusion.completeness_per_frame[i]);
  }
  return run;
}

std::vector<Table1Run> RunsOf(const std::vector<Table1Run>& runs, const std::string& kind) {
  std::vector<Table1Run> out;
  for (const Table1Run& r : runs) {
    if (r.kind == kind) out.push_back(r);
  }
  return out;
}

json KindJson(const std::vector<Table1Run>& runs, const PaperTable1Row& paper) {
  json k, spread, paper_json, seeds = json::array();
  for (int i = 0; i < 3; ++i) {
    std::vector<double> v;
    for (const Table1Run& r : runs) v.push_back(r.after_percent[i]);
    const Stats s = MeanSd(v);
    k[kFrameKeys[i]] = std::isfinite(s.mean) ? json(s.mean) : json(nullptr);
    spread[kFrameKeys[i]] = std::isfinite(s.sd) ? json(s.sd) : json(nullptr);
    paper_json[kFrameKeys[i]] = paper.after_percent[i];
  }
  std::vector<double> all, mae, rmse, within;
  for (const Table1Run& r : runs) {
    all.push_back(r.completeness_percent);
    mae.push_back(r.mae_mm);
    rmse.push_back(r.rmse_mm);
    within.push_back(r.within_1mm_percent);
    json seed = {{"seed", r.seed},       {"all_frames", r.completeness_percent},
                 {"frames", r.frames},   {"mae_mm", r.mae_mm},
                 {"rmse_mm", r.rmse_mm}, {"within_1mm_percent", r.within_1mm_percent}};
    for (int i = 0; i < 3; ++i) {
      seed[kFrameKeys[i]] = std::isfinite(r.after_percent[i]) ? json(r.after_percent[i]) : json(nullptr);
    }
    seeds.push_back(seed);
  }
  k["spread"] = spread;  // sample standard deviation over the seeds
  k["paper"] = paper_json;
  k["all_frames"] = MeanSd(all).mean;
  k["mae_mm"] = MeanSd(mae).mean;
  k["rmse_mm"] = MeanSd(rmse).mean;
  k["within_1mm_percent"] = MeanSd(within).mean;
  k["per_seed"] = seeds;
  return k;
}

std::string Cell(const json& mean, const json& sd) {
  if (mean.is_null()) return "-";
  return Format("%.1f", mean.get<double>()) + (sd.is_null() ? "" : Format(" ± %.1f", sd.get<double>()));
}

std::string Markdown(const json& j, int seeds) {
  std::ostringstream s;
  s << "# Table 1: completeness of the fused depth map (%)\n\n"
    << "Mean ± standard deviation over " << seeds << " seeds per kind; frame 1 is the first frame with the "
    << "pile in the measurable range; the denominator is the whole 150 x 80 mm region.\n\n"
    << "| object | paper 1 | ours 1 | paper 20 | ours 20 | paper 50 | ours 50 | ours, all frames | MAE [mm] | "
       "within 1 mm [%] |\n|---|---|---|---|---|---|---|---|---|---|\n";
  for (const PaperTable1Row& row : PaperTable1()) {
    const json& k = j[row.kind];
    s << "| " << row.kind;
    for (int i = 0; i < 3; ++i) {
      s << " | " << Format("%.2f", row.after_percent[i]) << " | " << Cell(k[kFrameKeys[i]], k["spread"][kFrameKeys[i]]);
    }
    s << " | " << Format("%.1f", k["all_frames"].get<double>()) << " | " << Format("%.3f", k["mae_mm"].get<double>())
      << " | " << Format("%.1f", k["within_1mm_percent"].get<double>()) << " |\n";
  }
  return s.str();
}

// Every run's completeness curve in one plot (inline SVG), the paper's points as circles.
std::string CurvesSvg(const std::vector<Table1Run>& runs) {
  const double w = 720, h = 360, left = 50, bottom = 30, top = 10, right = 10;
  int max_frames = 50;
  for (const Table1Run& r : runs) max_frames = std::max<int>(max_frames, static_cast<int>(r.curve_percent.size()));
  auto X = [&](double frame) { return left + (frame - 1) / std::max(1, max_frames - 1) * (w - left - right); };
  auto Y = [&](double percent) { return h - bottom - percent / 100.0 * (h - bottom - top); };
  std::ostringstream s;
  s << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << w << "\" height=\"" << h << "\">"
    << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>";
  for (int p = 0; p <= 100; p += 20) {
    s << "<line x1=\"" << left << "\" x2=\"" << w - right << "\" y1=\"" << Y(p) << "\" y2=\"" << Y(p)
      << "\" stroke=\"#ddd\"/><text x=\"" << left - 6 << "\" y=\"" << Y(p) + 4
      << "\" font-size=\"11\" text-anchor=\"end\">" << p << " %</text>";
  }
  for (int f : {1, 20, 50}) {
    s << "<line x1=\"" << X(f) << "\" x2=\"" << X(f) << "\" y1=\"" << Y(0) << "\" y2=\"" << Y(100)
      << "\" stroke=\"#eee\"/><text x=\"" << X(f) << "\" y=\"" << h - 10
      << "\" font-size=\"11\" text-anchor=\"middle\">" << f << "</text>";
  }
  const std::vector<PaperTable1Row>& paper = PaperTable1();
  for (size_t k = 0; k < paper.size(); ++k) {
    for (const Table1Run& r : RunsOf(runs, paper[k].kind)) {
      s << "<polyline fill=\"none\" stroke-opacity=\"0.6\" stroke=\"" << kColours[k] << "\" points=\"";
      for (size_t i = 0; i < r.curve_percent.size(); ++i) s << X(i + 1.0) << "," << Y(r.curve_percent[i]) << " ";
      s << "\"/>";
    }
    for (int i = 0; i < 3; ++i) {
      s << "<circle cx=\"" << X(kTable1Frames[i]) << "\" cy=\"" << Y(paper[k].after_percent[i])
        << "\" r=\"4\" fill=\"white\" stroke=\"" << kColours[k] << "\" stroke-width=\"2\"/>";
    }
    s << "<text x=\"" << w - 120 << "\" y=\"" << Y(40 - 8.0 * k) << "\" font-size=\"12\" fill=\"" << kColours[k]
      << "\">" << paper[k].kind << "</text>";
  }
  s << "<text x=\"" << (w + left) / 2 << "\" y=\"" << h - 1
    << "\" font-size=\"11\" text-anchor=\"middle\">frames (circles: the paper)</text></svg>";
  return s.str();
}

std::string Html(const json& j, const std::vector<Table1Run>& runs, const std::string& markdown, int seeds) {
  std::ostringstream h;
  h << "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>romunect: table 1</title><style>"
       "body{font-family:sans-serif;margin:2em;max-width:1100px}table{border-collapse:collapse;margin:1em 0}"
       "td,th{border:1px solid #bbb;padding:4px 10px;text-align:right}th{background:#eee}</style></head><body>"
    << "<h1>Table 1: completeness of the fused depth map</h1><p>Mean ± standard deviation over " << seeds
    << " seeds per kind. Frame 1 is the first frame with the pile in the measurable range; the denominator "
       "is the whole 150 x 80 mm region.</p><table><tr><th>object</th><th>frames</th><th>paper [%]</th>"
       "<th>ours [%]</th></tr>";
  for (const PaperTable1Row& row : PaperTable1()) {
    const json& k = j[row.kind];
    for (int i = 0; i < 3; ++i) {
      h << "<tr>" << (i == 0 ? "<th rowspan=\"3\">" + std::string(row.kind) + "</th>" : "") << "<td>"
        << kTable1Frames[i] << "</td><td>" << Format("%.2f", row.after_percent[i]) << "</td><td>"
        << Cell(k[kFrameKeys[i]], k["spread"][kFrameKeys[i]]) << "</td></tr>";
    }
  }
  h << "</table><h2>Completeness per frame, every run</h2>" << CurvesSvg(runs)
    << "<h2>Accuracy against ground truth</h2><table><tr><th>object</th><th>all frames [%]</th><th>MAE [mm]</th>"
       "<th>RMSE [mm]</th><th>within 1 mm [%]</th></tr>";
  for (const PaperTable1Row& row : PaperTable1()) {
    const json& k = j[row.kind];
    h << "<tr><th>" << row.kind << "</th><td>" << Format("%.1f", k["all_frames"].get<double>()) << "</td><td>"
      << Format("%.3f", k["mae_mm"].get<double>()) << "</td><td>" << Format("%.3f", k["rmse_mm"].get<double>())
      << "</td><td>" << Format("%.1f", k["within_1mm_percent"].get<double>()) << "</td></tr>";
  }
  h << "</table><h2>table1.md</h2><pre>" << markdown << "</pre></body></html>\n";
  return h.str();
}

}  // namespace

const std::vector<PaperTable1Row>& PaperTable1() {
  static const std::vector<PaperTable1Row> kRows = {{"keys", {19.69, 75.53, 88.67}},
                                                    {"pillbox", {14.97, 56.06, 86.31}},
                                                    {"puzzle", {20.59, 61.38, 86.31}},
                                                    {"lego", {15.19, 74.89, 89.61}}};
  return kRows;
}

const PaperTable1Row* FindPaperTable1Row(const std::string& kind) {
  const char* name = nullptr;
  switch (sim::GeneratedKindFromName(kind, "kind")) {
    case sim::ObjectKind::kKey: name = "keys"; break;
    case sim::ObjectKind::kPillBox: name = "pillbox"; break;
    case sim::ObjectKind::kPuzzlePiece: name = "puzzle"; break;
    case sim::ObjectKind::kLegoBrick: name = "lego"; break;
    default: return nullptr;
  }
  for (const auto& row : PaperTable1()) {
    if (std::string(row.kind) == name) return &row;
  }
  return nullptr;
}

Table1Summary RunTable1(const Table1Options& o) {
  if (o.seeds < 1 || o.seeds > 20) throw InputError("--seeds", "", std::to_string(o.seeds) + " is outside 1..20");
  if (o.threads < 1 || o.threads > 64) {
    throw InputError("--threads", "", std::to_string(o.threads) + " is outside 1..64");
  }
  for (const int n : {o.keys, o.pillbox, o.puzzle, o.lego}) {
    if (n < 1 || n > 60) throw InputError("objects per kind", "", std::to_string(n) + " is outside 1..60");
  }
  RunFolder folder(o.out.empty() ? DefaultDir() : o.out, "--out", "experiment table1");
  folder.Begin();
  Table1Summary summary;
  const int total = static_cast<int>(PaperTable1().size()) * o.seeds;
  for (const PaperTable1Row& row : PaperTable1()) {
    for (int seed = 1; seed <= o.seeds; ++seed) {
      std::fprintf(stderr, "table1: scan %d/%d: %s, seed %d\n", static_cast<int>(summary.runs.size()) + 1, total,
                   row.kind, seed);
      summary.runs.push_back(RunOne(o, row.kind, static_cast<unsigned>(seed), folder.work_dir()));
      const Table1Run& r = summary.runs.back();
      std::fprintf(stderr,
                   "table1: %s seed %d: %.1f / %.1f / %.1f %% after 1 / 20 / 50 frames (paper %.1f / %.1f / %.1f)\n",
                   row.kind, seed, r.after_percent[0], r.after_percent[1], r.after_percent[2], row.after_percent[0],
                   row.after_percent[1], row.after_percent[2]);
    }
  }
  json j;
  for (const PaperTable1Row& row : PaperTable1()) j[row.kind] = KindJson(RunsOf(summary.runs, row.kind), row);
  j["format"] = "romunect-table1";
  j["version"] = 1;
  j["options"] = {{"seeds", o.seeds},
                  {"rig", o.rig},
                  {"threads", o.threads},
                  {"objects_keys", o.keys},
                  {"objects_pillbox", o.pillbox},
                  {"objects_puzzle", o.puzzle},
                  {"objects_lego", o.lego}};
  summary.markdown = Markdown(j, o.seeds);
  WriteTextAtomically(folder.work_dir() / "table1.md", summary.markdown);
  WriteTextAtomically(folder.work_dir() / "table1.json", j.dump(1) + "\n");
  WriteTextAtomically(folder.work_dir() / "table1.html", Html(j, summary.runs, summary.markdown, o.seeds));
  folder.Commit();
  summary.dir = folder.dir();
  return summary;
}

}  // namespace romunect::jobs
