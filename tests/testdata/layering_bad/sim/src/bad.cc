// Fixture for the layering test: sim sees calib through its port header only. The test expects
// a failure for the intrinsics header.
#include "romunect/calib/intrinsics.h"
