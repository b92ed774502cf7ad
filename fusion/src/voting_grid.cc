#include "romunect/fusion/voting_grid.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <sstream>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "romunect/sensor/check.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/parallel_rows.h"
#include "romunect/sensor/world_box.h"

namespace romunect::fusion {
namespace {

constexpr const char* kSource = "fusion grid";

std::string Mb(size_t bytes) {
  std::ostringstream s;
  s.precision(1);
  s << std::fixed << bytes / 1e6 << " MB";
  return s.str();
}

size_t PhysicalMemoryBytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return std::numeric_limits<size_t>::max();
  return static_cast<size_t>(pages) * static_cast<size_t>(page);
}

// The highest vote in votes[lo..hi] (lo <= hi) and the highest k holding it; 8 lanes at a time
// (the last block may overlap the previous one, which a maximum does not mind).
void MaxVoteSse2(const Vote* votes, int lo, int hi, int* best, int* best_k) {
  int k = lo;
  int m = std::numeric_limits<Vote>::min();
#if defined(__SSE2__)
  if (hi - lo + 1 >= 8) {
    __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + lo));
    for (k = lo + 8; k + 8 <= hi + 1; k += 8) {
      v = _mm_max_epi16(v, _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + k)));
    }
    if (k <= hi) v = _mm_max_epi16(v, _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + hi - 7)));
    v = _mm_max_epi16(v, _mm_srli_si128(v, 8));
    v = _mm_max_epi16(v, _mm_srli_si128(v, 4));
    v = _mm_max_epi16(v, _mm_srli_si128(v, 2));
    m = static_cast<int16_t>(_mm_cvtsi128_si32(v) & 0xffff);
    k = hi + 1;
  }
#endif
  for (; k <= hi; ++k) m = std::max(m, int{votes[k]});
  *best = m;
  int top = hi;
  while (votes[top] != m) --top;
  *best_k = top;
}

// Whether votes[lo..hi] hold a positive vote, from the top down: a filled column's winner lies
// near its highest hit, so the search stops early.
bool AnyPositive(const Vote* votes, int lo, int hi) {
  for (int k = hi; k >= lo; --k) {
    if (votes[k] > 0) return true;
  }
  return false;
}

#if defined(__x86_64__)
#pragma GCC push_options
#pragma GCC target("avx2")
// AnyPositive, 16 lanes at a time from the top (loads start at lo or later, as MaxVoteAvx2's).
bool AnyPositiveAvx2(const Vote* votes, int lo, int hi) {
  const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  for (int top = hi; top >= lo; top -= 16) {
    const int start = std::max(lo, top - 15);
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(votes + start));
    const __m256i in_range = _mm256_cmpgt_epi16(_mm256_set1_epi16(static_cast<int16_t>(top - start + 1)), lane);
    if (!_mm256_testz_si256(_mm256_and_si256(_mm256_cmpgt_epi16(v, _mm256_setzero_si256()), in_range), in_range)) {
      return true;
    }
  }
  return false;
}

// MaxVoteSse2 with 16 lanes and masked ends: loads start at lo or later and may read up to 15
// votes past hi (MappedBytes leaves room after the last column), never before lo.
void MaxVoteAvx2(const Vote* votes, int lo, int hi, int* best, int* best_k) {
  const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m256i lowest = _mm256_set1_epi16(std::numeric_limits<Vote>::min());
  auto load = [&](int start, int count) {  // votes [start, start + count), the rest lowest
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(votes + start));
    return _mm256_blendv_epi8(lowest, v, _mm256_cmpgt_epi16(_mm256_set1_epi16(static_cast<int16_t>(count)), lane));
  };
  __m256i m = lowest;
  for (int k = lo; k <= hi; k += 16) m = _mm256_max_epi16(m, load(k, std::min(16, hi - k + 1)));
  __m128i h = _mm_max_epi16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
  h = _mm_max_epi16(h, _mm_srli_si128(h, 8));
  h = _mm_max_epi16(h, _mm_srli_si128(h, 4));
  h = _mm_max_epi16(h, _mm_srli_si128(h, 2));
  const int16_t found = static_cast<int16_t>(_mm_cvtsi128_si32(h) & 0xffff);
  *best = found;
  const __m256i target = _mm256_set1_epi16(found);
  for (int top = hi;; top -= 16) {  // from the top: the highest k holding the maximum
    const int start = std::max(lo, top - 15);
    const __m256i v = load(start, top - start + 1);
    const uint32_t equal = static_cast<uint32_t>(_mm256_movemask_epi8(_mm256_cmpeq_epi16(v, target)));
    if (equal != 0) {
      *best_k = start + (31 - __builtin_clz(equal)) / 2;
      return;
    }
  }
}
#pragma GCC pop_options
#endif

