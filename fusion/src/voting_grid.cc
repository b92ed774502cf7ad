#include "romunect/fusion/voting_grid.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <sstream>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "romunect/sensor/errors.h"

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

// max(votes[lo..hi]), lo <= hi; 8 lanes at a time (the last block may overlap the previous one,
// which a maximum does not mind).
int MaxVote(const Vote* votes, int lo, int hi) {
  int k = lo;
  int best = std::numeric_limits<Vote>::min();
#if defined(__SSE2__)
  if (hi - lo + 1 >= 8) {
    __m128i m = _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + lo));
    for (k = lo + 8; k + 8 <= hi + 1; k += 8) {
      m = _mm_max_epi16(m, _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + k)));
    }
    if (k <= hi) m = _mm_max_epi16(m, _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + hi - 7)));
    m = _mm_max_epi16(m, _mm_srli_si128(m, 8));
    m = _mm_max_epi16(m, _mm_srli_si128(m, 4));
    m = _mm_max_epi16(m, _mm_srli_si128(m, 2));
    return static_cast<int16_t>(_mm_cvtsi128_si32(m) & 0xffff);
  }
#endif
  for (; k <= hi; ++k) best = std::max(best, int{votes[k]});
  return best;
}

constexpr size_t kHugePage = size_t{2} << 20;

// Zeroed memory for the votes, paged in on first touch: an anonymous mapping aligned to 2 MB and
// marked for transparent huge pages. A frame's rays touch a frustum of the grid in scattered
// columns; with 4 KB pages its ~14 MB miss the TLB (measured: insertion ~12 % faster with huge
// pages on the benchmark). Returns the mapping's start (for munmap) and the aligned votes.
Vote* MapVotes(size_t bytes, void** mapping, size_t* mapped) {
  *mapped = bytes + kHugePage;
  void* p = mmap(nullptr, *mapped, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
  if (p == MAP_FAILED) return nullptr;
  *mapping = p;
  char* aligned = reinterpret_cast<char*>((reinterpret_cast<uintptr_t>(p) + kHugePage - 1) & ~(kHugePage - 1));
  madvise(aligned, bytes, MADV_HUGEPAGE);  // advice only: without it the grid works with small pages
  return reinterpret_cast<Vote*>(aligned);
}

}  // namespace

std::string GridOptions::Problem() const {
  std::ostringstream s;
  s.precision(9);
  for (int a = 0; a < 3; ++a) {
    const char axis = "xyz"[a];
    if (!std::isfinite(min_W[a]) || !std::isfinite(max_W[a])) {
      s << "box " << axis << " range [" << min_W[a] << ", " << max_W[a] << "] must be finite";
      return s.str();
    }
    if (!(max_W[a] > min_W[a])) {
      s << "box " << axis << " range [" << min_W[a] << ", " << max_W[a]
        << "] is empty or inverted: max must be greater than min";
      return s.str();
    }
  }
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
  votes_ = MapVotes(columns * nz_ * sizeof(Vote), &mapping_, &mapped_bytes_);
  hit_lo_ = static_cast<uint16_t*>(std::malloc(columns * sizeof(uint16_t)));
  hit_hi_ = static_cast<uint16_t*>(std::malloc(columns * sizeof(uint16_t)));
  if (votes_ == nullptr || hit_lo_ == nullptr || hit_hi_ == nullptr) {
    if (mapping_ != nullptr) munmap(mapping_, mapped_bytes_);
    std::free(hit_lo_);
    std::free(hit_hi_);
    throw InputError(kSource, "memory", "could not allocate " + Mb(need) + " for a " + dims + " grid");
  }
  std::fill(hit_lo_, hit_lo_ + columns, std::numeric_limits<uint16_t>::max());
  std::fill(hit_hi_, hit_hi_ + columns, uint16_t{0});
}

VotingGrid::~VotingGrid() {
  munmap(mapping_, mapped_bytes_);
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

cv::Mat ExtractHeightMap(const VotingGrid& grid) {
  cv::Mat height(grid.ny(), grid.nx(), CV_32F);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const double z0 = grid.options().min_W.z(), voxel = grid.voxel_m();
  for (int iy = 0; iy < grid.ny(); ++iy) {
    float* row = height.ptr<float>(iy);
    for (int ix = 0; ix < grid.nx(); ++ix) {
      const size_t c = grid.ColumnIndex(ix, iy);
      const int lo = grid.hit_lo(c), hi = grid.hit_hi(c);
      row[ix] = nan;
      if (lo > hi) continue;
      const Vote* votes = grid.column(ix, iy);
      // The highest vote, then the highest z holding it (ties go to the higher z).
      const int best = MaxVote(votes, lo, hi);
      if (best <= 0) continue;  // only positive votes win
      int best_k = hi;
      while (votes[best_k] != best) --best_k;
      row[ix] = static_cast<float>(z0 + (best_k + 0.5) * voxel);
    }
  }
  return height;
}

}  // namespace romunect::fusion
