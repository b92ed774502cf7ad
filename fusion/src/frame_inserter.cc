#include "romunect/fusion/frame_inserter.h"

#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <new>
#include <span>
#include <sstream>
#include <type_traits>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "romunect/sensor/check.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/parallel_rows.h"

namespace romunect::fusion {
namespace {

constexpr Vote kVoteMax = std::numeric_limits<Vote>::max();
constexpr Vote kVoteMin = -kVoteMax;  // symmetric saturation

// The side of the square pixel tiles in which a frame's rays are cast: neighbouring rays cross
// the same columns, so a tile's columns stay in cache (pixel-row order revisits a column only
// 640 rays later). Not part of the semantics (voting_grid.h: the order of rays does not matter).
constexpr int kInsertionTilePx = 32;

// One cast ray of the kernels without a lane setup: set up once per frame (phase 1) and walked
// by every slab owner (phase 2); also the scalar fallbacks' form of a lane's ray.
struct RaySetup {
  double p_g[3];           // measured point, grid units
  double t_enter, t_exit;  // the segment's part inside the box
  int32_t iy_lo, iy_hi;    // rows the walk may visit (conservative, for slab skipping)
  bool ends_inside;        // the point is in the grid: the last voxel gets a hit
};

double ThreadCpuMs() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

// A ray's hit, kept until the frame's misses are applied (voting_grid.h): the column's index and
// the voxel's z.
struct HitRecord {
  uint32_t column;
  uint16_t z;
};
static_assert(sizeof(HitRecord) == 8, "the AVX-512 walk stores hits as column | z << 32");

// Slots past a thread's hits that the AVX-512 walk may write and then overwrite: it stores eight
// compressed hits at once: a compress straight into memory took ~15 ns on this project's Zen 4
// host even with an empty mask (micro-benchmark), one into a register and a plain store ~1.4 ns.
constexpr size_t kHitSlack = 8;

struct WalkContext {
  double ox, oy, oz;  // camera centre, grid units
  int nx, ny, nz;
  int ya, yb;         // this thread's rows [ya, yb)
  Vote* votes;
  HitRecord* hits;    // this thread's hits (in its rows): room for one per pixel, plus kHitSlack
  size_t hit_count;
  size_t misses;
};

// A frame's constants of the setup below (the lane setup of ray_walk_lanes512.inc evaluates the
// same expressions).
struct SetupFrame {
  double R[3][3], o_W[3], min_W[3], o_g[3], voxel;
  int n[3];
  const double* ray_C;  // x, y per pixel (z = 1)
  int width;
};

// The (x, y) range, in grid units, of the segments a thread set up in a frame: the columns whose
// votes the frame may change lie within it (FrameInserter::changed_columns()).
struct SegmentBounds {
  double x_lo = std::numeric_limits<double>::infinity(), x_hi = -std::numeric_limits<double>::infinity();
  double y_lo = std::numeric_limits<double>::infinity(), y_hi = -std::numeric_limits<double>::infinity();
  void Add(double xa, double xb, double ya, double yb) {
    x_lo = std::min({x_lo, xa, xb});
    x_hi = std::max({x_hi, xa, xb});
    y_lo = std::min({y_lo, ya, yb});
    y_hi = std::max({y_hi, ya, yb});
  }
  // The union with another range, which may be empty (lo > hi).
  void Merge(const SegmentBounds& o) {
    x_lo = std::min(x_lo, o.x_lo);
    x_hi = std::max(x_hi, o.x_hi);
    y_lo = std::min(y_lo, o.y_lo);
    y_hi = std::max(y_hi, o.y_hi);
  }
};

// The start voxel on one axis: clamp(floor(x)) into [0, n).
inline int StartIndex(double x, int n) { return static_cast<int>(std::clamp(std::floor(x), 0.0, n - 1.0)); }

// The start of a ray's column walk, the same expressions for every kernel: the segment's
// direction (dz) and inverse per axis, the start voxel, the step signs, and per axis in (x, y)
// the first crossing plane (voxel index + 1 going up) and its time (inf without motion).
struct WalkStart {
  double dz, inv_x, inv_y, inv_z, tx, ty;
  int ix0, iy0, iz0, sx, sy, plane_x, plane_y;
};
inline WalkStart StartWalk(const RaySetup& ray, double ox, double oy, double oz, int nx, int ny, int nz) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  WalkStart w;
  const double dx = ray.p_g[0] - ox, dy = ray.p_g[1] - oy;
  w.dz = ray.p_g[2] - oz;
  w.inv_x = 1.0 / dx;
  w.inv_y = 1.0 / dy;
  w.inv_z = 1.0 / w.dz;
  w.ix0 = StartIndex(ox + ray.t_enter * dx, nx);
  w.iy0 = StartIndex(oy + ray.t_enter * dy, ny);
  w.iz0 = StartIndex(oz + ray.t_enter * w.dz, nz);
  w.sx = dx > 0.0 ? 1 : (dx < 0.0 ? -1 : 0);
  w.sy = dy > 0.0 ? 1 : (dy < 0.0 ? -1 : 0);
  w.plane_x = w.ix0 + (dx > 0.0);
  w.plane_y = w.iy0 + (dy > 0.0);
  w.tx = w.sx != 0 ? (static_cast<double>(w.plane_x) - ox) * w.inv_x : kInf;
  w.ty = w.sy != 0 ? (static_cast<double>(w.plane_y) - oy) * w.inv_y : kInf;
  return w;
}

// Lane masks for runs of misses: loading a block at mask + kLanes - a gives -1 in lanes >= a, at
// mask + 2 kLanes - b gives -1 in lanes < b; their AND selects the lanes [a, b) of a block, the
// second alone the first b lanes, and a load at b the last b lanes.
template <int kLanes>
struct LaneMaskTable {
  int16_t mask[3 * kLanes];
  constexpr LaneMaskTable() : mask() {
    for (int i = kLanes; i < 2 * kLanes; ++i) mask[i] = -1;
  }
};

// The frame's hits, after its misses: +1 each, saturating, and the columns' hit bounds.
void ApplyHits(const HitRecord* hits, size_t count, VotingGrid* grid) {
  const size_t nz = grid->nz();
  Vote* votes = grid->mutable_column(0);
  uint16_t* hit_lo = grid->mutable_hit_lo();
  uint16_t* hit_hi = grid->mutable_hit_hi();
  // Each hit is in a column of its own, whose lines the frame's later rays have pushed out of
  // the caches: fetched 32 hits ahead, the misses overlap (~45 % less time in the benchmark).
  constexpr size_t kAhead = 32;
  for (size_t i = 0; i < count; ++i) {
    const HitRecord& h = hits[i];
    if (i + kAhead < count) {
      const HitRecord& a = hits[i + kAhead];
      __builtin_prefetch(votes + a.column * nz + a.z, 1);
      __builtin_prefetch(hit_lo + a.column, 1);
      __builtin_prefetch(hit_hi + a.column, 1);
    }
    Vote* v = votes + h.column * nz + h.z;
    *v = static_cast<Vote>(std::min(*v + 1, int{kVoteMax}));
    hit_lo[h.column] = std::min(hit_lo[h.column], h.z);
    hit_hi[h.column] = std::max(hit_hi[h.column], h.z);
  }
}

// Each kernel defines a block of votes and its four operations; ray_walk.inc builds the runs of
// misses and the walk on them. AddMiss adds a lane mask (0 or -1 per lane) and saturates at
// kVoteMin: v >= kVoteMin, so v - 1 cannot wrap.
namespace scalar {
using Block = Vote;
inline Block LoadBlock(const Vote* p) { return *p; }
inline void StoreBlock(Vote* p, Block v) { *p = v; }
inline Block AndBlocks(Block a, Block b) { return static_cast<Block>(a & b); }
inline Block AddMiss(Block v, Block mask) { return static_cast<Block>(std::max(v + mask, int{kVoteMin})); }
#include "ray_walk.inc"
}  // namespace scalar

#if defined(__x86_64__)
namespace sse2 {
using Block = __m128i;
inline Block LoadBlock(const Vote* p) { return _mm_loadu_si128(reinterpret_cast<const __m128i*>(p)); }
inline void StoreBlock(Vote* p, Block v) { _mm_storeu_si128(reinterpret_cast<__m128i*>(p), v); }
inline Block AndBlocks(Block a, Block b) { return _mm_and_si128(a, b); }
inline Block AddMiss(Block v, Block mask) { return _mm_max_epi16(_mm_add_epi16(v, mask), _mm_set1_epi16(kVoteMin)); }
#include "ray_walk.inc"
}  // namespace sse2

#pragma GCC push_options
#pragma GCC target("avx2")
namespace avx2 {
using Block = __m256i;
inline Block LoadBlock(const Vote* p) { return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)); }
inline void StoreBlock(Vote* p, Block v) { _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), v); }
inline Block AndBlocks(Block a, Block b) { return _mm256_and_si256(a, b); }
inline Block AddMiss(Block v, Block mask) { return _mm256_max_epi16(_mm256_add_epi16(v, mask), _mm256_set1_epi16(kVoteMin)); }
#include "ray_walk.inc"
#include "ray_walk_lanes.inc"
}  // namespace avx2
#pragma GCC pop_options

