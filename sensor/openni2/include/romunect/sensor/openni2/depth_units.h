// Depth units on the OpenNI2 wire. OpenNI2 carries depth as 16-bit integers in one of two units:
// 1 mm (ONI_PIXEL_FORMAT_DEPTH_1_MM, what the stock PS1080 chip reports) or 100 um
// (ONI_PIXEL_FORMAT_DEPTH_100_UM). At the sensor's 200 mm working distance the paper needs
// sub-millimetre depth, so romunect asks for 100 um when a device offers it (the virtual device
// does, and makes it its default): at most 0.05 mm rounding error, range up to 6.5535 m.
//
//   value = round(depth_m / unit_m)   (0 for no measurement, for depth <= 0 or NaN, and for
//                                      depth beyond the largest value, 65535 units)
//   depth_m = float(value * unit_m)   (computed in double, then rounded to float once)
#pragma once

#include <cmath>
#include <cstdint>

namespace romunect::openni2 {

enum class DepthUnit {
  k100um,  // 0.1 mm per count
  k1mm,    // 1 mm per count
};

inline double DepthUnitMeters(DepthUnit unit) { return unit == DepthUnit::k100um ? 1e-4 : 1e-3; }
inline const char* ToString(DepthUnit unit) { return unit == DepthUnit::k100um ? "100 um" : "1 mm"; }

// Metres to wire counts (see the header comment for the rule).
inline uint16_t QuantizeDepth(float depth_m, DepthUnit unit) {
  if (!(depth_m > 0.0f)) return 0;  // also NaN
  const double counts = std::nearbyint(static_cast<double>(depth_m) / DepthUnitMeters(unit));
  if (counts > 65535.0) return 0;
  return static_cast<uint16_t>(counts);
}

// Wire counts to metres.
inline float DequantizeDepth(uint16_t value, DepthUnit unit) {
  return static_cast<float>(static_cast<double>(value) * DepthUnitMeters(unit));
}

}  // namespace romunect::openni2
