#include "romunect/fusion/frame_inserter.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <iterator>
#include <new>
#include <sstream>
#include <vector>

#include "insert_kernel.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/parallel_rows.h"

namespace romunect::fusion {
namespace {

using insert_internal::HitRecord;
using insert_internal::InsertSlabFn;
using insert_internal::kHitSlack;
using insert_internal::kInsertionTilePx;
using insert_internal::kVoteMax;
using insert_internal::RaySetup;
using insert_internal::SegmentBounds;
using insert_internal::SetupFrame;
using insert_internal::StartIndex;
using insert_internal::TileRays;
using insert_internal::WalkContext;
using insert_internal::WalkRaysFn;

// The insertion kernels compiled in (insert_kernel.h), narrowest first. AVX-512 inserts a slab
// with its own lane setup; its walk, unused then, is AVX2's.
constexpr insert_internal::Kernel kKernels[] = {
    {Isa::kScalar, &insert_internal::WalkRaysScalar, nullptr, 1},
#if ROMUNECT_FUSION_KERNEL_SSE2
    {Isa::kSse2, &insert_internal::WalkRaysSse2, nullptr, insert_internal::kSse2BlockVotes},
#endif
#if ROMUNECT_FUSION_KERNEL_AVX2
    {Isa::kAvx2, &insert_internal::WalkRaysAvx2, nullptr, insert_internal::kAvx2BlockVotes},
#endif
#if ROMUNECT_FUSION_KERNEL_AVX512
    {Isa::kAvx512, &insert_internal::WalkRaysAvx2, &insert_internal::InsertSlabAvx512,
     insert_internal::kAvx512BlockVotes},
#endif
};

// The kernels for `requested` (ResolveIsa over kKernels); null where they are not compiled in or
// the CPU lacks them.
const insert_internal::Kernel* KernelFor(Isa requested) { return ResolveKernel(requested, kKernels); }

// The entry that runs for `kernel` (one of kKernels) on columns of nz votes: it, or where a column
// is shorter than its block the widest narrower entry whose block fits (the votes do not depend on
// the kernel). The scalar entry fits every column.
const insert_internal::Kernel& KernelForColumns(const insert_internal::Kernel* kernel, int nz) {
  while (kernel != std::begin(kKernels) && nz < kernel->min_nz) --kernel;
  return *kernel;
}

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

// One measured pixel's ray (voting_grid.h): direction, point and clip to the box, with the
// reference's double expressions (r: the pixel's camera ray x, y; its z is 1). Counts it; false
// when the segment misses the box. Widens *bounds by the segment's (x, y) and, with `rows`, sets
// the rows its walk may visit.
[[gnu::always_inline]] inline bool SetUpRay(const SetupFrame& f, double d, const double* r, bool rows, RaySetup* ray,
                                            InsertStats* s, SegmentBounds* bounds) {
  double dg[3];
  bool inside = true;
  for (int a = 0; a < 3; ++a) {
    // R(a, 2) * ray z with z = 1 is R(a, 2) exactly: the reference's double expression.
    const double dir = f.R[a][0] * r[0] + f.R[a][1] * r[1] + f.R[a][2];
    const double p_W = f.o_W[a] + d * dir;
    ray->p_g[a] = (p_W - f.min_W[a]) / f.voxel;
    dg[a] = ray->p_g[a] - f.o_g[a];
    inside = inside && ray->p_g[a] >= 0.0 && ray->p_g[a] < f.n[a];
  }
  double t0 = 0.0, t1 = 1.0;
  for (int a = 0; a < 3; ++a) {
    if (dg[a] != 0.0) {
      const double inv = 1.0 / dg[a];
      double ta = (0.0 - f.o_g[a]) * inv, tb = (static_cast<double>(f.n[a]) - f.o_g[a]) * inv;
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    } else if (!(f.o_g[a] >= 0.0 && f.o_g[a] < f.n[a])) {
      t0 = 1.0;
      t1 = 0.0;
    }
  }
  if (!inside) ++s->points_outside_box;
  if (!(t0 < t1)) {
    ++s->rays_missing_box;
    return false;
  }
  ray->t_enter = t0;
  ray->t_exit = t1;
  ray->ends_inside = inside;
  const double y0 = f.o_g[1] + t0 * dg[1], y1 = f.o_g[1] + t1 * dg[1];
  bounds->Add(f.o_g[0] + t0 * dg[0], f.o_g[0] + t1 * dg[0], y0, y1);
  if (rows) {  // row bounds matter only when threads own slabs
    ray->iy_lo = static_cast<int32_t>(std::clamp(std::floor(std::min(y0, y1)) - 1.0, 0.0, f.n[1] - 1.0));
    ray->iy_hi = static_cast<int32_t>(std::clamp(std::floor(std::max(y0, y1)) + 1.0, 0.0, f.n[1] - 1.0));
  }
  return true;
}

// Classifies the pixels of tile [u0, u1) x [v0, v1) and sets the rays of the measured ones up
// into out (room for one per pixel); returns how many enter the box. With `weight` (ny
// counters), each such ray gets its rows and counts at its middle row, for balancing slabs.
size_t SetUpTileRays(const SetupFrame& frame, const cv::Mat& depth_m, int u0, int u1, int v0, int v1, RaySetup* out,
                     InsertStats* s, SegmentBounds* bounds, uint32_t* weight) {
  const SetupFrame f = frame;  // a local copy: the stores to the rays cannot change it
  size_t count = 0;
  for (int v = v0; v < v1; ++v) {
    const float* row = depth_m.ptr<float>(v);
    for (int u = u0; u < u1; ++u) {
      const float depth = row[u];
      if (depth == 0.0f) {
        ++s->no_measurement;
        continue;
      }
      if (!(depth > 0.0f) || !std::isfinite(depth)) {
        ++s->invalid_depth;
        continue;
      }
      ++s->rays;
      const double* r = &f.ray_C[2 * (static_cast<size_t>(v) * f.width + u)];
      RaySetup& ray = out[count];
      if (!SetUpRay(f, depth, r, weight != nullptr, &ray, s, bounds)) continue;
      if (weight != nullptr) ++weight[(ray.iy_lo + ray.iy_hi) / 2];
      ++count;
    }
  }
  return count;
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
    << " without measurement, " << invalid_depth << " invalid (NaN/inf/negative) skipped; " << rays_missing_box
    << " rays miss the box, " << points_outside_box << " points outside it; " << hits << " hits, " << misses
    << " misses";
  return s.str();
}

std::string InserterOptions::Problem() const {
  if (threads < 1 || threads > 256) {
    return "threads = " + std::to_string(threads) + ": must be in [1, 256]";
  }
  if (KernelFor(isa) == nullptr) {
    return std::string("isa = ") + ToString(isa) +
           (CpuSupports(isa) ? ": the inserter has no kernel for it in this build" : ": this CPU does not support it");
  }
  return "";
}

// What the inserter keeps from frame to frame, and the phases of a frame. Per thread t: its
// chunk of tile rows in the setup, its slab of rows [slab[t], slab[t + 1]) in the walk, its
// counts (chunk_stats[t]: the pixels of its chunk, the votes of its slab) and its CPU time.
struct FrameInserter::Workspace {
  Workspace(VotingGrid* grid_in, int threads_in, const insert_internal::Kernel& kernel)
      : grid(grid_in),
        threads(threads_in),
        walk_rays(kernel.walk_rays),
        insert_slab(kernel.insert_slab),
        pool(threads_in) {
    chunk_begin.assign(threads, 0);
    hits.resize(threads);
    tile_end.resize(threads);
    chunk_stats.assign(threads, InsertStats{});
    chunk_bounds.assign(threads, SegmentBounds{});
    cpu_s.assign(threads, 0.0);
    row_weight.assign(static_cast<size_t>(threads) * grid->ny(), 0);
    slab.assign(threads + 1, 0);
    if (insert_slab != nullptr) {
      for (int t = 0; t < threads; ++t) tile_rays.push_back(std::make_unique<TileRays>());
    }
  }

