#include "romunect/fusion/frame_inserter.h"

#include <time.h>

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <mutex>
#include <new>
#include <sstream>
#include <thread>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect::fusion {
namespace {

constexpr Vote kVoteMax = std::numeric_limits<Vote>::max();
constexpr Vote kVoteMin = -kVoteMax;  // symmetric saturation

// A fixed set of threads that run one job at a time; the caller is thread 0. Jobs are passed as
// a function pointer and context, so running one allocates nothing.
class WorkerPool {
 public:
  explicit WorkerPool(int threads) {
    for (int t = 1; t < threads; ++t) workers_.emplace_back([this, t] { WorkerLoop(t); });
  }
  ~WorkerPool() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    start_cv_.notify_all();
    for (std::thread& w : workers_) w.join();
  }

  // Runs f(thread) on every thread, f(0) on the caller; returns when all are done.
  template <class F>
  void Run(F& f) {
    RunImpl(&Trampoline<F>, &f);
  }

 private:
  template <class F>
  static void Trampoline(void* context, int thread) {
    (*static_cast<F*>(context))(thread);
  }

  void RunImpl(void (*fn)(void*, int), void* context) {
    if (workers_.empty()) {
      fn(context, 0);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      fn_ = fn;
      context_ = context;
      pending_ = static_cast<int>(workers_.size());
      ++generation_;
    }
    start_cv_.notify_all();
    fn(context, 0);
    std::unique_lock<std::mutex> lock(mutex_);
    done_cv_.wait(lock, [this] { return pending_ == 0; });
  }

  void WorkerLoop(int thread) {
    uint64_t seen = 0;
    for (;;) {
      void (*fn)(void*, int);
      void* context;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        start_cv_.wait(lock, [&] { return stop_ || generation_ != seen; });
        if (stop_) return;
        seen = generation_;
        fn = fn_;
        context = context_;
      }
      fn(context, thread);
      {
        std::lock_guard<std::mutex> lock(mutex_);
        if (--pending_ == 0) done_cv_.notify_one();
      }
    }
  }

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_, done_cv_;
  uint64_t generation_ = 0;
  int pending_ = 0;
  bool stop_ = false;
  void (*fn_)(void*, int) = nullptr;
  void* context_ = nullptr;
};

// One cast ray, set up once per frame (phase 1) and walked by every slab owner (phase 2).
struct RaySetup {
  double p_g[3];           // measured point, grid units
  double t_enter, t_exit;  // the segment's part inside the box
  int32_t iy_lo, iy_hi;    // rows the walk may visit (conservative, for slab skipping)
  bool ends_inside;        // the point is in the grid: the last voxel gets a hit
};

// Misses for votes [lo, end) of a column of nz votes (saturating at kVoteMin). Runs are short
// (a handful to a few dozen voxels) and of every length, so the compiler's vectorized loop spends
// its time in scalar prologue and epilogue; here full 8-lane blocks and one masked last block.
// The masked block may cover votes of the same column outside the run: it rewrites them with
// their own value, and the column belongs to this thread (threads own rows), so that is safe.
inline void ApplyMissRun(Vote* column, int lo, int end, int nz) {
#if defined(__SSE2__)
  if (nz >= 8 && nz <= 32760) {  // lane indices must fit signed 16 bits
    const __m128i floor_v = _mm_set1_epi16(kVoteMin);
    int k = lo;
    for (; k + 8 <= end; k += 8) {
      __m128i* p = reinterpret_cast<__m128i*>(column + k);
      const __m128i v = _mm_loadu_si128(p);
      _mm_storeu_si128(p, _mm_max_epi16(_mm_sub_epi16(v, _mm_set1_epi16(1)), floor_v));
    }
    if (k < end) {
      const int s = std::max(end - 8, 0);  // [s, s + 8) lies in the column since nz >= 8
      const __m128i lane = _mm_add_epi16(_mm_set1_epi16(static_cast<int16_t>(s)), _mm_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7));
      const __m128i active = _mm_and_si128(_mm_cmpgt_epi16(lane, _mm_set1_epi16(static_cast<int16_t>(k - 1))),
                                           _mm_cmplt_epi16(lane, _mm_set1_epi16(static_cast<int16_t>(end))));
      __m128i* p = reinterpret_cast<__m128i*>(column + s);
      const __m128i v = _mm_loadu_si128(p);
      // Active lanes are -1: v - 1 >= -32768 cannot wrap; inactive lanes keep v >= kVoteMin.
      _mm_storeu_si128(p, _mm_max_epi16(_mm_add_epi16(v, active), floor_v));
    }
    return;
  }