#pragma GCC push_options
#pragma GCC target("avx2,avx512f,avx512bw,avx512dq")
// GCC 12 warns inside its own AVX-512 headers (their _mm512_undefined_* placeholders).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
namespace avx512 {
using Block = __m512i;
inline Block LoadBlock(const Vote* p) { return _mm512_loadu_si512(p); }
inline void StoreBlock(Vote* p, Block v) { _mm512_storeu_si512(p, v); }
inline Block AndBlocks(Block a, Block b) { return _mm512_and_si512(a, b); }
inline Block AddMiss(Block v, Block mask) { return _mm512_max_epi16(_mm512_add_epi16(v, mask), _mm512_set1_epi16(kVoteMin)); }
#include "ray_walk.inc"
#include "ray_walk_lanes512.inc"
}  // namespace avx512
#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif  // __x86_64__

constexpr bool CompiledForX86() {
#if defined(__x86_64__)
  return true;
#else
  return false;
#endif
}

using WalkRaysFn = void (*)(const RaySetup*, size_t, WalkContext*);

// Whether the kernel sets its rays up in lanes too and walks them tile by tile (AVX-512:
// avx512::InsertTile) for columns of nz votes.
bool LaneSetup(InsertKernel kernel, int nz) {
#if defined(__x86_64__)
  return kernel == InsertKernel::kAvx512 && nz >= avx512::kLanes;
#else
  (void)kernel;
  (void)nz;
  return false;
#endif
}

