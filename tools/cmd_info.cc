// romunect info DIR: summarize and validate a frame directory (jobs/info.h).
#include <cstdio>
#include <memory>
#include <string>

#include "commands.h"
#include "romunect/tools/jobs/info.h"

namespace romunect::tools {

void AddInfoCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand("info", "Summarize and validate a frame directory");
  auto dir = std::make_shared<std::string>();
  cmd->add_option("DIR", *dir, "Frame directory (holds frames.json)")->required();
  cmd->callback([dir] { std::printf("%s", jobs::FrameDirectoryInfoText(jobs::InspectFrameDirectory(*dir)).c_str()); });
}

}  // namespace romunect::tools
