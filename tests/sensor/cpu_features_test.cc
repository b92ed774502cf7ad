#include "romunect/sensor/cpu_features.h"

#include <gtest/gtest.h>

namespace romunect {
namespace {

constexpr Isa kEvery[] = {Isa::kAuto, Isa::kScalar, Isa::kSse2, Isa::kAvx2, Isa::kAvx512};

TEST(CpuFeaturesTest, NamesRoundTrip) {
  for (Isa isa : kEvery) EXPECT_EQ(ParseIsa(ToString(isa)), isa);
  EXPECT_EQ(ParseIsa("avx"), std::nullopt);
  EXPECT_STREQ(ToString(Isa::kAvx512), "avx512");
}

TEST(CpuFeaturesTest, ResolveIsaTakesTheWidestSupportedOrRefuses) {
  EXPECT_TRUE(CpuSupports(Isa::kAuto));
  EXPECT_TRUE(CpuSupports(Isa::kScalar));
  EXPECT_EQ(ResolveIsa(Isa::kAuto, {Isa::kScalar}), Isa::kScalar);
  EXPECT_EQ(ResolveIsa(Isa::kAuto, {}), std::nullopt);
  EXPECT_EQ(ResolveIsa(Isa::kSse2, {Isa::kScalar, Isa::kAvx2}), std::nullopt);  // not implemented
  const std::optional<Isa> widest = ResolveIsa(Isa::kAuto, {Isa::kAvx512, Isa::kScalar, Isa::kAvx2, Isa::kSse2});
  ASSERT_TRUE(widest.has_value());
  for (Isa isa : kEvery) {
    // Named: itself where the CPU has it, else refused; never wider than kAuto's choice.
    const std::optional<Isa> named = ResolveIsa(isa, {Isa::kScalar, Isa::kSse2, Isa::kAvx2, Isa::kAvx512});
    if (isa == Isa::kAuto) continue;
    EXPECT_EQ(named.has_value(), CpuSupports(isa)) << ToString(isa);
    if (named) {
      EXPECT_LE(static_cast<int>(isa), static_cast<int>(*widest));
    }
  }
#if defined(__x86_64__)
  EXPECT_NE(*widest, Isa::kScalar);
#endif
}

int Twice(int v) { return 2 * v; }
int Thrice(int v) { return 3 * v; }

TEST(CpuFeaturesTest, ResolveKernelPicksTheTableEntry) {
  struct Kernel {
    Isa isa;
    int (*fn)(int);
  };
  constexpr Kernel kTable[] = {{Isa::kScalar, &Twice}, {Isa::kSse2, &Thrice}};
  const Kernel* scalar = ResolveKernel(Isa::kScalar, kTable);
  ASSERT_NE(scalar, nullptr);
  EXPECT_EQ(scalar->fn(5), 10);
  EXPECT_EQ(ResolveKernel(Isa::kAvx2, kTable), nullptr);  // not in the table
  const Kernel* best = ResolveKernel(Isa::kAuto, kTable);
  ASSERT_NE(best, nullptr);
  EXPECT_EQ(best->isa, CpuSupports(Isa::kSse2) ? Isa::kSse2 : Isa::kScalar);
}

}  // namespace
}  // namespace romunect
