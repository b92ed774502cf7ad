// An exact, analytic geometry back end for the sensor model's tests: planes, axis-aligned boxes
// and spheres in the camera frame C, intersected in closed form, with exact shadows (a shadow
// ray from each hit to the projector centre). It fills the same GeometryBuffer as the Embree
// renderer, so the fidelity tests need no Embree.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/geometry_buffer.h"

namespace romunect::testing {

struct AnalyticScene {
  struct Plane {
    Eigen::Vector3d point_C, normal_C;
    int material = 0, id = 0;
  };
  struct Box {  // axis-aligned in C
    Eigen::Vector3d min_C, max_C;
    int material = 0, id = 0;
  };
  struct Sphere {
    Eigen::Vector3d centre_C;
    double radius_m = 0.01;
    int material = 0, id = 0;
  };
  std::vector<Plane> planes;
  std::vector<Box> boxes;
  std::vector<Sphere> spheres;
  std::vector<IrMaterial> materials{IrMaterial{}};

  // A plane z = depth_m tilted about the camera's y axis by tilt_rad (0 = fronto-parallel).
  static AnalyticScene TiltedPlane(double depth_m, double tilt_rad, const IrMaterial& material = {});
};

// Ray parameter of the first hit along origin + t dir (t > t_min), or infinity.
double FirstHit(const AnalyticScene& scene, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double t_min,
                Eigen::Vector3d* normal, int* material, int* id);

// One pinhole layer through the pixel centres of `camera`, shadows towards projector_centre_C.
GeometryBuffer RenderAnalytic(const AnalyticScene& scene, const CameraModel& camera,
                              const Eigen::Vector3d& projector_centre_C);

// Ground-truth depth (z in C, metres, CV_32F, 0 where missed) of a buffer's layer 0.
cv::Mat TruthDepth(const GeometryBuffer& buffer);

}  // namespace romunect::testing
