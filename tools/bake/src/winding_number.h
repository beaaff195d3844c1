// Generalized winding number of a triangle soup (Jacobson et al. 2013), evaluated fast with a bounding volume
// hierarchy and the far-field dipole approximation of Barill et al. 2018. Defines inside (>= 1/2) for open,
// non-manifold or self-intersecting surfaces, where ray or flood-fill rules leak.
#pragma once

#include <memory>

#include "stages.h"

namespace voxfmt::bake {

class WindingNumber {
 public:
  explicit WindingNumber(const TriangleMesh& mesh);
  ~WindingNumber();
  WindingNumber(const WindingNumber&) = delete;
  WindingNumber& operator=(const WindingNumber&) = delete;
  /// ~1 inside an outward-oriented closed surface, ~0 outside; fractional near holes.
  double operator()(const Vec3& point) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace voxfmt::bake
