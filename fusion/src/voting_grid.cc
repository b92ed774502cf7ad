#include "romunect/fusion/voting_grid.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <sstream>

#include "extract_kernel.h"
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

// The column kernels compiled in (extract_kernel.h), narrowest first. SSE2 has no search of its
// own for a positive vote.
constexpr extract_internal::Kernel kKernels[] = {
    {Isa::kScalar, &extract_internal::MaxVoteScalar, &extract_internal::AnyPositiveScalar},
#if ROMUNECT_FUSION_EXTRACT_SSE2
    {Isa::kSse2, &extract_internal::MaxVoteSse2, &extract_internal::AnyPositiveScalar},
#endif
#if ROMUNECT_FUSION_EXTRACT_AVX2
    {Isa::kAvx2, &extract_internal::MaxVoteAvx2, &extract_internal::AnyPositiveAvx2},
#endif
};

// The kernels for `requested` (ResolveIsa over kKernels); null where they are not compiled in or
// the CPU lacks them.
const extract_internal::Kernel* KernelFor(Isa requested) { return ResolveKernel(requested, kKernels); }

// The mapping of `bytes` of votes: 64 bytes more, so that a 16-lane load at the last column's top
// (the AVX2 column kernels of extraction: up to 15 votes past the hit range) stays inside it.
size_t MappedBytes(size_t bytes) { return bytes + 64; }
static_assert(extract_internal::kAvx2ReadPastHi * sizeof(Vote) <= 64);

// Zeroed memory for the votes, paged in on first touch (parts no ray reaches cost no memory) or,
// with `prefault`, all at once. Huge pages would be no faster at one thread (the tile order
// keeps the TLB's working set small) and 18 % faster at two, but cost +12 MB resident on the
// benchmark (the whole grid at 2 MB granularity), so the grid stays on normal pages.
Vote* MapVotes(size_t bytes, bool prefault) {
  void* p = mmap(nullptr, MappedBytes(bytes), PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1,
                 0);
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
      s << "box "
        << "xyz"[a] << " extent " << (max_W[a] - min_W[a]) << " m at voxel_m = " << voxel_m << " gives " << n
        << " voxels: at most 65535 per axis";
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

cv::Mat ExtractHeightMap(const VotingGrid& grid, Isa isa, int threads) {
  ROMUNECT_CHECK(threads >= 1);
  const extract_internal::Kernel* kernel = KernelFor(isa);
  if (kernel == nullptr) {
    throw InputError("fusion extraction", "isa",
                     std::string(ToString(isa)) + (CpuSupports(isa) ? ": no extraction kernel for it in this build"
                                                                    : ": this CPU does not support it"));
  }
  const extract_internal::MaxVoteFn max_vote = kernel->max_vote;
  constexpr int kPrefetchColumns = 16;
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
          if (grid.hit_lo(ahead) <= grid.hit_hi(ahead))
            __builtin_prefetch(grid.column(ix + kPrefetchColumns, iy) + grid.hit_lo(ahead));
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
  const extract_internal::AnyPositiveFn any_positive = KernelFor(Isa::kAuto)->any_positive;
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
      const bool now = lo <= hi && any_positive(grid_.column(ix, iy), lo, hi);
      filled_count_ += static_cast<size_t>(now) - filled_[c];
      filled_[c] = now;
    }
  }
  return static_cast<double>(filled_count_) / static_cast<double>(filled_.size());
}

}  // namespace romunect::fusion