// The mapping of `bytes` of votes: 64 bytes more, so that a 16-lane load at the last column's top
// (MaxVoteAvx2, AnyPositiveAvx2: up to 15 votes past the hit range) stays inside it.
size_t MappedBytes(size_t bytes) { return bytes + 64; }

// Zeroed memory for the votes, paged in on first touch (parts no ray reaches cost no memory) or,
// with `prefault`, all at once. Huge pages were measured too: no faster at one thread (the
// tile order keeps the TLB's working set small), 18 % faster at two, but +12 MB resident on the
// benchmark (the whole grid at 2 MB granularity), so the grid stays on normal pages.
Vote* MapVotes(size_t bytes, bool prefault) {
  void* p = mmap(nullptr, MappedBytes(bytes), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
  if (p == MAP_FAILED) return nullptr;
  if (prefault) madvise(p, bytes, MADV_POPULATE_WRITE);  // advice only (Linux >= 5.14)
  return static_cast<Vote*>(p);
}

}  // namespace

std::string GridOptions::Problem() const {
  if (const std::string box = WorldBox{min_W, max_W}.Problem(); !box.empty()) return "box " + box;
  std::ostringstream s;
  s.precision(9);
  if (!std::isfinite(voxel_m) || !(voxel_m > 0.0)) {
    s << "voxel_m = " << voxel_m << ": must be a positive number of metres";
    return s.str();
  }
  for (int a = 0; a < 3; ++a) {
    const double n = std::ceil((max_W[a] - min_W[a]) / voxel_m - 1e-6);
    if (n > 65535.0) {
      s << "box " << "xyz"[a] << " extent " << (max_W[a] - min_W[a]) << " m at voxel_m = " << voxel_m
        << " gives " << n << " voxels: at most 65535 per axis";
      return s.str();
    }
  }
  return "";
}

Eigen::Vector3i GridOptions::Dims() const {
  Eigen::Vector3i n;
  for (int a = 0; a < 3; ++a) {
    n[a] = std::max(1, static_cast<int>(std::ceil((max_W[a] - min_W[a]) / voxel_m - 1e-6)));
  }
  return n;
}

size_t GridOptions::RequiredBytes() const {
  const Eigen::Vector3i n = Dims();
  const size_t columns = static_cast<size_t>(n.x()) * n.y();
  return columns * n.z() * sizeof(Vote) + 2 * columns * sizeof(uint16_t);
}

VotingGrid::VotingGrid(const GridOptions& options) : options_(options) {
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError(kSource, "options", problem);
  const Eigen::Vector3i n = options.Dims();
  nx_ = n.x();
  ny_ = n.y();
  nz_ = n.z();
  const size_t need = options.RequiredBytes();
  const size_t physical = PhysicalMemoryBytes();
  const size_t limit = std::min(options.max_memory_bytes, physical);
  const std::string dims = std::to_string(nx_) + " x " + std::to_string(ny_) + " x " + std::to_string(nz_);
  if (need > limit) {
    throw InputError(kSource, "memory",
                     "a " + dims + " grid needs " + Mb(need) + ", more than the limit of " + Mb(limit) +
                         (limit == physical ? " (physical memory)" : " (max_memory_bytes)") +
                         ": use a larger voxel or a smaller box");
  }
  const size_t columns = static_cast<size_t>(nx_) * ny_;
  votes_ = MapVotes(columns * nz_ * sizeof(Vote), options.prefault);
  hit_lo_ = static_cast<uint16_t*>(std::malloc(columns * sizeof(uint16_t)));
  hit_hi_ = static_cast<uint16_t*>(std::malloc(columns * sizeof(uint16_t)));
  if (votes_ == nullptr || hit_lo_ == nullptr || hit_hi_ == nullptr) {
    if (votes_ != nullptr) munmap(votes_, MappedBytes(columns * nz_ * sizeof(Vote)));
    std::free(hit_lo_);
    std::free(hit_hi_);
    throw InputError(kSource, "memory", "could not allocate " + Mb(need) + " for a " + dims + " grid");
  }
  std::fill(hit_lo_, hit_lo_ + columns, std::numeric_limits<uint16_t>::max());
  std::fill(hit_hi_, hit_hi_ + columns, uint16_t{0});
}

VotingGrid::~VotingGrid() {
  munmap(votes_, MappedBytes(static_cast<size_t>(nx_) * ny_ * nz_ * sizeof(Vote)));
  std::free(hit_lo_);
  std::free(hit_hi_);
}