// The walk of the kernels without LaneSetup for columns of nz votes: a narrower one where a
// column is shorter than a block (the votes do not depend on the kernel).
WalkRaysFn KernelWalk(InsertKernel kernel, int nz) {
#if defined(__x86_64__)
  if ((kernel == InsertKernel::kAvx512 || kernel == InsertKernel::kAvx2) && nz >= avx2::kLanes) return &avx2::WalkRaysInLanes;
  if (kernel != InsertKernel::kScalar && nz >= sse2::kLanes) return &sse2::WalkRays;
#endif
  return &scalar::WalkRays;
}

// Slabs of rows [slab[t], slab[t + 1]) with about equal numbers of rays (the rays are where the
// camera looks), from rays counted per row (threads x ny counters, summed over threads). Without
// a ray the slabs stay as they are.
void BalanceSlabs(const std::vector<uint32_t>& row_weight, int threads, int ny, std::vector<int>* slab) {
  uint64_t total = 0;
  for (uint32_t w : row_weight) total += w;
  if (total == 0) return;
  (*slab)[0] = 0;
  (*slab)[threads] = ny;
  uint64_t cumulative = 0;
  int t = 1;
  for (int iy = 0; iy < ny && t < threads; ++iy) {
    for (int c = 0; c < threads; ++c) cumulative += row_weight[static_cast<size_t>(c) * ny + iy];
    while (t < threads && cumulative * threads >= total * t) (*slab)[t++] = iy + 1;
  }
  while (t < threads) (*slab)[t++] = ny;
}

}  // namespace

