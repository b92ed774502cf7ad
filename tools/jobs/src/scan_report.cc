#include "romunect/tools/jobs/scan_report.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/fusion/outputs.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/image_io.h"
#include "romunect/tools/jobs/table1.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

// The paper's table 1 reports completeness after 1, 20 and 50 frames.
constexpr int kTableFrames[] = {1, 20, 50};

// Frames are counted from the first that holds depth (SampleDepths' threshold), as the
// paper counts fused depth maps: the descent from 400 mm starts above the focused range.
int FirstFrameWithDepth(const ScanReport& r) {
  for (size_t i = 0; i < r.valid_fraction_per_frame.size(); ++i) {
    if (r.valid_fraction_per_frame[i] >= SampleDepths::kMinValidFraction) return static_cast<int>(i);
  }
  return 0;
}

json CompletenessAfter(const ScanReport& r, int frames) {
  const std::optional<double> c = Table1Completeness(r, frames);
  return c ? json(*c) : json(nullptr);
}

// The paper's row for a scan of one of its kinds; null otherwise.
const PaperTable1Row* PaperRow(const ScanReport& r) {
  return r.options.kinds.size() == 1 ? FindPaperTable1Row(r.options.kinds[0]) : nullptr;
}

// Figure 2 shows no value in white, as the paper does.
const cv::Vec3b kWhite(255, 255, 255);

// A depth map (CV_32F, metres, 0 or NaN = none) over its own range.
cv::Mat ColourDepth(const cv::Mat& depth_m) {
  double lo, hi;
  fusion::ValueRange(depth_m, /*zero_is_empty=*/true, &lo, &hi);
  return fusion::ColourMapped(depth_m, lo, hi, /*flip_rows=*/false, /*zero_is_empty=*/true, kWhite);
}

