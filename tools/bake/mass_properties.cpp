// Stage 5: volume, centre of mass and inertia of a closed surface (divergence theorem over tetrahedra).
#include <cmath>

#include "bake.h"

namespace voxfmt::bake {

MassProperties compute_mass_properties(const TriangleMesh& mesh) {
  // Work relative to a point near the mesh to keep the sums well-conditioned far from the origin.
  Vec3 ref{};
  for (const Vec3& v : mesh.vertices)
    for (int a = 0; a < 3; ++a) ref[a] += v[a] / double(mesh.vertices.size());
  double volume = 0;
  Vec3 first{};               // integral of x dV
  double second[3][3] = {};   // integral of x x^T dV
  for (const auto& t : mesh.triangles) {
    Vec3 p[3];
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) p[i][a] = mesh.vertices[t[i]][a] - ref[a];
    // Signed tetrahedron (ref, p0, p1, p2): det = 6 V.
    const double det = p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0]) +
                       p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
    volume += det / 6;
    Vec3 s{};
    for (int i = 0; i < 3; ++i)
      for (int a = 0; a < 3; ++a) s[a] += p[i][a];
    for (int a = 0; a < 3; ++a) first[a] += det / 24 * s[a];
    // Integral of x x^T over a tetrahedron with one vertex at the origin: det/120 (sum v v^T + s s^T).
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) {
        double vv = 0;
        for (int i = 0; i < 3; ++i) vv += p[i][a] * p[i][b];
        second[a][b] += det / 120 * (vv + s[a] * s[b]);
      }
  }
  MassProperties m;
  m.volume = volume;
  if (!(std::abs(volume) > 0)) return m;
  Vec3 c{};
  for (int a = 0; a < 3; ++a) c[a] = first[a] / volume;
  double central[3][3];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) central[a][b] = second[a][b] - volume * c[a] * c[b];
  const double trace = central[0][0] + central[1][1] + central[2][2];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) m.inertia[a * 3 + b] = (a == b ? trace : 0.0) - central[a][b];
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b) m.inertia[a * 3 + b] = m.inertia[b * 3 + a];  // exactly symmetric
  for (int a = 0; a < 3; ++a) m.center_of_mass[a] = c[a] + ref[a];
  return m;
}

}  // namespace voxfmt::bake