  void UseCamera(const CameraModel& camera);
  SetupFrame Frame(const Pose& T_W_C) const;
  WalkContext Context(const SetupFrame& f, int thread, int ya, int yb) const;
  void FinishWalk(const WalkContext& c, InsertStats* s) const;
  // The kernels with a lane setup: each thread sets the frame up and walks its slab.
  void InsertInSlabs(const SetupFrame& f, const cv::Mat& depth_m);
  void InsertSlab(const SetupFrame& f, const cv::Mat& depth_m, int thread);
  // The others: phase 1 sets the frame up in chunks, phase 2 walks it in slabs.
  void SetUpThenWalk(const SetupFrame& f, const cv::Mat& depth_m);
  void SetUpChunk(const SetupFrame& f, const cv::Mat& depth_m, int chunk);
  void WalkSlab(const SetupFrame& f, int thread);
  cv::Rect ChangedColumns() const;
  InsertStats FrameStats() const;

  VotingGrid* grid;
  int threads;
  WalkRaysFn walk_rays;      // the walk of the set-up rays (phase 1 at one thread, phase 2)
  InsertSlabFn insert_slab;  // null: no lane setup
  WorkerPool pool;
  bool has_camera = false;
  CameraModel camera;
  std::vector<double> ray_C;  // 2 per pixel: camera.Ray(u, v) x, y (its z is exactly 1)
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
  std::vector<std::unique_ptr<TileRays>> tile_rays;  // per thread: its tile (lane setup)
  std::vector<size_t> chunk_begin;                   // chunk c's first ray slot (its first pixel)
  std::vector<std::vector<size_t>> tile_end;         // per chunk: each tile's end in its rays
  std::vector<InsertStats> chunk_stats;
  std::vector<SegmentBounds> chunk_bounds;
  std::vector<double> cpu_s;         // per thread, all phases of the frame: its critical path
  std::vector<uint32_t> row_weight;  // threads x ny: rays per row, for balancing slabs (lane setups: thread 0's)
  std::vector<int> slab;             // threads + 1 row boundaries
  bool slab_balanced = false;        // slab holds a frame's balance (lane setups: the last frame's)
};

// The camera's per-pixel rays, and the buffers sized by its pixels, when the camera changes.
void FrameInserter::Workspace::UseCamera(const CameraModel& new_camera) {
  if (has_camera && camera == new_camera) return;
  camera = new_camera;
  has_camera = true;
  const int width = camera.width, height = camera.height;
  const size_t pixels = static_cast<size_t>(width) * height;
  ray_C.resize(2 * pixels);
  // Without a lane setup, one thread walks each tile's rays as it sets them up; threads share a
  // frame's setups.
  if (insert_slab == nullptr) {
    const size_t slots = threads == 1 ? static_cast<size_t>(kInsertionTilePx) * kInsertionTilePx : pixels;
    rays.reset(static_cast<RaySetup*>(std::malloc(slots * sizeof(RaySetup))));
    if (rays == nullptr) throw std::bad_alloc();
  }
  for (auto& thread_hits : hits) thread_hits.reset(new HitRecord[pixels + kHitSlack]);  // one hit per pixel at most
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      const Eigen::Vector3d r = camera.Ray(Eigen::Vector2d(u, v));
      ROMUNECT_CHECK(r.z() == 1.0);  // CameraModel::Ray's contract; the walk relies on it
      double* out = &ray_C[2 * (static_cast<size_t>(v) * width + u)];
      out[0] = r.x();
      out[1] = r.y();
    }
  }
}