HeightMapGeometry VotingGrid::geometry() const {
  HeightMapGeometry g;
  g.min_x_m = options_.min_W.x();
  g.min_y_m = options_.min_W.y();
  g.min_z_m = options_.min_W.z();
  g.voxel_m = options_.voxel_m;
  g.nx = nx_;
  g.ny = ny_;
  g.nz = nz_;
  return g;
}

size_t VotingGrid::memory_bytes() const { return options_.RequiredBytes(); }

void VotingGrid::Clear() {
  const size_t columns = static_cast<size_t>(nx_) * ny_;
  std::memset(votes_, 0, columns * nz_ * sizeof(Vote));
  std::fill(hit_lo_, hit_lo_ + columns, std::numeric_limits<uint16_t>::max());
  std::fill(hit_hi_, hit_hi_ + columns, uint16_t{0});
}

cv::Mat ExtractHeightMap(const VotingGrid& grid, ExtractKernel kernel, int threads) {
  ROMUNECT_CHECK(threads >= 1);
  constexpr int kPrefetchColumns = 16;
  void (*max_vote)(const Vote*, int, int, int*, int*) = &MaxVoteSse2;
#if defined(__x86_64__)
  if (kernel == ExtractKernel::kAuto && CpuHasAvx2()) max_vote = &MaxVoteAvx2;
#endif
  cv::Mat height(grid.ny(), grid.nx(), CV_32F);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const double z0 = grid.options().min_W.z(), voxel = grid.voxel_m();
  auto extract_rows = [&](int iy0, int iy1) {
    for (int iy = iy0; iy < iy1; ++iy) {
      float* row = height.ptr<float>(iy);
      for (int ix = 0; ix < grid.nx(); ++ix) {
        const size_t c = grid.ColumnIndex(ix, iy);
        // Columns are read where they were hit, 512 B apart: fetch a few ahead (the latency of
        // the grid's memory, not the maximum, bounds extraction).
        if (ix + kPrefetchColumns < grid.nx()) {
          const size_t ahead = c + kPrefetchColumns;
          if (grid.hit_lo(ahead) <= grid.hit_hi(ahead)) __builtin_prefetch(grid.column(ix + kPrefetchColumns, iy) + grid.hit_lo(ahead));
        }
        const int lo = grid.hit_lo(c), hi = grid.hit_hi(c);
        row[ix] = nan;
        if (lo > hi) continue;
        // The highest vote, then the highest z holding it (ties go to the higher z).
        int best, best_k;
        max_vote(grid.column(ix, iy), lo, hi, &best, &best_k);
        if (best <= 0) continue;  // only positive votes win
        row[ix] = static_cast<float>(z0 + (best_k + 0.5) * voxel);
      }
    }
  };
  ParallelRows(threads, grid.ny(), extract_rows);  // rows are independent
  return height;
}

CompletenessTracker::CompletenessTracker(const VotingGrid& grid)
    : grid_(grid), filled_(static_cast<size_t>(grid.nx()) * grid.ny(), 0) {}

double CompletenessTracker::Update(const cv::Rect& changed_columns) {
  ROMUNECT_CHECK((changed_columns & cv::Rect(0, 0, grid_.nx(), grid_.ny())) == changed_columns);
  const bool avx2 = CpuHasAvx2();
  // The search starts at a column's highest hit, a column's length (nz votes) from the last one: a
  // stride the caches do not fetch ahead by themselves, so it is fetched 8 columns ahead.
  constexpr int kAhead = 8;
  const int x_end = changed_columns.x + changed_columns.width;
  for (int iy = changed_columns.y; iy < changed_columns.y + changed_columns.height; ++iy) {
    for (int ix = changed_columns.x; ix < x_end; ++ix) {
      if (ix + kAhead < x_end) {
        const size_t a = grid_.ColumnIndex(ix + kAhead, iy);
        if (grid_.hit_lo(a) <= grid_.hit_hi(a)) __builtin_prefetch(grid_.column(ix + kAhead, iy) + grid_.hit_hi(a));
      }
      const size_t c = grid_.ColumnIndex(ix, iy);
      const int lo = grid_.hit_lo(c), hi = grid_.hit_hi(c);
      const bool now = lo <= hi && (avx2 ? AnyPositiveAvx2(grid_.column(ix, iy), lo, hi)
                                         : AnyPositive(grid_.column(ix, iy), lo, hi));
      filled_count_ += static_cast<size_t>(now) - filled_[c];
      filled_[c] = now;
    }
  }
  return static_cast<double>(filled_count_) / static_cast<double>(filled_.size());
}

}  // namespace romunect::fusion
