// The matching kernel in portable C++: 32 lanes as plain arrays. The reference for the SIMD
// instantiations (same bytes) and the path on CPUs without them.
#include "depth_engine_kernel_rows.h"

namespace {

struct ScalarLanes {
  struct U8 {
    uint8_t v[kLanesPerBlock];
  };
  struct I16 {
    int16_t v[kLanesPerBlock];
  };
  template <typename Fn>
  static I16 Map(Fn fn) {
    I16 out;
    for (int k = 0; k < kLanesPerBlock; ++k) out.v[k] = static_cast<int16_t>(fn(k));
    return out;
  }
  static constexpr int Lane(int k) { return k; }
  static U8 AbsDiff(uint8_t obs, const uint8_t* ref) {
    U8 out;
    for (int k = 0; k < kLanesPerBlock; ++k)
      out.v[k] = static_cast<uint8_t>(obs > ref[k] ? obs - ref[k] : ref[k] - obs);
    return out;
  }
  static U8 OrBytes(const U8& a, const uint8_t* bytes) {
    U8 out;
    for (int k = 0; k < kLanesPerBlock; ++k) out.v[k] = static_cast<uint8_t>(a.v[k] | bytes[k]);
    return out;
  }
  static I16 Widen(const U8& a) {
    return Map([&](int k) { return a.v[k]; });
  }
  static I16 WidenDiff(const U8& a, const U8& b) {
    return Map([&](int k) { return a.v[k] - b.v[k]; });
  }
  static I16 Load(const int16_t* p) {
    return Map([&](int k) { return p[k]; });
  }
  static void Store(int16_t* p, const I16& a) {
    for (int k = 0; k < kLanesPerBlock; ++k) p[k] = a.v[k];
  }
  static I16 Add(const I16& a, const I16& b) {
    return Map([&](int k) { return a.v[k] + b.v[k]; });
  }
  static I16 Sub(const I16& a, const I16& b) {
    return Map([&](int k) { return a.v[k] - b.v[k]; });
  }
  static I16 Min(const I16& a, const I16& b) {
    return Map([&](int k) { return a.v[k] < b.v[k] ? a.v[k] : b.v[k]; });
  }
  static I16 Or(const I16& a, const I16& b) {
    return Map([&](int k) { return a.v[k] | b.v[k]; });
  }
  static int HorizontalMin(const I16& a) {
    int m = a.v[0];
    for (int k = 1; k < kLanesPerBlock; ++k) m = a.v[k] < m ? a.v[k] : m;
    return m;
  }
  template <typename Pred>
  static uint32_t Mask(const I16& a, Pred pred) {
    uint32_t mask = 0;
    for (int k = 0; k < kLanesPerBlock; ++k) mask |= static_cast<uint32_t>(pred(a.v[k])) << k;
    return mask;
  }
  static uint32_t EqualMask(const I16& a, int value) {
    return Mask(a, [&](int v) { return v == value; });
  }
  static uint32_t LessMask(const I16& a, int value) {
    return Mask(a, [&](int v) { return v < value; });
  }
};

}  // namespace

namespace romunect::depth_engine_internal {

void MatchRowsScalar(const KernelArgs& args, KernelStats* stats) { MatchRowsAnyBlocks<ScalarLanes>(args, stats); }

}  // namespace romunect::depth_engine_internal