// One captioned panel, scaled to `height_px` rows.
cv::Mat Panel(const cv::Mat& coloured, int height_px, const std::string& caption) {
  cv::Mat scaled;
  const double s = static_cast<double>(height_px) / coloured.rows;
  cv::resize(coloured, scaled, cv::Size(), s, s, s < 1.0 ? cv::INTER_AREA : cv::INTER_NEAREST);
  cv::Mat panel(scaled.rows + 30, scaled.cols, CV_8UC3, cv::Scalar(255, 255, 255));
  scaled.copyTo(panel(cv::Rect(0, 30, scaled.cols, scaled.rows)));
  cv::putText(panel, caption, cv::Point(4, 20), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  return panel;
}

// Figure 2 of the paper: two single depth maps (camera views) and the fused height map.
cv::Mat Figure2(const ScanReport& r) {
  const int height_px = 300;
  std::vector<cv::Mat> panels;
  for (const auto& [depth, index] : {std::pair{&r.sample_depths.first_m, r.sample_depths.first_index},
                                     std::pair{&r.sample_depths.last_m, r.sample_depths.last_index}}) {
    if (depth->empty()) continue;
    panels.push_back(Panel(ColourDepth(*depth), height_px,
                           "frame " + std::to_string(index) + ": " +
                               Format("%.1f %% valid", 100.0 * cv::countNonZero(*depth) / depth->total())));
  }
  double lo, hi;
  fusion::ValueRange(r.height_m, /*zero_is_empty=*/false, &lo, &hi);
  const cv::Mat fused = fusion::ColourMapped(r.height_m, lo, hi, /*flip_rows=*/true, /*zero_is_empty=*/false, kWhite);
  panels.push_back(Panel(fused, height_px,
                         "fused, " + std::to_string(r.fusion.completeness_per_frame.size()) +
                             " frames: " + Format("%.1f %% complete", 100.0 * fusion::Completeness(r.height_m))));
  for (cv::Mat& p : panels) cv::copyMakeBorder(p, p, 0, 0, 0, 12, cv::BORDER_CONSTANT, cv::Scalar(255, 255, 255));
  cv::Mat figure;
  cv::hconcat(panels, figure);
  return figure;
}

// Signed error of the fused map against ground truth, +-2 mm mapped to blue..red.
cv::Mat ErrorPicture(const cv::Mat& fused_m, const cv::Mat& gt_m) {
  cv::Mat error(fused_m.size(), CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  for (int r = 0; r < fused_m.rows; ++r) {
    for (int c = 0; c < fused_m.cols; ++c) {
      const float f = fused_m.at<float>(r, c), g = gt_m.at<float>(r, c);
      if (std::isfinite(f) && std::isfinite(g)) error.at<float>(r, c) = f - g;
    }
  }
  return Panel(fusion::ColourMapped(error, -2e-3, 2e-3, /*flip_rows=*/true, /*zero_is_empty=*/false, kWhite), 320,
               "fused - ground truth, -2 mm (blue) .. +2 mm (red)");
}

std::string Base64(const std::vector<uchar>& bytes) {
  static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  for (size_t i = 0; i < bytes.size(); i += 3) {
    const uint32_t n = (uint32_t{bytes[i]} << 16) | (i + 1 < bytes.size() ? uint32_t{bytes[i + 1]} << 8 : 0) |
                       (i + 2 < bytes.size() ? uint32_t{bytes[i + 2]} : 0);
    out += table[(n >> 18) & 63];
    out += table[(n >> 12) & 63];
    out += i + 1 < bytes.size() ? table[(n >> 6) & 63] : '=';
    out += i + 2 < bytes.size() ? table[n & 63] : '=';
  }
  return out;
}

std::string InlinePng(const fs::path& file) {
  const cv::Mat image = cv::imread(file.string(), cv::IMREAD_COLOR);
  if (image.empty()) return "";
  std::vector<uchar> png;
  cv::imencode(".png", image, png);
  return "<img src=\"data:image/png;base64," + Base64(png) + "\" alt=\"" + file.filename().string() + "\">";
}

// Text for HTML: the markup characters escaped (scene and mesh paths are the user's).
std::string Escape(const std::string& text) {
  std::string out;
  for (const char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string Html(const ScanReport& r, const fs::path& dir) {
  const fusion::HeightMapMetrics& m = *r.fusion.metrics;
  const json j = json::parse(ScanReportJson(r));
  std::ostringstream h;
  auto cell = [](const json& v, const char* format, double scale = 1.0) {
    return v.is_null() ? std::string("&ndash;") : Format(format, scale * v.get<double>());
  };
  h << "<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>romunect scan</title><style>"
       "body{font-family:sans-serif;margin:2em;max-width:1300px}table{border-collapse:collapse;margin:1em 0}"
       "td,th{border:1px solid #bbb;padding:4px 10px;text-align:right}th{background:#eee}"
       "img{max-width:100%;border:1px solid #ddd;margin:4px 0}</style></head><body>";
  h << "<h1>romunect scan</h1><p>" << Escape(r.scan_description) << "<br>rig <b>" << Escape(r.rig_name) << "</b>, seed "
    << r.seed << ", " << r.objects << " objects, " << r.options.threads << " threads (fusion " << r.fusion.threads
    << "), " << r.samples << " sample(s) per pixel.<br>Depth correction: " << Escape(r.depth_correction) << "</p>";
  h << "<h2>Completeness (the paper's table 1)</h2><table><tr><th>frames</th>";
  for (int n : kTableFrames) h << "<th>" << n << "</th>";
  h << "<th>all (" << r.fusion.completeness_per_frame.size() << ")</th></tr><tr><th>completeness [%]</th>";
  for (int n : kTableFrames) h << "<td>" << cell(CompletenessAfter(r, n), "%.2f", 100.0) << "</td>";
  h << "<td>" << Format("%.2f", 100.0 * m.completeness) << "</td></tr>";
  if (const PaperTable1Row* paper = PaperRow(r)) {
    h << "<tr><th>the paper (" << paper->kind << ") [%]</th>";
    for (double v : paper->after_percent) h << "<td>" << Format("%.2f", v) << "</td>";
    h << "<td>&ndash;</td></tr>";
  }
  h << "</table>";
  if (r.cells_above_box + r.cells_below_box > 0) {
    h << "<p><b>Warning:</b> " << r.cells_above_box << " cells lie above and " << r.cells_below_box
      << " below the fusion box (ground truth): fusion could not hold them.</p>";
  }
  h << "<p>Frames are counted from "
    << "frame " << FirstFrameWithDepth(r)
    << ", the first with at least 5 % valid depth pixels (the descent starts above the focused "
    << "range).</p>";
  h << InlinePng(dir / "completeness.png");
  h << "<h2>Accuracy against ground truth</h2><table><tr><th>RMSE [mm]</th><th>MAE [mm]</th><th>within 1 mm</th>"
       "<th>cells compared</th></tr><tr><td>"
    << Format("%.3f", m.rmse_mm) << "</td><td>" << Format("%.3f", m.mae_mm) << "</td><td>"
    << Format("%.1f %%", 100.0 * m.within_1mm) << "</td><td>" << m.compared_cells << "</td></tr></table>";
  h << "<h2>Depth maps</h2>" << InlinePng(dir / "figure2.png") << InlinePng(dir / "fused_depth.png")
    << InlinePng(dir / "error.png");
  h << "<h2>Pick</h2><p>" << Escape(r.pick.BriefReport()) << "</p>" << InlinePng(dir / "overview.png");
  h << "<h2>Timings</h2><table><tr><th>stage</th><th>seconds</th></tr>";
  for (const auto& [stage, seconds] : j["timings_s"].items()) {
    h << "<tr><td style=\"text-align:left\">" << Escape(stage) << "</td><td>" << Format("%.3f", seconds.get<double>())
      << "</td></tr>";
  }
  h << "</table><p>Simulated approach " << Format("%.2f s", j["realtime"]["simulated_s"].get<double>())
    << ", scan loop " << Format("%.2f s", j["realtime"]["loop_wall_s"].get<double>())
    << " of wall time: " << Format("%.2fx real time", j["realtime"]["factor"].get<double>()) << ", "
    << Format("%.2f s", j["realtime"]["loop_cpu_s"].get<double>()) << " of CPU on "
    << j["realtime"]["cores"].get<unsigned>() << " cores.</p>";
  h << "<h2>report.json</h2><pre>" << Escape(j.dump(1)) << "</pre></body></html>\n";
  return h.str();
}

}  // namespace

std::string ScanOptionsJson(const ScanJobOptions& a) {
  // `romunect scan` with these repeats the run (same bytes).
  const json j = {{"scene", a.scene},
                  {"saved_scene", a.saved_scene},
                  {"seed", a.seed},
                  {"objects", a.objects},
                  {"kinds", a.kinds},
                  {"one_layer", a.one_layer},
                  {"meshes", a.meshes},
                  {"mesh_unit_m", a.mesh_unit_m},
                  {"mesh_material", a.mesh_material},
                  {"rig", a.rig},
                  {"calibration", a.calibration},
                  {"threads", a.threads},
                  {"samples", a.samples},
                  {"voxel_m", a.voxel_m},
                  {"sweep", a.sweep},
                  {"ideal_depth", a.ideal_depth},
                  {"compress_frames", a.compress_frames}};
  return j.dump();
}

std::string ScanReportJson(const ScanReport& r) {
  ROMUNECT_CHECK(r.fusion.metrics.has_value());
  const fusion::HeightMapMetrics& m = *r.fusion.metrics;
  json j;
  j["format"] = "romunect-scan-report";
  j["version"] = 1;
  std::ostringstream started;
  started << std::put_time(std::gmtime(&r.started_at), "%Y-%m-%dT%H:%M:%SZ");
  j["started_at"] = started.str();
  j["scan"] = r.scan_description;
  j["rig"] = r.rig_name;
  j["seed"] = r.seed;
  j["objects"] = r.objects;
  j["samples_per_pixel"] = r.samples;
  j["depth_correction"] = r.depth_correction;
  // injected errors, the calibration's errors against the truth and the map's, side by side
  const CalibrationErrors& e = r.calibration_errors;
  j["calibration_check"] = {{"injected", r.perturbation},
                            {"hand_eye_error_deg", e.hand_eye_deg},
                            {"hand_eye_error_mm", e.hand_eye_mm},
                            {"focal_error_pct", e.focal_pct},
                            {"principal_point_error_px", e.principal_px}};
  j["options"] = json::parse(ScanOptionsJson(r.options));
  j["frames"] = r.fusion.completeness_per_frame.size();
  json table = json::object();
  for (int n : kTableFrames) table["after_" + std::to_string(n)] = CompletenessAfter(r, n);
  j["table1_completeness"] = table;
  j["table1_first_frame"] = FirstFrameWithDepth(r);  // frames counted from this one (holds depth)
  if (const PaperTable1Row* paper = PaperRow(r)) {
    j["table1_paper"] = {{"kind", paper->kind},
                         {"after_1", paper->after_percent[0] / 100},
                         {"after_20", paper->after_percent[1] / 100},
                         {"after_50", paper->after_percent[2] / 100}};
  }
  j["fusion_box"] = {{"min_z_m", r.box_min_z_m},
                     {"max_z_m", r.box_max_z_m},
                     {"cells_above", r.cells_above_box},
                     {"cells_below", r.cells_below_box},
                     {"measured_pile_top_m", r.pile_top_m ? json(*r.pile_top_m) : json(nullptr)}};
  j["valid_fraction_per_frame"] = r.valid_fraction_per_frame;
  j["accuracy"] = {{"completeness", m.completeness}, {"rmse_mm", m.rmse_mm}, {"mae_mm", m.mae_mm},
                   {"within_1mm", m.within_1mm},     {"cells", m.cells},     {"compared_cells", m.compared_cells}};
  json pick = {{"grasp_found", r.pick.grasp_found},
               {"contact", r.pick.contact},
               {"object", r.pick.object},
               {"success", r.pick.success},
               {"failure", r.pick.failure}};
  if (r.pick.grasp_found) {
    const auto& g = r.pick.grasp;
    pick["grasp_point_W"] = {g.p_W.x(), g.p_W.y(), g.p_W.z()};
    pick["grasp_normal_W"] = {g.normal_W.x(), g.normal_W.y(), g.normal_W.z()};
    pick["grasp_plane_rms_mm"] = 1e3 * g.rms_m;
  }
  j["pick"] = pick;
  const sim::ScanStats& s = r.scan_stats;
  double fusion_s = 0.0;
  for (double ms : r.fusion.insert_ms) fusion_s += ms / 1e3;
  for (double ms : r.completeness_each_ms) fusion_s += ms / 1e3;
  j["timings_s"] = {{"settle_wall", s.settle.wall_s},
                    {"setup", s.setup_s},
                    {"physics", s.physics_s},
                    {"rendering", s.render_s},
                    {"imaging (IR synthesis + depth engine)", s.imaging_s},
                    {"fusion (insert + completeness per frame)", fusion_s},
                    {"frame directory writing (own thread)", r.write_s},
                    {"fusion waiting for the simulator (pipelined)", r.wait_s},
                    {"picking", r.pick.wall_s},
                    {"total", r.total_wall_s}};
  j["realtime"] = {{"simulated_s", s.simulated_s},
                   {"loop_wall_s", r.loop_wall_s},
                   {"loop_cpu_s", r.loop_cpu_s},
                   {"cores", std::thread::hardware_concurrency()},
                   {"factor", r.loop_wall_s > 0 ? s.simulated_s / r.loop_wall_s : 0.0}};
  j["fusion"] = json::parse(fusion::FusionReportJson(r.fusion));
  j["settle"] = s.settle.BriefReport();
  j["tracking"] = {{"max_position_error_mm", 1e3 * s.tracking.max_position_error_m},
                   {"rms_position_error_mm", 1e3 * s.tracking.rms_position_error_m},
                   {"max_angle_error_deg", s.tracking.max_angle_error_rad * 180.0 / M_PI}};
  j["outputs"] = {"frames/",          "scene.json",       "fused_depth.exr", "fused_depth.png",
                  "fused_points.ply", "gt_height.exr",    "figure2.png",     "error.png",
                  "overview.png",     "completeness.png", "report.html"};
  return j.dump(1) + "\n";
}

int Table1FirstFrame(const ScanReport& r) { return FirstFrameWithDepth(r); }

void CountCellsOutsideBox(const cv::Mat& gt_height_m, double min_z_m, double max_z_m, int* above, int* below) {
  ROMUNECT_CHECK(gt_height_m.type() == CV_32F && above != nullptr && below != nullptr);
  *above = *below = 0;
  for (auto it = gt_height_m.begin<float>(); it != gt_height_m.end<float>(); ++it) {
    if (std::isnan(*it)) continue;
    *above += *it > max_z_m;
    *below += *it < min_z_m;
  }
}

std::optional<double> Table1Completeness(const ScanReport& r, int frames) {
  const std::vector<double>& curve = r.fusion.completeness_per_frame;
  const int last = FirstFrameWithDepth(r) + frames - 1;
  if (static_cast<int>(curve.size()) <= last) return std::nullopt;
  return curve[last];
}

void WriteScanOutputs(const fs::path& dir, const ScanReport& r) {
  WriteHeightMapExr(dir / "fused_depth.exr", r.height_m, r.fusion.geometry);
  fusion::WriteHeightMapPicture(dir / "fused_depth.png", r.height_m, r.fusion.geometry);
  fusion::WriteHeightMapPly(dir / "fused_points.ply", r.height_m, r.fusion.geometry);
  WriteHeightMapExr(dir / "gt_height.exr", r.gt_height_m, r.fusion.geometry);
  fusion::WriteCompletenessPlot(dir / "completeness.png", r.fusion.completeness_per_frame);
  WritePicture(dir / "figure2.png", Figure2(r));
  WritePicture(dir / "error.png", ErrorPicture(r.height_m, r.gt_height_m));
  if (!r.overview.empty()) WritePicture(dir / "overview.png", r.overview);
  WriteTextAtomically(dir / "report.json", ScanReportJson(r));
  WriteTextAtomically(dir / "report.html", Html(r, dir));
}

std::string ScanSummaryText(const ScanSummary& summary) {
  const ScanReport& r = summary.report;
  const fs::path& run_dir = summary.run_dir;
  const fusion::HeightMapMetrics& m = *r.fusion.metrics;
  std::ostringstream s;
  s << "completeness after 1 / 20 / 50 frames (from frame " << FirstFrameWithDepth(r)
    << ", the first with >= 5 % valid depth):";
  for (int n : kTableFrames) {
    const json v = CompletenessAfter(r, n);
    s << (v.is_null() ? std::string(" -") : Format(" %.1f %%", 100.0 * v.get<double>()));
  }
  s << "   (all " << r.fusion.completeness_per_frame.size() << " frames: " << Format("%.1f %%", 100.0 * m.completeness)
    << ")\n";
  const CalibrationErrors& e = r.calibration_errors;
  s << "calibration used vs truth: hand-eye " << Format("%.3f deg %.3f mm", e.hand_eye_deg, e.hand_eye_mm) << ", focal "
    << Format("%+.3f %%", e.focal_pct) << ", principal point " << Format("%.2f px", e.principal_px)
    << " (injected: " << r.perturbation << ")\n";
  if (const PaperTable1Row* paper = PaperRow(r)) {
    s << "the paper's table 1 (" << paper->kind << "):" << Format(" %.1f %%", paper->after_percent[0])
      << Format(" %.1f %%", paper->after_percent[1]) << Format(" %.1f %%", paper->after_percent[2]) << "\n";
  }
  if (r.cells_above_box + r.cells_below_box > 0) {
    s << "warning: " << r.cells_above_box << " cells lie above and " << r.cells_below_box
      << " below the fusion box (ground truth): fusion could not hold them\n";
  }
  s << "accuracy vs ground truth: RMSE " << Format("%.3f", m.rmse_mm) << " mm, MAE " << Format("%.3f", m.mae_mm)
    << " mm, " << Format("%.1f %%", 100.0 * m.within_1mm) << " within 1 mm\n";
  s << "pick: " << r.pick.BriefReport() << "\n";
  const double simulated = r.scan_stats.simulated_s;
  s << "time: scan loop " << Format("%.2f s", r.loop_wall_s) << " for " << Format("%.2f s", simulated) << " simulated ("
    << Format("%.2fx real time", r.loop_wall_s > 0 ? simulated / r.loop_wall_s : 0.0) << ", "
    << Format("%.1f", r.loop_wall_s > 0 ? r.loop_cpu_s / r.loop_wall_s : 0.0) << " cores busy), total "
    << Format("%.1f s", r.total_wall_s) << "\n";
  s << "wrote " << run_dir.string() << "/ (report.html, report.json, figure2.png, fused_depth.*, frames/)\n";
  return s.str();
}

}  // namespace romunect::jobs
