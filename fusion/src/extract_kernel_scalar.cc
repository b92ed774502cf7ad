// The column kernels of extraction in portable C++: the reference for the SIMD ones (same
// answers) and the path on CPUs without them.
#include <algorithm>
#include <limits>

#include "extract_kernel.h"

namespace romunect::fusion::extract_internal {

void MaxVoteScalar(const Vote* votes, int lo, int hi, int* best, int* best_k) {
  int m = std::numeric_limits<Vote>::min();
  for (int k = lo; k <= hi; ++k) m = std::max(m, int{votes[k]});
  *best = m;
  int top = hi;
  while (votes[top] != m) --top;
  *best_k = top;
}

bool AnyPositiveScalar(const Vote* votes, int lo, int hi) {
  for (int k = hi; k >= lo; --k) {
    if (votes[k] > 0) return true;
  }
  return false;
}

}  // namespace romunect::fusion::extract_internal