// The frame's constants for a camera at T_W_C.
SetupFrame FrameInserter::Workspace::Frame(const Pose& T_W_C) const {
  SetupFrame f{};
  const Eigen::Matrix3d R = T_W_C.linear();
  const Eigen::Vector3d o_W = T_W_C.translation();
  const Eigen::Vector3d& min_W = grid->options().min_W;
  const int n[3] = {grid->nx(), grid->ny(), grid->nz()};
  f.voxel = grid->voxel_m();
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) f.R[a][b] = R(a, b);
    f.o_W[a] = o_W[a];
    f.min_W[a] = min_W[a];
    f.o_g[a] = (o_W[a] - min_W[a]) / f.voxel;
    f.n[a] = n[a];
  }
  f.ray_C = ray_C.data();
  f.width = camera.width;
  return f;
}

// Thread `thread`'s walk of rows [ya, yb), its hits into its own list.
WalkContext FrameInserter::Workspace::Context(const SetupFrame& f, int thread, int ya, int yb) const {
  return WalkContext{f.o_g[0],           f.o_g[1], f.o_g[2], f.n[0], f.n[1], f.n[2], ya, yb, grid->mutable_column(0),
                     hits[thread].get(), 0,        0};
}

// A walk's hits, after the frame's misses in its rows (voting_grid.h), and its votes counted.
void FrameInserter::Workspace::FinishWalk(const WalkContext& c, InsertStats* s) const {
  ApplyHits(c.hits, c.hit_count, grid);
  s->hits = c.hit_count;
  s->misses = c.misses;
}

