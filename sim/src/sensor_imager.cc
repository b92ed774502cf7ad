#include "romunect/sim/sensor_imager.h"

#include <sstream>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/keep_or_zero.h"

namespace romunect::sim {

std::string SensorImagerOptions::Problem() const {
  std::ostringstream s;
  if (threads < 1 || threads > 256) {
    s << "threads = " << threads << ": expected 1..256";
  } else if (!(sweep_near_m == 0.0 && sweep_far_m == 0.0) && !(sweep_near_m > 0.0 && sweep_far_m > sweep_near_m)) {
    s << "sweep_near_m = " << sweep_near_m << ", sweep_far_m = " << sweep_far_m
      << ": expected 0 < near < far (or both 0: the rig's range)";
  } else if (!(sweep_fraction > 0.0 && sweep_fraction <= 1.0)) {
    s << "sweep_fraction = " << sweep_fraction << ": expected (0, 1]";
  } else if (!(keep_fraction > 0.0 && keep_fraction <= 1.0)) {
    s << "keep_fraction = " << keep_fraction << ": expected (0, 1]";
  } else if (sweep_planes < 2) {
    s << "sweep_planes = " << sweep_planes << ": expected at least 2";
  }
  return s.str();
}

namespace {

DepthEngineOptions EngineOptions(const Rig& rig, int threads) {
  DepthEngineOptions options = rig.depth_engine;
  options.threads = threads;
  return options;
}

// The sweep of GroundTruthDepthCorrection through a given synthesizer (its noise off for the
// sweep) and engine: the imager lends its own, whose pattern levels and reference image it
// needs anyway, and neither keeps state from frame to frame.
DepthCorrection FitOnPlanes(const Rig& rig, const SensorImagerOptions& options, IrSynthesizer* synthesizer,
                            DepthEngine* engine) {
  const bool noise = synthesizer->noise();
  synthesizer->set_noise(false);
  std::vector<DepthEngineOutput> outputs(options.sweep_planes);
  std::vector<cv::Mat> truth;
  cv::Mat ir;
  const DepthRange sweep = SweepRange(rig, options);
  for (int i = 0; i < options.sweep_planes; ++i) {
    const double z_m = sweep.near_m + (sweep.far_m - sweep.near_m) * i / (options.sweep_planes - 1);
    synthesizer->Synthesize(rig, FrontoParallelPlane(rig.camera, z_m, IrMaterial{}), 0, &ir, nullptr);
    engine->Compute(ir, &outputs[i]);
    truth.emplace_back(rig.camera.height, rig.camera.width, CV_32F, cv::Scalar(static_cast<float>(z_m)));
  }
  synthesizer->set_noise(noise);
  return FitDepthCorrection(DepthCorrectionModel::kInverseAffineInRaw, outputs, truth);
}

}  // namespace

DepthRange SweepRange(const Rig& rig, const SensorImagerOptions& options) {
  if (options.sweep_far_m > 0) return {options.sweep_near_m, options.sweep_far_m};
  return MeasurableDepthRange(rig, options.sweep_fraction);
}

DepthCorrection GroundTruthDepthCorrection(const Rig& rig, const SensorImagerOptions& options) {
  IrSynthesisOptions synthesis;
  synthesis.threads = options.threads;
  IrSynthesizer synthesizer(synthesis);
  DepthEngine engine(EngineOptions(rig, options.threads));
  return FitOnPlanes(rig, options, &synthesizer, &engine);
}

SensorImager::SensorImager(const Rig& rig, const SensorImagerOptions& options)
    : options_(options),
      synthesizer_([&] {
        IrSynthesisOptions synthesis;
        synthesis.threads = options.threads;
        return synthesis;
      }()),
      engine_(EngineOptions(rig, options.threads)),
      keep_(options.keep_fraction < 1.0 ? MeasurableDepthRange(rig, options.keep_fraction) : DepthRange{0.0, 1e30}) {
  if (const std::string problem = options.Problem(); !problem.empty()) {
    throw InputError("sensor imager", "options", problem);
  }
  synthesizer_.Prepare(rig);
  if (options.correction) {
    const DepthCorrection& c = *options.correction;
    if (c.a.rows != rig.camera.height || c.a.cols != rig.camera.width || c.b.size() != c.a.size()) {
      throw InputError(options.correction_source.empty() ? "sensor imager" : options.correction_source,
                       "depth correction",
                       "per-pixel maps of " + std::to_string(c.a.cols) + " x " + std::to_string(c.a.rows) +
                           " do not match the rig's camera (" + std::to_string(rig.camera.width) + " x " +
                           std::to_string(rig.camera.height) + ")");
    }
    correction_ = c;
    correction_source_ = options.correction_source;
  } else {
    correction_ = FitOnPlanes(rig, options, &synthesizer_, &engine_);
    std::ostringstream s;
    const DepthRange sweep = SweepRange(rig, options);
    s << "ground truth of the rig (" << DepthCorrectionModelName(correction_.model) << ", fitted on "
      << options.sweep_planes << " simulated planes at " << 1e3 * sweep.near_m << "-" << 1e3 * sweep.far_m
      << " mm; the calibration chain is not in the loop)";
    correction_source_ = s.str();
  }
}

void SensorImager::SynthesizeIr(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) {
  synthesizer_.Synthesize(rig, geometry, seed, &frame->ir, nullptr);
}

void SensorImager::ComputeDepth(const Rig& /*rig*/, Frame* frame) {
  engine_.Compute(frame->ir, &output_);
  output_.raw.copyTo(frame->raw);
  frame->depth_m = ApplyDepthCorrection(correction_, output_);
  // Outside the matchable range a depth is a clamped match, not a measurement.
  const float near_m = static_cast<float>(keep_.near_m), far_m = static_cast<float>(keep_.far_m);
  for (int v = 0; v < frame->depth_m.rows; ++v) {
    float* row = frame->depth_m.ptr<float>(v);
    for (int u = 0; u < frame->depth_m.cols; ++u) {
      const float d = row[u];
      row[u] = KeepOrZero(!((d < near_m) | (d > far_m)), d);  // a NaN stays
    }
  }
}

}  // namespace romunect::sim
