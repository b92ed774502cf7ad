// The column kernels of extraction (private to fusion/src): the highest vote of a column's hit
// range, and whether the range holds a positive vote. One translation unit per instruction set,
// extract_kernel_{scalar,sse2,avx2}.cc, the AVX2 one compiled under `#pragma GCC target` and
// called only where the CPU reports it (voting_grid.cc lists them in its dispatch table). Every
// instruction set gives the same answers (tests/fusion compares them with the reference).
// Declarations only: no inline function is shared between units compiled for different
// instruction sets. docs/design.md, "SIMD kernels".
#pragma once

#include "romunect/fusion/voting_grid.h"

namespace romunect::fusion::extract_internal {

// The highest vote in votes[lo..hi] (lo <= hi) and the highest k holding it.
using MaxVoteFn = void (*)(const Vote* votes, int lo, int hi, int* best, int* best_k);
void MaxVoteScalar(const Vote* votes, int lo, int hi, int* best, int* best_k);
void MaxVoteSse2(const Vote* votes, int lo, int hi, int* best, int* best_k);
void MaxVoteAvx2(const Vote* votes, int lo, int hi, int* best, int* best_k);

// Whether votes[lo..hi] (lo <= hi) hold a positive vote, from the top down: a filled column's
// winner lies near its highest hit, so the search stops early.
using AnyPositiveFn = bool (*)(const Vote* votes, int lo, int hi);
bool AnyPositiveScalar(const Vote* votes, int lo, int hi);
bool AnyPositiveAvx2(const Vote* votes, int lo, int hi);

// The AVX2 kernels load 16 votes at a time from lo or later, never before lo, and may read up to
// this many votes past hi: the grid's mapping leaves room for them after its last column.
inline constexpr int kAvx2ReadPastHi = 15;

// One entry of extraction's dispatch table (voting_grid.cc, ResolveKernel).
struct Kernel {
  Isa isa;
  MaxVoteFn max_vote;
  AnyPositiveFn any_positive;
};

}  // namespace romunect::fusion::extract_internal

#if defined(__SSE2__)
#define ROMUNECT_FUSION_EXTRACT_SSE2 1
#endif
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROMUNECT_FUSION_EXTRACT_AVX2 1
#endif