// Every thread sets all of the frame's tiles up in lanes and walks, tile by tile while the rays
// are in cache, those that may touch its slab of rows, balanced on the last frame's rays (the
// votes do not depend on the slabs); thread 0 counts. Setting a frame up costs a tenth of walking
// it, and no frame of setups is kept or shared.
void FrameInserter::Workspace::InsertInSlabs(const SetupFrame& f, const cv::Mat& depth_m) {
  const int ny = f.n[1];
  if (!slab_balanced) {  // one thread, or the first frame: rows split evenly
    for (int t = 0; t <= threads; ++t) slab[t] = static_cast<int>(static_cast<int64_t>(ny) * t / threads);
  }
  if (threads > 1) std::fill(row_weight.begin(), row_weight.end(), 0u);  // thread 0 counts into it
  auto insert = [&](int thread) { InsertSlab(f, depth_m, thread); };
  pool.Run(insert);
  if (threads > 1) {
    BalanceSlabs(row_weight, threads, ny, &slab);  // for the next frame
    slab_balanced = true;
  }
}

void FrameInserter::Workspace::InsertSlab(const SetupFrame& f, const cv::Mat& depth_m, int thread) {
  const double cpu0 = ThreadCpuSeconds();
  InsertStats& s = chunk_stats[thread];
  s = InsertStats{};
  chunk_bounds[thread] = SegmentBounds{};
  if (thread != 0 && slab[thread] >= slab[thread + 1]) return;  // no rows: nothing to walk or count
  InsertStats uncounted;
  SegmentBounds unbounded;
  InsertStats* counts = thread == 0 ? &s : &uncounted;
  SegmentBounds* bounds = thread == 0 ? &chunk_bounds[0] : &unbounded;
  uint32_t* weight = thread == 0 && threads > 1 ? row_weight.data() : nullptr;
  WalkContext context = Context(f, thread, slab[thread], slab[thread + 1]);
  insert_slab(f, depth_m, tile_rays[thread].get(), &context, counts, bounds, weight);
  FinishWalk(context, &s);
  if (thread == 0) s.pixels = static_cast<size_t>(depth_m.rows) * depth_m.cols;
  cpu_s[thread] += ThreadCpuSeconds() - cpu0;
}

void FrameInserter::Workspace::SetUpThenWalk(const SetupFrame& f, const cv::Mat& depth_m) {
  auto setup = [&](int chunk) { SetUpChunk(f, depth_m, chunk); };
  pool.Run(setup);
  BalanceSlabs(row_weight, threads, f.n[1], &slab);
  auto walk = [&](int thread) { WalkSlab(f, thread); };
  if (threads > 1) pool.Run(walk);
}

// Phase 1, per band of tile rows, tile by tile: classify each pixel and set its ray up (clip to
// the box). At one thread, the tile's rays are walked right away (no frame-sized buffer, and the
// rays are still in cache); a tile's rays cross neighbouring columns, which stay in cache.
void FrameInserter::Workspace::SetUpChunk(const SetupFrame& f, const cv::Mat& depth_m, int chunk) {
  const double cpu0 = ThreadCpuSeconds();
  constexpr int kTile = kInsertionTilePx;
  const int width = depth_m.cols, height = depth_m.rows, ny = f.n[1];
  const int tile_rows = (height + kTile - 1) / kTile;
  const int v0 = std::min(height, kTile * static_cast<int>(static_cast<int64_t>(tile_rows) * chunk / threads));
  const int v1 = std::min(height, kTile * static_cast<int>(static_cast<int64_t>(tile_rows) * (chunk + 1) / threads));
  InsertStats& s = chunk_stats[chunk];
  s = InsertStats{};
  SegmentBounds& bounds = chunk_bounds[chunk];
  bounds = SegmentBounds{};
  const bool walk_now = threads == 1;
  uint32_t* weight = walk_now ? nullptr : &row_weight[static_cast<size_t>(chunk) * ny];
  if (!walk_now) std::fill(weight, weight + ny, 0u);
  WalkContext context = walk_now ? Context(f, 0, 0, ny) : WalkContext{};
  chunk_begin[chunk] = walk_now ? 0 : static_cast<size_t>(v0) * width;
  RaySetup* out = &rays[chunk_begin[chunk]];
  std::vector<size_t>& ends = tile_end[chunk];
  ends.clear();
  size_t count = 0;
  for (int tv = v0; tv < v1; tv += kTile) {
    for (int tu = 0; tu < width; tu += kTile) {
      count += SetUpTileRays(f, depth_m, tu, std::min(tu + kTile, width), tv, std::min(tv + kTile, v1), out + count, &s,
                             &bounds, weight);
      if (walk_now) {
        walk_rays(out, count, &context);
        count = 0;
      } else {
        ends.push_back(count);
      }
    }
  }
  if (walk_now) FinishWalk(context, &s);
  s.pixels = static_cast<size_t>(v1 - v0) * width;
  cpu_s[chunk] += ThreadCpuSeconds() - cpu0;
}

