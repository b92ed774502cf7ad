#include "romunect/sensor/cpu_features.h"

#include <algorithm>

namespace romunect {

const char* ToString(Isa isa) {
  switch (isa) {
    case Isa::kAuto: return "auto";
    case Isa::kScalar: return "scalar";
    case Isa::kSse2: return "sse2";
    case Isa::kAvx2: return "avx2";
    case Isa::kAvx512: return "avx512";
  }
  return "?";
}

std::optional<Isa> ParseIsa(std::string_view name) {
  for (Isa isa : {Isa::kAuto, Isa::kScalar, Isa::kSse2, Isa::kAvx2, Isa::kAvx512}) {
    if (name == ToString(isa)) return isa;
  }
  return std::nullopt;
}

bool CpuSupports(Isa isa) {
  switch (isa) {
    case Isa::kAuto:
    case Isa::kScalar: return true;
#if defined(__x86_64__)
    case Isa::kSse2: return true;
    case Isa::kAvx2: return __builtin_cpu_supports("avx2");
    case Isa::kAvx512:
      return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
             __builtin_cpu_supports("avx512dq");
#else
    default: return false;
#endif
  }
  return false;
}

std::optional<Isa> ResolveIsa(Isa requested, std::initializer_list<Isa> implements) {
  return ResolveIsa(requested, std::span<const Isa>(implements.begin(), implements.size()));
}

std::optional<Isa> ResolveIsa(Isa requested, std::span<const Isa> implements) {
  if (requested != Isa::kAuto) {
    const bool implemented = std::find(implements.begin(), implements.end(), requested) != implements.end();
    if (implemented && CpuSupports(requested)) return requested;
    return std::nullopt;
  }
  std::optional<Isa> best;
  for (Isa isa : implements) {
    if (isa != Isa::kAuto && CpuSupports(isa) && (!best || static_cast<int>(isa) > static_cast<int>(*best))) best = isa;
  }
  return best;
}

}  // namespace romunect
