// romunect: the command line of the hand-mounted structured-light sensor twin.
#include <cstdio>
#include <exception>
#include <iostream>

#include <CLI/CLI.hpp>

#include "commands.h"
#include "romunect/sensor/errors.h"

int main(int argc, char** argv) {
  CLI::App app{"romunect: a digital twin of a hand-mounted structured-light depth sensor"};
  app.set_version_flag("--version", std::string("romunect ") + ROMUNECT_VERSION);
  app.require_subcommand(1);
  app.fallthrough(false);

  romunect::tools::AddScanCommand(app);
  romunect::tools::AddInfoCommand(app);
  romunect::tools::AddFuseCommand(app);
  romunect::tools::AddRecordCommand(app);
  romunect::tools::AddRenderCommand(app);
  romunect::tools::AddCalibrateCommand(app);
  romunect::tools::AddExperimentCommand(app);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const romunect::InputError& e) {
    std::cerr << "romunect: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "romunect: error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
