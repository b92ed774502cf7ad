// Fixture for the layering test: the port header (CalibrationHardware) is allowed in sim.
#include "romunect/calib/chain.h"
