// Fixture for the layering test: fusion must never include MuJoCo. The test expects a failure.
#include <mujoco/mujoco.h>