#endif
  for (int k = lo; k < end; ++k) column[k] = static_cast<Vote>(std::max(column[k] - 1, int{kVoteMin}));
}

double ThreadCpuMs() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

inline void ApplyHit(Vote* v) { *v = static_cast<Vote>(std::min(*v + 1, int{kVoteMax})); }

struct WalkContext {
  double ox, oy, oz;  // camera centre, grid units
  int nx, ny, nz;
  int ya, yb;         // this thread's rows [ya, yb)
  Vote* votes;
  uint16_t* hit_lo;
  uint16_t* hit_hi;
  size_t hits, misses;
};

// The start voxel on one axis: clamp(floor(x)) into [0, n).
inline int StartIndex(double x, int n) { return static_cast<int>(std::clamp(std::floor(x), 0.0, n - 1.0)); }

// Walks one ray through the columns of the thread's rows (voting_grid.h semantics). State is in
// scalars and the x/y step is branch-free: the walk is dominated by per-column overhead.
inline void WalkRay(const RaySetup& ray, WalkContext* c) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  constexpr double kNearPlane = 1e-7;  // voxel units; rounding errors are below 1e-11
  const double ox = c->ox, oy = c->oy, oz = c->oz;
  const int nx = c->nx, ny = c->ny, nz = c->nz, ya = c->ya, yb = c->yb;
  const double dx = ray.p_g[0] - ox, dy = ray.p_g[1] - oy, dz = ray.p_g[2] - oz;
  const double inv_x = 1.0 / dx, inv_y = 1.0 / dy, inv_z = 1.0 / dz;
  int ix = StartIndex(ox + ray.t_enter * dx, nx);
  int iy = StartIndex(oy + ray.t_enter * dy, ny);
  int iz = StartIndex(oz + ray.t_enter * dz, nz);
  const int sx = dx > 0.0 ? 1 : (dx < 0.0 ? -1 : 0);
  const int sy = dy > 0.0 ? 1 : (dy < 0.0 ? -1 : 0);
  const int sz = dz > 0.0 ? 1 : (dz < 0.0 ? -1 : 0);
  const int bx = dx > 0.0, by = dy > 0.0, bz = dz > 0.0;  // next plane = index + b
  // Crossing out of voxel k on an axis: the exact expression of the 3D walk.
  auto t_x = [&](int k) { return sx != 0 ? (static_cast<double>(k + bx) - ox) * inv_x : kInf; };
  auto t_y = [&](int k) { return sy != 0 ? (static_cast<double>(k + by) - oy) * inv_y : kInf; };
  auto t_z = [&](int k) { return (static_cast<double>(k + bz) - oz) * inv_z; };
  double tx = t_x(ix), ty = t_y(iy);
  const double t_exit = ray.t_exit;
  const int z_end = sz > 0 ? nz - 1 : 0;
  for (;;) {
    const double t_column = std::min(tx, ty);
    const double limit = std::min(t_column, t_exit);
    // The last z voxel in this column: the first k (from iz on) whose crossing is not < limit.
    // Crossings grow monotonically along the walk, so estimate from the z at `limit` and settle
    // with the exact comparisons.
    int iz_last = iz;
    if (sz != 0) {
      const double z_at_limit = oz + limit * dz;
      const double z_limit = std::floor(z_at_limit);
      iz_last = static_cast<int>(sz > 0 ? std::clamp(z_limit, static_cast<double>(iz), nz - 1.0)
                                        : std::clamp(z_limit, 0.0, static_cast<double>(iz)));
      // Away from a plane, the comparisons cannot disagree with the floor (their rounding is
      // ~1e-12 voxel); only near one do they decide.
      const double fraction = z_at_limit - z_limit;
      if (fraction < kNearPlane || fraction > 1.0 - kNearPlane) {
        while (iz_last != iz && !(t_z(iz_last - sz) < limit)) iz_last -= sz;
        while (iz_last != z_end && t_z(iz_last) < limit) iz_last += sz;
      }
    }
    const bool ends_here = !(t_column < t_exit);
    if (iy >= ya && iy < yb) {
      const size_t column_index = static_cast<size_t>(iy) * nx + ix;
      Vote* column = c->votes + column_index * nz;
      const int lo = std::min(iz, iz_last), hi = std::max(iz, iz_last);
      if (ends_here && ray.ends_inside) {  // the last voxel gets the hit, the rest misses
        ApplyMissRun(column, lo + (sz < 0), lo + (sz < 0) + hi - lo, nz);
        ApplyHit(column + iz_last);
        c->misses += hi - lo;
        ++c->hits;
        c->hit_lo[column_index] = std::min<uint16_t>(c->hit_lo[column_index], static_cast<uint16_t>(iz_last));
        c->hit_hi[column_index] = std::max<uint16_t>(c->hit_hi[column_index], static_cast<uint16_t>(iz_last));
      } else {
        ApplyMissRun(column, lo, hi + 1, nz);
        c->misses += hi - lo + 1;
      }
    }
    if (ends_here) break;
    iz = iz_last;
    const int step_x = tx <= ty;  // ties: x first, as in the 3D walk
    ix += step_x * sx;
    iy += (1 - step_x) * sy;
    if (static_cast<unsigned>(ix) >= static_cast<unsigned>(nx) ||
        static_cast<unsigned>(iy) >= static_cast<unsigned>(ny)) {
      break;  // cannot happen before t_exit; a guard
    }
    if (sy > 0 ? iy >= yb : iy < ya) break;  // left this thread's rows for good
    __builtin_prefetch(c->votes + (static_cast<size_t>(iy) * nx + ix) * nz + iz);
    // Only the stepped axis gets a new crossing (the same expression as t_x / t_y).
    const double plane = static_cast<double>(step_x ? ix + bx : iy + by);
    const double t_new = (plane - (step_x ? ox : oy)) * (step_x ? inv_x : inv_y);
    tx = step_x ? t_new : tx;
    ty = step_x ? ty : t_new;
  }
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