// Phase 2 (threads > 1): each thread walks every ray that may touch its own rows, votes only in
// them, and then applies its hits (all in its rows, so after all of the frame's misses there).
void FrameInserter::Workspace::WalkSlab(const SetupFrame& f, int thread) {
  const int ya = slab[thread], yb = slab[thread + 1];
  if (ya >= yb) return;
  const double cpu0 = ThreadCpuSeconds();
  WalkContext context = Context(f, thread, ya, yb);
  for (int chunk = 0; chunk < threads; ++chunk) {
    size_t begin = 0;
    for (const size_t end : tile_end[chunk]) {
      walk_rays(&rays[chunk_begin[chunk] + begin], end - begin, &context);
      begin = end;
    }
  }
  FinishWalk(context, &chunk_stats[thread]);
  cpu_s[thread] += ThreadCpuSeconds() - cpu0;
}

// The columns the frame may have changed: its segments' (x, y) range, widened by a column for the
// rounding of the walk's crossings.
cv::Rect FrameInserter::Workspace::ChangedColumns() const {
  SegmentBounds all;
  for (const SegmentBounds& b : chunk_bounds) all.Merge(b);
  if (!(all.x_lo <= all.x_hi)) return cv::Rect();
  const int x0 = StartIndex(all.x_lo - 1.0, grid->nx()), x1 = StartIndex(all.x_hi + 1.0, grid->nx());
  const int y0 = StartIndex(all.y_lo - 1.0, grid->ny()), y1 = StartIndex(all.y_hi + 1.0, grid->ny());
  return cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1);
}

// The frame's counts over all threads; its CPU time is the busiest thread's.
InsertStats FrameInserter::Workspace::FrameStats() const {
  InsertStats frame;
  frame.frames = 1;
  for (int t = 0; t < threads; ++t) {
    frame.Add(chunk_stats[t]);
    frame.critical_path_cpu_ms = std::max(frame.critical_path_cpu_ms, 1e3 * cpu_s[t]);
  }
  return frame;
}

FrameInserter::FrameInserter(VotingGrid* grid, const InserterOptions& options) : grid_(grid), options_(options) {
  ROMUNECT_CHECK(grid != nullptr);
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError("fusion inserter", "options", problem);
  const insert_internal::Kernel* kernel = KernelFor(options.isa);  // not null: Problem() is empty
  isa_ = kernel->isa;
  ws_ = std::make_unique<Workspace>(grid, options.threads, KernelForColumns(kernel, grid->nz()));
}

FrameInserter::~FrameInserter() = default;

void FrameInserter::Insert(const CameraModel& camera, const cv::Mat& depth_m, const Pose& T_W_C, InsertStats* stats) {
  ROMUNECT_CHECK(depth_m.type() == CV_32FC1);
  ROMUNECT_CHECK(depth_m.rows == camera.height && depth_m.cols == camera.width);
  Workspace& ws = *ws_;
  ws.UseCamera(camera);
  const SetupFrame frame = ws.Frame(T_W_C);
  std::fill(ws.cpu_s.begin(), ws.cpu_s.end(), 0.0);
  if (ws.insert_slab != nullptr) {
    ws.InsertInSlabs(frame, depth_m);
  } else {
    ws.SetUpThenWalk(frame, depth_m);
  }
  changed_columns_ = ws.ChangedColumns();
  if (stats != nullptr) stats->Add(ws.FrameStats());
}

}  // namespace romunect::fusion
