// romunect-oni-trial-read: not a command for users. OpenNI2Source runs it on a recording before
// it reads one itself, so that a recording that crashes libOpenNI2 takes down this program, not
// the caller's (oni_file.h).
#include "oni_trial_read.h"

int main(int argc, char** argv) { return romunect::openni2::OniTrialReadMain(argc, argv); }