std::string InserterOptions::Problem() const {
  if (threads < 1 || threads > 256) {
    return "threads = " + std::to_string(threads) + ": must be in [1, 256]";
  }
  return "";
}

struct FrameInserter::Workspace {
  explicit Workspace(int threads) : pool(threads) {}

  WorkerPool pool;
  bool has_camera = false;
  CameraModel camera;
  std::vector<double> ray_C;      // 2 per pixel: camera.Ray(u, v) x, y (its z is exactly 1)
  // One slot per pixel; chunk c's rays start at its first pixel. malloc'd, not zero-filled:
  // only the slots valid pixels use ever become resident (17 MB at 640 x 480 otherwise).
  struct Free {
    void operator()(void* p) const { std::free(p); }
  };
  std::unique_ptr<RaySetup[], Free> rays;
  std::vector<size_t> chunk_count;     // rays set up by chunk c
  std::vector<InsertStats> chunk_stats;
  std::vector<uint32_t> row_weight;    // threads x ny: rays per row, for balancing slabs
  std::vector<int> slab;               // threads + 1 row boundaries
};

FrameInserter::FrameInserter(VotingGrid* grid, const InserterOptions& options)
    : grid_(grid), options_(options) {
  ROMUNECT_CHECK(grid != nullptr);
  const std::string problem = options.Problem();
  if (!problem.empty()) throw InputError("fusion inserter", "options", problem);
  ws_ = std::make_unique<Workspace>(options.threads);
  ws_->chunk_count.assign(options.threads, 0);
  ws_->chunk_stats.assign(options.threads, InsertStats{});
  ws_->row_weight.assign(static_cast<size_t>(options.threads) * grid->ny(), 0);
  ws_->slab.assign(options.threads + 1, 0);
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
    ws.rays.reset(static_cast<RaySetup*>(std::malloc(pixels * sizeof(RaySetup))));
    if (ws.rays == nullptr) throw std::bad_alloc();
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

  // Phase 1: per pixel rows, classify each pixel and set its ray up (clip to the box).
  double thread_cpu_ms[256] = {};  // per thread, both phases: the frame's critical path
  auto setup = [&](int chunk) {
    const double cpu0 = ThreadCpuMs();
    const int v0 = static_cast<int>(static_cast<int64_t>(height) * chunk / threads);
    const int v1 = static_cast<int>(static_cast<int64_t>(height) * (chunk + 1) / threads);
    InsertStats& s = ws.chunk_stats[chunk];
    s = InsertStats{};
    uint32_t* weight = &ws.row_weight[static_cast<size_t>(chunk) * n[1]];
    std::fill(weight, weight + n[1], 0u);
    RaySetup* out = &ws.rays[static_cast<size_t>(v0) * width];
    size_t count = 0;
    for (int v = v0; v < v1; ++v) {
      const float* row = depth_m.ptr<float>(v);
      for (int u = 0; u < width; ++u) {
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
        ray.iy_lo = static_cast<int32_t>(std::clamp(std::floor(std::min(y0, y1)) - 1.0, 0.0, n[1] - 1.0));
        ray.iy_hi = static_cast<int32_t>(std::clamp(std::floor(std::max(y0, y1)) + 1.0, 0.0, n[1] - 1.0));
        ++weight[(ray.iy_lo + ray.iy_hi) / 2];
        ++count;
      }
    }
    ws.chunk_count[chunk] = count;
    s.pixels = static_cast<size_t>(v1 - v0) * width;
    thread_cpu_ms[chunk] += ThreadCpuMs() - cpu0;
  };
  ws.pool.Run(setup);

  // Slabs of rows with about equal numbers of rays (the rays are where the camera looks).
  uint64_t total = 0;
  for (uint32_t w : ws.row_weight) total += w;
  ws.slab[0] = 0;
  ws.slab[threads] = n[1];
  {
    uint64_t cumulative = 0;
    int t = 1;
    for (int iy = 0; iy < n[1] && t < threads; ++iy) {
      for (int c = 0; c < threads; ++c) cumulative += ws.row_weight[static_cast<size_t>(c) * n[1] + iy];
      while (t < threads && cumulative * threads >= total * t) ws.slab[t++] = iy + 1;
    }
    while (t < threads) ws.slab[t++] = n[1];
  }

  // Phase 2: each thread walks every ray in pixel order and votes only in its own rows.
  size_t thread_hits[256] = {}, thread_misses[256] = {};
  VotingGrid* mutable_grid = grid_;
  uint16_t* hit_lo = mutable_grid->mutable_hit_lo();
  uint16_t* hit_hi = mutable_grid->mutable_hit_hi();
  auto walk = [&](int thread) {
    const int ya = ws.slab[thread], yb = ws.slab[thread + 1];
    if (ya >= yb) return;
    const double cpu0 = ThreadCpuMs();
    WalkContext context{o_g[0], o_g[1], o_g[2], n[0], n[1], n[2], ya, yb, mutable_grid->mutable_column(0),
                        hit_lo, hit_hi, 0, 0};
    for (int chunk = 0; chunk < threads; ++chunk) {
      const int v0 = static_cast<int>(static_cast<int64_t>(height) * chunk / threads);
      const RaySetup* rays = &ws.rays[static_cast<size_t>(v0) * width];
      const size_t count = ws.chunk_count[chunk];
      for (size_t i = 0; i < count; ++i) {
        const RaySetup& ray = rays[i];
        if (ray.iy_hi < ya || ray.iy_lo >= yb) continue;
        WalkRay(ray, &context);
      }
    }
    thread_hits[thread] = context.hits;
    thread_misses[thread] = context.misses;
    thread_cpu_ms[thread] += ThreadCpuMs() - cpu0;
  };
  ws.pool.Run(walk);

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
