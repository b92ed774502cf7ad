// Frame directories: the one on-disk format for simulated, recorded and user-supplied
// captures (docs/frame-directory.md). A directory holds frames.json and the images it names:
//
//   frames.json   {"format": "romunect-frames", "version": 1,
//                  "camera": {"width", "height", "fx", "fy", "cx", "cy",
//                             "distortion": [k1, k2, p1, p2, k3]},
//                  "frames": [{"index", "time_s", "depth": "depth/000000.exr",
//                              "T_W_C": [16 numbers, row-major 4x4, camera to world],
//                              optional "ir", "raw", "gt_depth", "color", "T_B_H"}],
//                  optional "region_W": [xmin, ymin, zmin, xmax, ymax, zmax],
//                  optional "color_camera": {the camera's keys, "T_C_RGB": [16 numbers]}}
//   depth/*.exr   metric depth, float32 EXR channel "Y", metres along the optical axis, 0 = none
//   ir/*.png      IR image, 16-bit PNG          raw/*.png  device raw depth, 16-bit PNG
//   gt_depth/*.exr ground-truth depth, like depth/
//   color/*.png   colour image, 8-bit RGB PNG of the color_camera's size (needs "color_camera")
//
// Unknown keys are kept (and written back by the writer) and otherwise ignored.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/frame.h"
#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/world_box.h"

namespace romunect {

inline constexpr const char* kFrameDirectoryFormat = "romunect-frames";
inline constexpr int kFrameDirectoryVersion = 1;

// One entry of frames.json. Image paths are relative to the directory; "" = absent.
struct FrameRecord {
  int index = 0;
  double time_s = 0.0;
  std::string depth, ir, raw, gt_depth, color;
  std::optional<Pose> T_W_C;
  std::optional<Pose> T_B_H;
  std::string extra_json = "{}";  // unknown keys of this entry, kept verbatim
};

struct FrameDirectoryManifest {
  CameraModel camera;
  std::vector<FrameRecord> frames;
  // The region the capture was taken of ("region_W"): `romunect fuse` fuses over it unless told
  // otherwise. `romunect scan` records its fusion box; captures without one leave it out.
  std::optional<WorldBox> region_W;
  // The colour camera beside the depth camera ("color_camera"), when frames carry colour images.
  std::optional<ColorCamera> color_camera;
  std::string extra_json = "{}";  // unknown top-level keys, kept verbatim
};

// Reads and validates <dir>/frames.json: format and version, camera, every entry's fields
// and poses (rigid), indices unique and times non-decreasing. Throws InputError naming the
// file and the field (e.g. "frames[3].T_W_C") on anything wrong. Images are not opened.
FrameDirectoryManifest ReadFrameDirectoryManifest(const std::filesystem::path& dir);

// What a loader does with per-pixel junk in a depth image (NaN, inf, negative values).
enum class InvalidDepthPolicy {
  kReject,  // throw InputError naming the file and the first bad pixel
  kSkip,    // set the pixel to 0 (no measurement) and count it
};

// Loads the images of manifest.frames[i], checking each file's size, type and values.
// Throws InputError naming the file. Pixels fixed under kSkip are added to *skipped_pixels.
Frame LoadFrame(const std::filesystem::path& dir, const FrameDirectoryManifest& manifest, size_t i,
                InvalidDepthPolicy policy = InvalidDepthPolicy::kReject, size_t* skipped_pixels = nullptr);

// Where the writer puts a frame's image, relative to the directory: "<folder>/<6-digit
// index>.<extension>" (folder "depth", "ir", "raw", "gt_depth" or "color").
std::string FrameFile(const char* folder, int index, const char* extension);

// Writes a frame directory frame by frame. Images are written as frames arrive (each
// atomically); frames.json is written by Finish(), atomically, so a directory without
// frames.json is an unfinished one. A directory that already holds frames.json is refused,
// so earlier results are never overwritten.
class FrameDirectoryWriter {
 public:
  // Creates `dir` if needed. Throws InputError if it already holds a frames.json. Images are
  // written with `compression` (image_io.h: kFast keeps up with a 30 Hz loop).
  FrameDirectoryWriter(const std::filesystem::path& dir, const CameraModel& camera,
                       ImageCompression compression = ImageCompression::kCompact);
  // The constructor's refusal, for callers that must check before their work starts: throws
  // InputError if `dir` already holds a frames.json.
  static void CheckCanWrite(const std::filesystem::path& dir);

  // Writes the frame's present images (ir, raw, depth_m, gt_depth_m, color) and records it, with
  // the entry's unknown keys (a JSON object text: a copied entry keeps its own). Images must be
  // camera-sized (color: the colour camera's size, set first) and of the types frame.h documents.
  void Add(const Frame& frame, const std::string& extra_json = "{}");
  // For a resumed capture that replays its source: records the frame as Add does when its files
  // are already in the directory and hold exactly its images (read back and compared pixel by
  // pixel), and returns true; returns false, recording nothing, when any is missing, unreadable or
  // different (the caller then Adds it, which replaces them).
  bool AddIfWritten(const Frame& frame, const std::string& extra_json = "{}");

  // Writes frames.json; the directory is complete from then on. Call once.
  void Finish();

  // Unknown keys to carry over into frames.json (top level), as a JSON object text.
  void SetExtraJson(const std::string& extra_json);
  // The region the frames are of (frames.json's "region_W"). min < max on every axis.
  void SetRegion(const WorldBox& region_W);
  // The colour camera of the frames' colour images (frames.json's "color_camera"). Valid.
  void SetColorCamera(const ColorCamera& color_camera);

  const std::filesystem::path& dir() const { return dir_; }
  size_t size() const { return manifest_.frames.size(); }

 private:
  std::filesystem::path dir_;
  ImageCompression compression_;
  FrameDirectoryManifest manifest_;
  bool finished_ = false;
};

// Writes a manifest as frames.json into dir, atomically (used by the writer and by tools that
// rewrite a manifest).
void WriteFrameDirectoryManifest(const std::filesystem::path& dir, const FrameDirectoryManifest& manifest);

// Plays a frame directory back as a FrameSource. The constructor reads and validates the
// manifest (throws InputError); a frame whose images are missing or invalid is kBadFrame,
// with the loader's message.
class FrameDirectorySource : public FrameSource {
 public:
  explicit FrameDirectorySource(const std::filesystem::path& dir,
                                InvalidDepthPolicy policy = InvalidDepthPolicy::kReject);
  // Plays a manifest already read from `dir`, as given: a caller may drop images it does not
  // need (an entry's gt_depth = "") or open many passes of one directory with one read.
  FrameDirectorySource(const std::filesystem::path& dir, FrameDirectoryManifest manifest,
                       InvalidDepthPolicy policy = InvalidDepthPolicy::kReject);

  const CameraModel& camera() const override { return manifest_.camera; }
  std::string Describe() const override;
  FrameStatus Next(Frame* frame, std::string* error) override;

  const FrameDirectoryManifest& manifest() const { return manifest_; }
  // Pixels set to 0 under InvalidDepthPolicy::kSkip so far.
  size_t skipped_pixels() const { return skipped_pixels_; }

 private:
  std::filesystem::path dir_;
  FrameDirectoryManifest manifest_;
  InvalidDepthPolicy policy_;
  size_t next_ = 0;
  size_t skipped_pixels_ = 0;
};

}  // namespace romunect
