// What the CPU running the program supports, for choosing SIMD kernels at run time: the build
// never assumes an instruction set beyond x86-64's SSE2, so one binary runs everywhere and takes
// the widest kernel the machine has.
#pragma once

namespace romunect {

bool CpuHasAvx2();
// AVX-512 F, BW and DQ: what every AVX-512 kernel of the project uses (all AVX-512 server and
// desktop CPUs have the three).
bool CpuHasAvx512();

}  // namespace romunect
