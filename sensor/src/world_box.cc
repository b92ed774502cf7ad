#include "romunect/sensor/world_box.h"

#include <cmath>
#include <sstream>

namespace romunect {

std::string WorldBox::Problem() const {
  std::ostringstream s;
  s.precision(9);
  for (int a = 0; a < 3; ++a) {
    const char axis = "xyz"[a];
    if (!std::isfinite(min_W[a]) || !std::isfinite(max_W[a])) {
      s << axis << " range [" << min_W[a] << ", " << max_W[a] << "] must be finite";
      return s.str();
    }
    if (!(max_W[a] > min_W[a])) {
      s << axis << " range [" << min_W[a] << ", " << max_W[a] << "] is empty or inverted: max must be greater than min";
      return s.str();
    }
  }
  return "";
}

}  // namespace romunect
