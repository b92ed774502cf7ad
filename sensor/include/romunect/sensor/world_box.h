// An axis-aligned box in the world frame W (metres): a frame directory's region, fusion's box.
#pragma once

#include <string>

#include <Eigen/Core>

namespace romunect {

struct WorldBox {
  Eigen::Vector3d min_W = Eigen::Vector3d::Zero();
  Eigen::Vector3d max_W = Eigen::Vector3d::Zero();

  // Why the box is unusable ("" when it is finite with min < max on every axis), naming the
  // axis and its range: "x range [0, 0] is empty or inverted: max must be greater than min".
  std::string Problem() const;
};

}  // namespace romunect
