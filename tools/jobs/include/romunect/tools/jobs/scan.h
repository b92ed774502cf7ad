// The main job, `romunect scan`: a MuJoCo arm approaches a bin with a settled random pile at
// 0.3 m/s, the simulated sensor delivers 30 Hz frames, each frame is fused as it arrives
// (FrameFuser on the frame pipeline's fuse stage), then the robot picks from the fused height
// map. The run folder is one transaction (RunFolder); its files are scan_report.h's.
#pragma once

#include "romunect/tools/jobs/scan_report.h"

namespace romunect::jobs {

// Validates the options (InputError naming the option or file, before any work or file), runs
// the scan, writes the run folder and returns its report. Progress goes to stderr.
ScanSummary RunScan(const ScanJobOptions& options);

}  // namespace romunect::jobs