void InsertStats::Add(const InsertStats& o) {
  frames += o.frames;
  pixels += o.pixels;
  no_measurement += o.no_measurement;
  invalid_depth += o.invalid_depth;
  rays += o.rays;
  rays_missing_box += o.rays_missing_box;
  points_outside_box += o.points_outside_box;
  hits += o.hits;
  misses += o.misses;
  critical_path_cpu_ms += o.critical_path_cpu_ms;
}

std::string InsertStats::BriefReport() const {
  std::ostringstream s;
  s << frames << " frame(s), " << pixels << " pixels: " << rays << " rays, " << no_measurement
    << " without measurement, " << invalid_depth << " invalid (NaN/inf/negative) skipped; "
    << rays_missing_box << " rays miss the box, " << points_outside_box << " points outside it; "
    << hits << " hits, " << misses << " misses";
  return s.str();
}

const char* InsertKernelName(InsertKernel kernel) {
  switch (kernel) {
    case InsertKernel::kAuto:
      return "auto";
    case InsertKernel::kAvx512:
      return "avx512";
    case InsertKernel::kAvx2:
      return "avx2";
    case InsertKernel::kSse2:
      return "sse2";
    case InsertKernel::kScalar:
      return "scalar";
  }
  return "?";
}

std::string InserterOptions::Problem() const {
  if (threads < 1 || threads > 256) {
    return "threads = " + std::to_string(threads) + ": must be in [1, 256]";
  }
  if ((kernel == InsertKernel::kAvx512 && !CpuHasAvx512()) || (kernel == InsertKernel::kAvx2 && !CpuHasAvx2()) ||
      (kernel == InsertKernel::kSse2 && !CompiledForX86())) {
    return std::string("kernel = ") + InsertKernelName(kernel) + ": this CPU does not support it";
  }
  return "";
}

struct FrameInserter::Workspace {
  explicit Workspace(int threads) : pool(threads) {}

  WorkerPool pool;
  bool has_camera = false;
  CameraModel camera;
  std::vector<double> ray_C;      // 2 per pixel: camera.Ray(u, v) x, y (its z is exactly 1)
  // Ray setups of the kernels without a lane setup: one tile's at one thread; else one slot per
  // pixel, chunk c's rays from its first pixel. malloc'd, not zero-filled: only the slots valid
  // pixels use ever become resident (17 MB at 640 x 480 otherwise).
  struct Free {
    void operator()(void* p) const { std::free(p); }
  };
  std::unique_ptr<RaySetup[], Free> rays;
  // Per thread: room for the frame's hits in its rows, one per pixel (plus kHitSlack). Not
  // zeroed, so only the pages its hits reach are resident (a vector made all of them so: 2.5 MB
  // per thread at 640 x 480, of which the benchmark's frames use ~0.9).
  std::vector<std::unique_ptr<HitRecord[]>> hits;
#if defined(__x86_64__)
  std::vector<std::unique_ptr<avx512::TileRays>> tile_rays;  // per thread: its tile (AVX-512 setup)
#endif
  std::vector<size_t> chunk_begin;     // chunk c's first ray slot (its first pixel)
  std::vector<std::vector<size_t>> tile_end;  // per chunk: each tile's end in its rays
  std::vector<InsertStats> chunk_stats;
  std::vector<SegmentBounds> chunk_bounds;
  std::vector<uint32_t> row_weight;    // threads x ny: rays per row, for balancing slabs (lane setups: thread 0's)
  std::vector<int> slab;               // threads + 1 row boundaries
  bool slab_balanced = false;          // slab holds a frame's balance (lane setups: the last frame's)
};

