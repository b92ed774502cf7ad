// A float kept or zeroed without a branch, for per-pixel loops that must vectorize: under
// -ftrapping-math (GCC's default) GCC if-converts neither a float select nor a conditional
// store, so the pixel's bits are masked instead. Exact: a kept value keeps its bits.
#pragma once

#include <bit>
#include <cstdint>

namespace romunect {

// `value` where `keep`, else +0.0f.
inline float KeepOrZero(bool keep, float value) {
  return std::bit_cast<float>(std::bit_cast<uint32_t>(value) & (0u - static_cast<uint32_t>(keep)));
}

}  // namespace romunect
