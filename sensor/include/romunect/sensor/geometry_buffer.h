// The contract between a geometry back end (the Embree renderer, an analytic scene in tests)
// and the sensor model's image synthesis: what each camera ray hit, in frame C. The back end
// only intersects rays; everything optical (projector pattern, defocus, BRDF, noise) happens
// in the sensor model, so it is the same for every back end.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace romunect {

// How a surface reflects the projector's (near-)IR light.
struct IrMaterial {
  float albedo = 0.5f;      // diffuse (Lambertian) reflectance in [0, 1]
  float specular = 0.0f;    // weight of the specular lobe in [0, 1]; shiny parts saturate
  float shininess = 50.0f;  // Phong exponent of the specular lobe (> 0)
};

// One sample per pixel of the camera image: all Mats are height x width of the camera.
struct GeometryLayer {
  cv::Mat p_C;        // CV_32FC3: hit point in C (m); NaN in all three where the ray missed
  cv::Mat normal_C;   // CV_32FC3: unit surface normal in C, facing the camera
  cv::Mat material;   // CV_32S: index into GeometryBuffer::materials, -1 where missed
  cv::Mat object_id;  // CV_32S: scene object id, -1 where missed
  cv::Mat lit;        // CV_8U: 1 where the projector centre sees the hit point, 0 in shadow
  // Where this sample's ray left from: sub-pixel offset from the pixel centre (px) and the
  // point on the camera's lens aperture (m, in C's x-y plane; 0 for a pinhole ray).
  Eigen::Vector2f pixel_offset_px = Eigen::Vector2f::Zero();
  Eigen::Vector2f lens_offset_m = Eigen::Vector2f::Zero();
};

// All samples of one frame. layers[0] is always the pinhole ray through each pixel centre
// (no pixel or lens offset): ground-truth depth and ids come from it. Further layers are the
// extra samples of the quality mode; image synthesis averages the radiance over all layers.
struct GeometryBuffer {
  std::vector<GeometryLayer> layers;
  std::vector<IrMaterial> materials;
};

}  // namespace romunect