FrameInserter::FrameInserter(VotingGrid* grid, const InserterOptions& options)
    : grid_(grid), options_(options) {
  ROMUNECT_CHECK(grid != nullptr);
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError("fusion inserter", "options", problem);
  kernel_ = options.kernel;
  if (kernel_ == InsertKernel::kAuto) {
    kernel_ = CpuHasAvx512() ? InsertKernel::kAvx512
              : CpuHasAvx2() ? InsertKernel::kAvx2
              : CompiledForX86() ? InsertKernel::kSse2
                                 : InsertKernel::kScalar;
  }
  ws_ = std::make_unique<Workspace>(options.threads);
  ws_->chunk_begin.assign(options.threads, 0);
  ws_->hits.resize(options.threads);
  ws_->tile_end.resize(options.threads);
  ws_->chunk_stats.assign(options.threads, InsertStats{});
  ws_->chunk_bounds.assign(options.threads, SegmentBounds{});
  ws_->row_weight.assign(static_cast<size_t>(options.threads) * grid->ny(), 0);
  ws_->slab.assign(options.threads + 1, 0);
#if defined(__x86_64__)
  if (LaneSetup(kernel_, grid->nz())) {
    for (int t = 0; t < options.threads; ++t) ws_->tile_rays.push_back(std::make_unique<avx512::TileRays>());
  }
#endif
}

FrameInserter::~FrameInserter() = default;

