// The instruction sets that SIMD kernels are built for, and what the CPU running the program
// supports. The build never assumes an instruction set beyond x86-64's SSE2, so one binary runs
// everywhere and each kernel family takes the widest implementation the machine has.
//
// One idiom for every kernel family (renderer, IR synthesis, depth engine, fusion insertion and
// extraction): the family's options hold an `Isa` (kAuto by default); the family implements a
// fixed set of instruction sets, one translation unit each (<family>_kernel_<isa>.cc, compiled
// under `#pragma GCC target`), lists those compiled in in a table and picks its entry with
// ResolveKernel() (ResolveIsa over the table). docs/design.md, "SIMD kernels".
#pragma once

#include <cstddef>
#include <initializer_list>
#include <optional>
#include <span>
#include <string_view>

namespace romunect {

// Narrowest first; kAuto asks for the widest the family implements and the CPU supports.
enum class Isa { kAuto, kScalar, kSse2, kAvx2, kAvx512 };

const char* ToString(Isa isa);                       // "auto", "scalar", "sse2", "avx2", "avx512"
std::optional<Isa> ParseIsa(std::string_view name);  // the inverse of ToString; nullopt if unknown

// Whether this CPU runs code built for `isa` (kAuto, kScalar: always; kSse2: on x86-64).
// kAvx512 means AVX-512 F, BW and DQ: what every AVX-512 kernel of the project uses.
bool CpuSupports(Isa isa);

// The instruction set a kernel family runs for `requested`, given the ones it `implements`:
// kAuto gives the widest implemented one the CPU supports; a named one is returned when it is
// implemented and supported, nullopt otherwise (the caller reports it as bad input).
std::optional<Isa> ResolveIsa(Isa requested, std::initializer_list<Isa> implements);
std::optional<Isa> ResolveIsa(Isa requested, std::span<const Isa> implements);

// A family's dispatch: its table holds one entry (a struct with an `isa` member and the
// family's function pointers) per instruction set compiled in; the entry ResolveIsa picks for
// `requested` among them, or null when it refuses.
template <class Kernel, std::size_t N>
const Kernel* ResolveKernel(Isa requested, const Kernel (&table)[N]) {
  Isa implements[N];
  for (std::size_t i = 0; i < N; ++i) implements[i] = table[i].isa;
  const std::optional<Isa> isa = ResolveIsa(requested, std::span<const Isa>(implements));
  if (!isa) return nullptr;
  for (const Kernel& kernel : table) {
    if (kernel.isa == *isa) return &kernel;
  }
  return nullptr;
}

}  // namespace romunect
