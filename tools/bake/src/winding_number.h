// Generalized winding number of a triangle soup (Jacobson et al. 2013), evaluated fast with a bounding volume
// hierarchy and the far-field dipole approximation of Barill et al. 2018. Defines inside (>= 1/2) for open,
// non-manifold or self-intersecting surfaces, where ray or flood-fill rules leak. The bake uses it beyond the
// distance band, where the value varies slowly; band voxels are decided exactly by BoundaryWinding.
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
  /// ~1 inside an outward-oriented closed surface, ~0 outside; fractional near holes. Fast: clusters farther
  /// than 2 radii count as dipoles, which can be off by a few hundredths where many distant parts add up.
  double operator()(const Vec3& point) const { return evaluate(point, 2.0); }
  /// The winding number with the dipole approximation only for clusters farther than `beta` radii (its error
  /// falls roughly as 1/beta^2); beta = infinity sums every triangle's exact solid angle.
  double evaluate(const Vec3& point, double beta) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace voxfmt::bake
