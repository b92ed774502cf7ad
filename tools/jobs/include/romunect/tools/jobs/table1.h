// The paper's experiment (its table 1), `romunect experiment table1`: a bin of one kind of object
// (keys, pill boxes, puzzle pieces, lego bricks) in about one layer, scanned during the approach
// (`romunect scan`'s job, the approach planned for coverage), N seeds per kind; completeness of
// the fused 150 x 80 mm map after 1, 20 and 50 frames counted as the paper counts (frame 1: the
// first frame with the pile in the measurable range; the whole region as the denominator), and
// accuracy against ground truth. Writes table1.md, table1.json, table1.html (the paper's numbers
// beside ours, every run's completeness curve in one plot) and a run folder per scan (without
// frames) into one RunFolder.
#pragma once

#include <array>
#include <filesystem>
#include <string>
#include <vector>

namespace romunect::jobs {

// One row of the paper's table 1: completeness (%) after 1, 20 and 50 frames.
struct PaperTable1Row {
  const char* kind;  // "keys", "pillbox", "puzzle", "lego"
  std::array<double, 3> after_percent;
};
// The paper's four rows, in its order.
const std::vector<PaperTable1Row>& PaperTable1();
// The row of a kind the scan's --kinds names (short or ToString names); null for others (gear).
const PaperTable1Row* FindPaperTable1Row(const std::string& kind);

struct Table1Options {
  int seeds = 5;    // 1..20, seeds 1..N per kind
  std::string out;  // "": runs/table1-<date>-<time>
  int threads = 2;  // per scan
  std::string rig = "romunect";
  // Objects per bin, by kind, in one layer (the paper's bins, sim::PileOptions::one_layer): as
  // many as the default bin's 120 x 55 mm inner floor holds side by side by their bounding boxes.
  int keys = 2, pillbox = 4, puzzle = 4, lego = 8;
};

struct Table1Run {
  std::string kind;
  unsigned seed = 0;
  std::array<double, 3> after_percent{};  // NaN when the scan had fewer frames
  double completeness_percent = 0.0;      // after all frames
  double mae_mm = 0.0, rmse_mm = 0.0, within_1mm_percent = 0.0;
  int frames = 0;
  std::vector<double> curve_percent;  // completeness per frame from frame 1 (as counted)
};

struct Table1Summary {
  std::filesystem::path dir;
  std::vector<Table1Run> runs;  // kind by kind, seed by seed
  std::string markdown;         // table1.md
};

// Validates the options (InputError naming the option, before any work), runs the scans,
// writes the folder and returns the runs. Progress goes to stderr.
Table1Summary RunTable1(const Table1Options& options);

}  // namespace romunect::jobs
