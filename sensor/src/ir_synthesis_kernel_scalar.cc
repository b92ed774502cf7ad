// The IR synthesis row kernels in portable C++, one pixel at a time (ScalarLanes): the reference
// for the SIMD instantiations (same bytes) and the path on CPUs without them.
#include "ir_synthesis_kernel_rows.h"

namespace romunect::ir_synthesis_internal {

void ShadeRowScalar(const ShadeArgs& args, const ShadeRowData& row) { ShadeRow<ScalarLanes>(args, row); }
void FinishRowScalar(const FinishArgs& args, const FinishRowData& row) { FinishRow<ScalarLanes>(args, row); }
void DefocusRowScalar(const DefocusArgs& args, const DefocusRowData& row) { DefocusRow<ScalarLanes>(args, row); }

void FindLevelScalar(const LevelStack& table, float sigma, int* k, float* w) {
  FindLevel<ScalarLanes>(table, sigma, k, w);
}

}  // namespace romunect::ir_synthesis_internal