void FrameInserter::Insert(const CameraModel& camera, const cv::Mat& depth_m, const Pose& T_W_C,
                           InsertStats* stats) {
  ROMUNECT_CHECK(depth_m.type() == CV_32FC1);
  ROMUNECT_CHECK(depth_m.rows == camera.height && depth_m.cols == camera.width);
  Workspace& ws = *ws_;
  const int width = camera.width, height = camera.height;
  const size_t pixels = static_cast<size_t>(width) * height;
  if (!ws.has_camera || !(ws.camera == camera)) {
    ws.camera = camera;
    ws.has_camera = true;
    ws.ray_C.resize(2 * pixels);
    // Without a lane setup, one thread walks each tile's rays as it sets them up; threads share
    // a frame's setups.
    if (!LaneSetup(kernel_, grid_->nz())) {
      const size_t slots = options_.threads == 1 ? static_cast<size_t>(kInsertionTilePx) * kInsertionTilePx : pixels;
      ws.rays.reset(static_cast<RaySetup*>(std::malloc(slots * sizeof(RaySetup))));
      if (ws.rays == nullptr) throw std::bad_alloc();
    }
    for (auto& hits : ws.hits) hits.reset(new HitRecord[pixels + kHitSlack]);  // one hit per pixel at most
    for (int v = 0; v < height; ++v) {
      for (int u = 0; u < width; ++u) {
        const Eigen::Vector3d r = camera.Ray(Eigen::Vector2d(u, v));
        ROMUNECT_CHECK(r.z() == 1.0);  // CameraModel::Ray's contract; the walk relies on it
        double* out = &ws.ray_C[2 * (static_cast<size_t>(v) * width + u)];
        out[0] = r.x();
        out[1] = r.y();
      }
    }
  }

  const VotingGrid& grid = *grid_;
  const int threads = options_.threads;
  const int n[3] = {grid.nx(), grid.ny(), grid.nz()};
  const double voxel = grid.voxel_m();
  const Eigen::Vector3d& min_W = grid.options().min_W;
  const Eigen::Matrix3d R = T_W_C.linear();
  const Eigen::Vector3d o_W = T_W_C.translation();
  double o_g[3];
  for (int a = 0; a < 3; ++a) o_g[a] = (o_W[a] - min_W[a]) / voxel;

  VotingGrid* mutable_grid = grid_;
  auto make_context = [&](int thread, int ya, int yb) {
    return WalkContext{o_g[0], o_g[1], o_g[2], n[0], n[1], n[2], ya, yb, mutable_grid->mutable_column(0),
                       ws.hits[thread].get(), 0, 0};
  };
  size_t thread_hits[256] = {}, thread_misses[256] = {};

  double thread_cpu_ms[256] = {};  // per thread, all phases: the frame's critical path
  constexpr int kTile = kInsertionTilePx;
  if (LaneSetup(kernel_, n[2])) {
#if defined(__x86_64__)
    // Every thread sets all of the frame's tiles up in lanes and walks, tile by tile while the
    // rays are in cache, those that may touch its slab of rows, balanced on the last frame's
    // rays (the votes do not depend on the slabs); thread 0 counts. Setting a frame up costs a
    // tenth of walking it, and no frame of setups is kept or shared.
    SetupFrame setup_frame{};
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) setup_frame.R[a][b] = R(a, b);
      setup_frame.o_W[a] = o_W[a];
      setup_frame.min_W[a] = min_W[a];
      setup_frame.o_g[a] = o_g[a];
      setup_frame.n[a] = n[a];
    }
    setup_frame.voxel = voxel;
    setup_frame.ray_C = ws.ray_C.data();
    setup_frame.width = width;
    if (!ws.slab_balanced) {  // one thread, or the first frame: rows split evenly
      for (int t = 0; t <= threads; ++t) ws.slab[t] = static_cast<int>(static_cast<int64_t>(n[1]) * t / threads);
    }
    if (threads > 1) std::fill(ws.row_weight.begin(), ws.row_weight.end(), 0u);  // thread 0 counts into it
    auto insert = [&](int thread) {
      const double cpu0 = ThreadCpuMs();
      InsertStats& s = ws.chunk_stats[thread];
      SegmentBounds& bounds = ws.chunk_bounds[thread];
      s = InsertStats{};
      bounds = SegmentBounds{};
      if (thread != 0 && ws.slab[thread] >= ws.slab[thread + 1]) return;  // no rows: nothing to walk or count
      InsertStats uncounted;
      SegmentBounds unbounded;
      InsertStats* counts = thread == 0 ? &s : &uncounted;
      SegmentBounds* widened = thread == 0 ? &bounds : &unbounded;
      uint32_t* weight = thread == 0 && threads > 1 ? ws.row_weight.data() : nullptr;
      WalkContext context = make_context(thread, ws.slab[thread], ws.slab[thread + 1]);
      avx512::TileAhead ahead;  // the next tile's lines
      auto tiles = [&](auto all_rows) {
        for (int tv = 0; tv < height; tv += kTile) {
          for (int tu = 0; tu < width; tu += kTile) {
            const int nu = tu + kTile < width ? tu + kTile : 0, nv = tu + kTile < width ? tv : tv + kTile;
            if (nv < height) {
              avx512::TileLines(setup_frame, depth_m, nu, std::min(nu + kTile, width), nv, std::min(nv + kTile, height),
                                context.ya, context.yb, context.votes, &ahead);
            } else {
              ahead.Clear();
            }
            avx512::InsertTile<all_rows()>(setup_frame, depth_m, tu, std::min(tu + kTile, width), tv,
                                           std::min(tv + kTile, height), ws.tile_rays[thread].get(), &context, counts,
                                           widened, weight, &ahead);
          }
        }
      };
      if (context.ya == 0 && context.yb == n[1]) {
        tiles(std::true_type{});
      } else {
        tiles(std::false_type{});
      }
      ApplyHits(context.hits, context.hit_count, mutable_grid);  // after the frame's misses in its rows
      if (thread == 0) s.pixels = pixels;
      thread_hits[thread] = context.hit_count;
      thread_misses[thread] = context.misses;
      thread_cpu_ms[thread] += ThreadCpuMs() - cpu0;
    };
    ws.pool.Run(insert);
    if (threads > 1) {
      BalanceSlabs(ws.row_weight, threads, n[1], &ws.slab);  // for the next frame
      ws.slab_balanced = true;
    }
