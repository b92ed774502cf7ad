// `romunect dataset`: ground-truth datasets in the BOP-scenewise format (the BOP benchmark's
// and its toolkit's), for depth completion and 6D pose estimation on structured-light depth.
// Each scene is a settled random pile seen from the arm's approach trajectory and from random
// reachable views; every image carries the simulated sensor's IR and depth, the ideal depth,
// each object's pose and its full and visible masks. Layout, fields and units: docs/datasets.md.
//
// Scene i is a function of (settings, i) alone, so shards, orders, machines and resumed runs
// write the same bytes. A scene is built as `<scene>.incomplete/` and renamed when complete;
// a rerun skips complete scenes and redoes incomplete ones. The folder's settings
// (dataset.json) are fixed by the first run: a rerun with other settings is refused.
// Units in files are BOP's (millimetres); in memory SI.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace romunect::jobs {

struct DatasetOptions {
  std::string out;            // the dataset's root folder
  int scenes = 1;             // scenes first_scene .. first_scene + scenes - 1
  int first_scene = 0;        // index of the first scene (extending a dataset)
  std::string shard = "0/1";  // "I/N": this process writes the scenes i with i % N == I
  // --- settings: fixed per output folder (dataset.json) ---
  uint32_t seed = 1;
  std::string rig = "romunect";  // preset name or rig JSON file
  std::vector<std::string> kinds = {"key", "pill_box", "puzzle_piece", "lego_brick", "gear"};
  std::string objects = "4-8";  // objects per scene, "A-B" (or "A"), drawn per scene
  int variants = 4;             // generated meshes per kind: obj_id per (kind, variant)
  std::string views = "both";   // approach, random or both
  int views_per_scene = 8;      // random views per scene
  int every = 4;                // every k-th frame of the 30 Hz approach
  // --- how it runs (not settings) ---
  int threads = 2;
  bool quiet = false;  // no progress lines
};

struct DatasetSummary {
  std::filesystem::path dir;
  int scenes_written = 0;
  int scenes_skipped = 0;  // complete already (resume)
  int images = 0;          // written by this run
  int annotations = 0;     // object instances annotated (scene_gt entries) by this run
  int models = 0;          // object models (obj_ids) of the dataset
  double mb_written = 0.0;
  double wall_s = 0.0;
  double cpu_s = 0.0;        // this process's CPU time over the whole run
  double image_cpu_s = 0.0;  // CPU of the scenes' loop: everything per image, scene set-up included
  // Where it went (process CPU, all threads): the scenes' set-up (world, settling, views),
  // rendering, IR synthesis and depth engine, the four images' PNGs, the silhouette renders,
  // the masks' PNGs and counts.
  struct CpuSeconds {
    double scene = 0, render = 0, imaging = 0, images = 0, silhouettes = 0, masks = 0;
    void Add(const CpuSeconds& o) {
      scene += o.scene, render += o.render, imaging += o.imaging, images += o.images;
      silhouettes += o.silhouettes, masks += o.masks;
    }
  } cpu;
  std::string Text() const;
};

// Validates every option (InputError naming the option, before any file is written), then
// writes the shard's scenes that are not complete yet. Progress goes to stderr.
DatasetSummary RunDataset(const DatasetOptions& options);

struct DatasetCheckSummary {
  int scenes = 0, images = 0, annotations = 0;
  // Visible pixels that disagree with the model alone among agreeing neighbours: a ray through
  // a crack between two triangles (vertices rounded to float) in one of the two renders. Not
  // problems: a wrong pose, model or depth shows in whole patches.
  int isolated_pixels = 0;
  int incomplete_scenes = 0;          // <scene>.incomplete folders: not checked (a rerun completes them)
  std::vector<std::string> problems;  // "<file>: <rule broken>", empty when the dataset is valid
  std::string Text() const;
};

// Checks a dataset written by RunDataset: JSON keys and types, image sizes and types, masks
// (mask_visib inside mask, bounding boxes and pixel counts as scene_gt_info says, visib_fract
// = px_count_visib / px_count_all) and geometry: every visible pixel of an object, its model
// (models/) rendered at its ground-truth pose, agrees with depth_gt within 0.1 mm (but on the
// edges of the model's render, and lone pixels: isolated_pixels). Throws
// InputError when `dir` holds no dataset; every other failure is a problem in the summary.
DatasetCheckSummary CheckDataset(const std::string& dir, int threads = 2);

}  // namespace romunect::jobs
