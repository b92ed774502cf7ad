// Subcommands of the romunect CLI. Each Add*Command registers one subcommand on the app; its
// callback may throw InputError (bad input), which main() reports with a non-zero exit.
#pragma once

#include <string>

#include <CLI/CLI.hpp>

#include "romunect/jobs/rig_argument.h"

namespace romunect::tools {

void AddInfoCommand(CLI::App& app);
void AddFuseCommand(CLI::App& app);  // cmd_fuse.cc (fusion)
void AddRecordCommand(CLI::App& app);  // cmd_record.cc (sensor/openni2)
void AddRenderCommand(CLI::App& app);  // cmd_render.cc (sensor/embree)
void AddCalibrateCommand(CLI::App& app);  // cmd_calibrate.cc (calib)
void AddScanCommand(CLI::App& app);  // cmd_scan.cc (the main job: sim/, fusion/)

using jobs::LoadRigArgument;

}  // namespace romunect::tools
