#include "romunect/fusion/frame_inserter.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <limits>
#include <mutex>
#include <sstream>
#include <thread>
#include <vector>

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

inline void ApplyMisses(Vote* v, int n) {
  for (int k = 0; k < n; ++k) v[k] = static_cast<Vote>(std::max(v[k] - 1, int{kVoteMin}));
}

inline void ApplyHit(Vote* v) { *v = static_cast<Vote>(std::min(*v + 1, int{kVoteMax})); }

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
  std::vector<double> ray_C;      // 3 per pixel: camera.Ray(u, v), z = 1
  std::vector<RaySetup> rays;     // one slot per pixel; chunk c's rays start at its first pixel
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
    ws.ray_C.resize(3 * pixels);
    ws.rays.resize(pixels);
    for (int v = 0; v < height; ++v) {
      for (int u = 0; u < width; ++u) {
        const Eigen::Vector3d r = camera.Ray(Eigen::Vector2d(u, v));
        double* out = &ws.ray_C[3 * (static_cast<size_t>(v) * width + u)];
        out[0] = r.x();
        out[1] = r.y();
        out[2] = r.z();
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
  auto setup = [&](int chunk) {
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
        const double* r = &ws.ray_C[3 * (static_cast<size_t>(v) * width + u)];
        RaySetup& ray = out[count];
        double dg[3];
        bool inside = true;
        for (int a = 0; a < 3; ++a) {
          const double dir = R(a, 0) * r[0] + R(a, 1) * r[1] + R(a, 2) * r[2];
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
    size_t hits = 0, misses = 0;
    if (ya >= yb) return;
    for (int chunk = 0; chunk < threads; ++chunk) {
      const int v0 = static_cast<int>(static_cast<int64_t>(height) * chunk / threads);
      const RaySetup* rays = &ws.rays[static_cast<size_t>(v0) * width];
      const size_t count = ws.chunk_count[chunk];
      for (size_t i = 0; i < count; ++i) {
        const RaySetup& ray = rays[i];
        if (ray.iy_hi < ya || ray.iy_lo >= yb) continue;
        double dg[3], inv[3], tn[3];
        int idx[3], step[3];
        for (int a = 0; a < 3; ++a) {
          dg[a] = ray.p_g[a] - o_g[a];
          inv[a] = 1.0 / dg[a];
          idx[a] = static_cast<int>(std::clamp(std::floor(o_g[a] + ray.t_enter * dg[a]), 0.0, n[a] - 1.0));
          if (dg[a] > 0.0) {
            step[a] = 1;
            tn[a] = (static_cast<double>(idx[a] + 1) - o_g[a]) * inv[a];
          } else if (dg[a] < 0.0) {
            step[a] = -1;
            tn[a] = (static_cast<double>(idx[a]) - o_g[a]) * inv[a];
          } else {
            step[a] = 0;
            tn[a] = std::numeric_limits<double>::infinity();
          }
        }
        const double t_exit = ray.t_exit;
        const int sz = step[2];
        for (;;) {
          const double t_column = std::min(tn[0], tn[1]);
          const double limit = std::min(t_column, t_exit);
          // z steps inside this column: every plane k with crossing t(k) < limit. Crossings grow
          // monotonically with k, so estimate the count from the z at `limit`, then settle it
          // with the exact comparisons the 3D walk would make.
          int m = 0;
          if (tn[2] < limit) {
            const int max_steps = sz > 0 ? n[2] - 1 - idx[2] : idx[2];
            const double plane0 = sz > 0 ? idx[2] + 1 : idx[2];
            auto t_plane = [&](int k) { return ((plane0 + k * sz) - o_g[2]) * inv[2]; };
            const double z_limit = o_g[2] + limit * dg[2];
            const double estimate = std::ceil(sz > 0 ? z_limit - plane0 : plane0 - z_limit);
            m = static_cast<int>(std::clamp(estimate, 1.0, static_cast<double>(std::max(max_steps, 1))));
            m = std::min(m, max_steps);
            while (m > 1 && !(t_plane(m - 1) < limit)) --m;
            while (m < max_steps && t_plane(m) < limit) ++m;
            tn[2] = t_plane(m);
          }
          const int iz_last = idx[2] + m * sz;
          const bool ends_here = !(t_column < t_exit);
          if (idx[1] >= ya && idx[1] < yb) {
            const size_t c = grid.ColumnIndex(idx[0], idx[1]);
            Vote* column = mutable_grid->mutable_column(c);
            const int lo = std::min(idx[2], iz_last), hi = std::max(idx[2], iz_last);
            if (ends_here && ray.ends_inside) {
              // The last voxel gets the hit, the rest of the run misses.
              if (sz >= 0) {
                ApplyMisses(column + lo, hi - lo);
              } else {
                ApplyMisses(column + lo + 1, hi - lo);
              }
              ApplyHit(column + iz_last);
              misses += hi - lo;
              ++hits;
              hit_lo[c] = std::min<uint16_t>(hit_lo[c], static_cast<uint16_t>(iz_last));
              hit_hi[c] = std::max<uint16_t>(hit_hi[c], static_cast<uint16_t>(iz_last));
            } else {
              ApplyMisses(column + lo, hi - lo + 1);
              misses += hi - lo + 1;
            }
          }
          if (ends_here) break;
          idx[2] = iz_last;
          const int a = tn[0] <= tn[1] ? 0 : 1;
          idx[a] += step[a];
          if (idx[a] < 0 || idx[a] >= n[a]) break;  // cannot happen before t_exit; a guard
          if (a == 1 && (step[1] > 0 ? idx[1] >= yb : idx[1] < ya)) break;  // left this slab
          tn[a] = (static_cast<double>(step[a] > 0 ? idx[a] + 1 : idx[a]) - o_g[a]) * inv[a];
        }
      }
    }
    thread_hits[thread] = hits;
    thread_misses[thread] = misses;
  };
  ws.pool.Run(walk);

  if (stats != nullptr) {
    InsertStats frame;
    frame.frames = 1;
    for (int t = 0; t < threads; ++t) {
      frame.Add(ws.chunk_stats[t]);
      frame.hits += thread_hits[t];
      frame.misses += thread_misses[t];
    }
    stats->Add(frame);
  }
}

}  // namespace romunect::fusion