#endif
  } else {
    const WalkRaysFn walk_rays = KernelWalk(kernel_, n[2]);
    // Phase 1: per band of tile rows, tile by tile, classify each pixel and set its ray up (clip
    // to the box). One thread walks each tile's rays right away (no frame-sized buffer, and the
    // rays are still in cache). A tile's rays cross neighbouring columns, which stay in cache.
    const int tile_rows = (height + kTile - 1) / kTile;
    auto setup = [&](int chunk) {
      const double cpu0 = ThreadCpuMs();
      const int v0 = std::min(height, kTile * static_cast<int>(static_cast<int64_t>(tile_rows) * chunk / threads));
      const int v1 = std::min(height, kTile * static_cast<int>(static_cast<int64_t>(tile_rows) * (chunk + 1) / threads));
      InsertStats& s = ws.chunk_stats[chunk];
      s = InsertStats{};
      SegmentBounds& bounds = ws.chunk_bounds[chunk];
      bounds = SegmentBounds{};
      const bool walk_now = threads == 1;
      uint32_t* weight = &ws.row_weight[static_cast<size_t>(chunk) * n[1]];
      if (!walk_now) std::fill(weight, weight + n[1], 0u);
      WalkContext context{};
      if (walk_now) context = make_context(0, 0, n[1]);
      ws.chunk_begin[chunk] = walk_now ? 0 : static_cast<size_t>(v0) * width;
      RaySetup* out = &ws.rays[ws.chunk_begin[chunk]];
      std::vector<size_t>& tile_end = ws.tile_end[chunk];
      tile_end.clear();
      size_t count = 0;
      for (int tv = v0; tv < v1; tv += kTile) {
        for (int tu = 0; tu < width; tu += kTile) {
          for (int v = tv; v < std::min(tv + kTile, v1); ++v) {
            const float* row = depth_m.ptr<float>(v);
            for (int u = tu; u < std::min(tu + kTile, width); ++u) {
              const float depth = row[u];
              if (depth == 0.0f) {
                ++s.no_measurement;
                continue;
              }
              if (!(depth > 0.0f) || !std::isfinite(depth)) {
                ++s.invalid_depth;
                continue;
              }
              ++s.rays;
              const double d = depth;
              const double* r = &ws.ray_C[2 * (static_cast<size_t>(v) * width + u)];
              RaySetup& ray = out[count];
              double dg[3];
              bool inside = true;
              for (int a = 0; a < 3; ++a) {
                // R(a, 2) * ray z with z = 1 is R(a, 2) exactly: the reference's double expression.
                const double dir = R(a, 0) * r[0] + R(a, 1) * r[1] + R(a, 2);
                const double p_W = o_W[a] + d * dir;
                ray.p_g[a] = (p_W - min_W[a]) / voxel;
                dg[a] = ray.p_g[a] - o_g[a];
                inside = inside && ray.p_g[a] >= 0.0 && ray.p_g[a] < n[a];
              }
              double t0 = 0.0, t1 = 1.0;
              for (int a = 0; a < 3; ++a) {
                if (dg[a] != 0.0) {
                  const double inv = 1.0 / dg[a];
                  double ta = (0.0 - o_g[a]) * inv, tb = (static_cast<double>(n[a]) - o_g[a]) * inv;
                  if (ta > tb) std::swap(ta, tb);
                  t0 = std::max(t0, ta);
                  t1 = std::min(t1, tb);
                } else if (!(o_g[a] >= 0.0 && o_g[a] < n[a])) {
                  t0 = 1.0;
                  t1 = 0.0;
                }
              }
              if (!inside) ++s.points_outside_box;
              if (!(t0 < t1)) {
                ++s.rays_missing_box;
                continue;
              }
              ray.t_enter = t0;
              ray.t_exit = t1;
              ray.ends_inside = inside;
              const double y0 = o_g[1] + t0 * dg[1], y1 = o_g[1] + t1 * dg[1];
              bounds.Add(o_g[0] + t0 * dg[0], o_g[0] + t1 * dg[0], y0, y1);
              if (!walk_now) {  // row bounds and slab balancing matter only when threads own slabs
                ray.iy_lo = static_cast<int32_t>(std::clamp(std::floor(std::min(y0, y1)) - 1.0, 0.0, n[1] - 1.0));
                ray.iy_hi = static_cast<int32_t>(std::clamp(std::floor(std::max(y0, y1)) + 1.0, 0.0, n[1] - 1.0));
                ++weight[(ray.iy_lo + ray.iy_hi) / 2];
              }
              ++count;
            }
          }
          if (walk_now) {
            walk_rays(out, count, &context);
            count = 0;
          } else {
            tile_end.push_back(count);
          }
        }
      }
      if (walk_now) {
        ApplyHits(context.hits, context.hit_count, mutable_grid);  // after the frame's misses (voting_grid.h)
        thread_hits[0] = context.hit_count;
        thread_misses[0] = context.misses;
      }
      s.pixels = static_cast<size_t>(v1 - v0) * width;
      thread_cpu_ms[chunk] += ThreadCpuMs() - cpu0;
    };
    ws.pool.Run(setup);
    BalanceSlabs(ws.row_weight, threads, n[1], &ws.slab);

    // Phase 2 (threads > 1): each thread walks every ray that may touch its own rows, votes only
    // in them, and then applies its hits (all in its rows, so after all of the frame's misses there).
    auto walk = [&](int thread) {
      const int ya = ws.slab[thread], yb = ws.slab[thread + 1];
      if (ya >= yb) return;
      const double cpu0 = ThreadCpuMs();
      WalkContext context = make_context(thread, ya, yb);
      for (int chunk = 0; chunk < threads; ++chunk) {
        size_t begin = 0;
        for (const size_t end : ws.tile_end[chunk]) {
          walk_rays(&ws.rays[ws.chunk_begin[chunk] + begin], end - begin, &context);
          begin = end;
        }
      }
      ApplyHits(context.hits, context.hit_count, mutable_grid);
      thread_hits[thread] = context.hit_count;
      thread_misses[thread] = context.misses;
      thread_cpu_ms[thread] += ThreadCpuMs() - cpu0;
    };
    if (threads > 1) ws.pool.Run(walk);
  }

  // The columns the frame may have changed: its segments' (x, y) range, widened by a column for
  // the rounding of the walk's crossings.
  SegmentBounds all;
  for (const SegmentBounds& b : ws.chunk_bounds) all.Merge(b);
  changed_columns_ = cv::Rect();
  if (all.x_lo <= all.x_hi) {
    const int x0 = StartIndex(all.x_lo - 1.0, n[0]), x1 = StartIndex(all.x_hi + 1.0, n[0]);
    const int y0 = StartIndex(all.y_lo - 1.0, n[1]), y1 = StartIndex(all.y_hi + 1.0, n[1]);
    changed_columns_ = cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1);
  }

  if (stats != nullptr) {
    InsertStats frame;
    frame.frames = 1;
    for (int t = 0; t < threads; ++t) {
      frame.critical_path_cpu_ms = std::max(frame.critical_path_cpu_ms, thread_cpu_ms[t]);
      frame.Add(ws.chunk_stats[t]);
      frame.hits += thread_hits[t];
      frame.misses += thread_misses[t];
    }
    stats->Add(frame);
  }
}

}  // namespace romunect::fusion
