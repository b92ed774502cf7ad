// The trial-read program's entry (oni_file.h): it reads a recording through libOpenNI2 as
// OpenNI2Source will, in a process of its own, and exits with one of oni_file.h's codes.
#pragma once

namespace romunect::openni2 {

int OniTrialReadMain(int argc, char** argv);

}  // namespace romunect::openni2
