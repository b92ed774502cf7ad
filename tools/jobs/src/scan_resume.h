// `romunect scan --resume` (ScanJobOptions::resume): the interrupted run's options and finished
// frames, and an imager that reads those frames back instead of rendering and imaging them. The
// simulation's physics replays from the start (deterministic, and cheap beside rendering), so
// every later frame, the plan and the fused map come out as the uninterrupted run's bytes.
#pragma once

#include <filesystem>
#include <memory>

#include "romunect/sim/scanner.h"
#include "romunect/tools/jobs/scan_report.h"

namespace romunect::jobs {

// Written into a scan's work folder when it begins (ScanOptionsJson and --perturb), removed
// before the run is committed: what --resume checks.
inline constexpr const char* kScanOptionsFile = "scan_options.json";
std::string ScanOptionsFileText(const ScanJobOptions& options);

// For the interrupted run in work_dir: checks its options against `options` (all but --threads,
// which do not change the bytes; InputError naming the option), removes a frames.json written
// just before the kill, and returns how many frames, from the first, are complete on disk.
int PrepareResume(const ScanJobOptions& options, const std::filesystem::path& work_dir);

// Frames below `reused` are replayed (FrameImager::Replay) from frames_dir: IR, raw, depth and
// ground-truth depth read back (checked: present, of the camera's size), neither rendered nor
// imaged; the others go to `inner`.
std::unique_ptr<sim::FrameImager> MakeResumingImager(std::unique_ptr<sim::FrameImager> inner,
                                                     const std::filesystem::path& frames_dir, int reused);

}  // namespace romunect::jobs
