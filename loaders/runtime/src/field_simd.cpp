#include "traversal/field_simd.h"

#include <atomic>
#include <cstdlib>
#include <cstring>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define VOXFMT_HAVE_AVX2_KERNEL 1
#include <immintrin.h>
#endif

namespace voxfmt::runtime::core {

namespace {

void lower_bounds_scalar(const Field& f, const Vec3* u, size_t n, float* out) { lower_bounds(f, u, n, out); }

#if defined(VOXFMT_HAVE_AVX2_KERNEL)
// AVX2 without FMA: every product and sum rounds as the scalar code's does.
#define VOXFMT_AVX2 __attribute__((target("avx2")))

// As max_f(a, b) decides (a < b ? b : a), ties and signed zeros alike.
VOXFMT_AVX2 inline __m256 max_f8(__m256 a, __m256 b) { return _mm256_max_ps(b, a); }

VOXFMT_AVX2 inline __m256 length8(__m256 x, __m256 y, __m256 z) {
  return _mm256_sqrt_ps(_mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(x, x), _mm256_mul_ps(y, y)), _mm256_mul_ps(z, z)));
}

VOXFMT_AVX2 inline __m256 lerp8(__m256 a, __m256 b, __m256 t) {
  return _mm256_add_ps(a, _mm256_mul_ps(t, _mm256_sub_ps(b, a)));
}

// A 16-bit array read at 8 indices (32-bit gathers at 2-byte steps; kGatherPadding makes the last one safe).
VOXFMT_AVX2 inline __m256i gather16(const void* base, __m256i index, __m256i mask) {
  return _mm256_mask_i32gather_epi32(_mm256_setzero_si256(), static_cast<const int*>(base), index, mask, 2);
}

// The lattice cells of 8 voxels (the cell of each voxel's brick): its 8 points' values (in lattice steps), the
// voxel's interpolation weights, and the cell's voxel coordinates. Lanes outside `mask` are not read.
struct Cell8 {
  __m256 p[8];
  __m256 t[3];
  __m256 x0[3], x1[3];
};

VOXFMT_AVX2 void lattice_cells8(const Field& f, const __m256i v[3], __m256i mask, Cell8& cell) {
  __m256i lower[3];
  for (int a = 0; a < 3; ++a) {
    lower[a] = _mm256_srli_epi32(v[a], kEdgeBits);
    const __m256i x0 = _mm256_slli_epi32(lower[a], kEdgeBits);
    const __m256i x1 = _mm256_min_epi32(_mm256_slli_epi32(_mm256_add_epi32(lower[a], _mm256_set1_epi32(1)), kEdgeBits),
                                        _mm256_set1_epi32(f.dims[a] - 1));
    const __m256 ratio =
        _mm256_div_ps(_mm256_cvtepi32_ps(_mm256_sub_epi32(v[a], x0)), _mm256_cvtepi32_ps(_mm256_sub_epi32(x1, x0)));
    cell.t[a] = _mm256_and_ps(ratio, _mm256_castsi256_ps(_mm256_cmpgt_epi32(x1, x0)));
    cell.x0[a] = _mm256_cvtepi32_ps(x0);
    cell.x1[a] = _mm256_cvtepi32_ps(x1);
  }
  const int row = f.lattice_dims[0], plane = row * f.lattice_dims[1];
  const __m256i q = _mm256_add_epi32(_mm256_add_epi32(_mm256_mullo_epi32(lower[2], _mm256_set1_epi32(plane)),
                                                      _mm256_mullo_epi32(lower[1], _mm256_set1_epi32(row))),
                                     lower[0]);
  const int offset[8] = {0, 1, row, row + 1, plane, plane + 1, plane + row, plane + row + 1};
  for (int c = 0; c < 8; ++c) {
    const __m256i word = gather16(f.lattice, _mm256_add_epi32(q, _mm256_set1_epi32(offset[c])), mask);
    cell.p[c] = _mm256_cvtepi32_ps(_mm256_and_si256(word, _mm256_set1_epi32(0xffff)));
  }
}

// coarse_value for 8 voxels of coarse bricks (entry -1 or -2): the lattice interpolated in each voxel's cell.
VOXFMT_AVX2 __m256 coarse_values8(const Field& f, const Cell8& cell, __m256i entry) {
  const __m256* p = cell.p;
  const __m256 x00 = lerp8(p[0], p[1], cell.t[0]), x10 = lerp8(p[2], p[3], cell.t[0]);
  const __m256 x01 = lerp8(p[4], p[5], cell.t[0]), x11 = lerp8(p[6], p[7], cell.t[0]);
  const __m256 y0 = lerp8(x00, x10, cell.t[1]), y1 = lerp8(x01, x11, cell.t[1]);
  const __m256 magnitude =
      max_f8(_mm256_mul_ps(lerp8(y0, y1, cell.t[2]), _mm256_set1_ps(f.lattice_step)), _mm256_set1_ps(f.band_edge));
  const __m256 inside = _mm256_castsi256_ps(_mm256_cmpeq_epi32(entry, _mm256_set1_epi32(kCoarseInside)));
  return _mm256_blendv_ps(magnitude, _mm256_xor_ps(magnitude, _mm256_set1_ps(-0.0f)), inside);
}

// lattice_corners_bound at the points `x`: each lattice point's bound (lattice_point_bound) less the distance to it.
VOXFMT_AVX2 __m256 corners_bound8(const Field& f, const Cell8& cell, const __m256 x[3]) {
  const __m256 step = _mm256_set1_ps(f.lattice_step);
  __m256 best = _mm256_set1_ps(-__builtin_huge_valf());
  for (int c = 0; c < 8; ++c) {
    const __m256 l = _mm256_mul_ps(cell.p[c], step);
    const __m256 own = _mm256_sub_ps(
        _mm256_mul_ps(
            _mm256_sub_ps(_mm256_sub_ps(l, _mm256_set1_ps(0.5f * f.lattice_step)), _mm256_set1_ps(f.estimate_offset)),
            _mm256_set1_ps(f.estimate_shrink)),
        _mm256_add_ps(_mm256_set1_ps(1e-3f), _mm256_mul_ps(_mm256_set1_ps(1e-6f), l)));
    const __m256 reach = length8(_mm256_sub_ps(x[0], c & 1 ? cell.x1[0] : cell.x0[0]),
                                 _mm256_sub_ps(x[1], c & 2 ? cell.x1[1] : cell.x0[1]),
                                 _mm256_sub_ps(x[2], c & 4 ? cell.x1[2] : cell.x0[2]));
    best = max_f8(best, _mm256_sub_ps(own, reach));
  }
  return best;
}

// Eight points of a batch between the passes of lower_bounds_avx2.
struct Lanes {
  __m256 x[3];
  __m256 covered;
  __m256i v[3];
  __m256i brick;
  __m256i entry;
};

// Pass 1: the points' coordinates, whether the grid covers them, their nearest voxels and bricks; the brick table
// entries are prefetched.
VOXFMT_AVX2 inline void locate8(const Field& f, const Vec3* u, Lanes& l) {
  const __m256i lanes = _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21);
  const float* first = &u[0].x;
  for (int a = 0; a < 3; ++a) l.x[a] = _mm256_i32gather_ps(first + a, lanes, 4);
  const float cover_max[3] = {f.cover_max.x, f.cover_max.y, f.cover_max.z};
  l.covered = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
  for (int a = 0; a < 3; ++a)
    l.covered =
        _mm256_and_ps(l.covered, _mm256_and_ps(_mm256_cmp_ps(l.x[a], _mm256_set1_ps(-0.5f), _CMP_GT_OQ),
                                               _mm256_cmp_ps(l.x[a], _mm256_set1_ps(cover_max[a]), _CMP_LT_OQ)));
  for (int a = 0; a < 3; ++a) l.v[a] = _mm256_cvttps_epi32(_mm256_add_ps(l.x[a], _mm256_set1_ps(0.5f)));
  l.brick = _mm256_add_epi32(
      _mm256_mullo_epi32(
          _mm256_add_epi32(_mm256_mullo_epi32(_mm256_srli_epi32(l.v[2], kEdgeBits), _mm256_set1_epi32(f.brick_dims[1])),
                           _mm256_srli_epi32(l.v[1], kEdgeBits)),
          _mm256_set1_epi32(f.brick_dims[0])),
      _mm256_srli_epi32(l.v[0], kEdgeBits));
  alignas(32) int32_t brick[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(brick), l.brick);
  const int covered = _mm256_movemask_ps(l.covered);
  for (int lane = 0; lane < 8; ++lane)
    if (covered & (1 << lane)) __builtin_prefetch(&f.bricks[brick[lane]]);
}

VOXFMT_AVX2 inline __m256i code_index8(const Lanes& l) {
  const __m256i edge = _mm256_set1_epi32(kEdge - 1);
  const __m256i local = _mm256_or_si256(
      _mm256_slli_epi32(
          _mm256_or_si256(_mm256_slli_epi32(_mm256_and_si256(l.v[2], edge), kEdgeBits), _mm256_and_si256(l.v[1], edge)),
          kEdgeBits),
      _mm256_and_si256(l.v[0], edge));
  return _mm256_add_epi32(_mm256_slli_epi32(l.entry, 9), local);
}

// Pass 2: the brick table entries; the value bricks' codes are prefetched.
VOXFMT_AVX2 inline void entries8(const Field& f, Lanes& l) {
  const __m256i covered = _mm256_castps_si256(l.covered);
  l.entry = _mm256_mask_i32gather_epi32(_mm256_setzero_si256(), f.bricks, l.brick, covered, 4);
  const int in_value = _mm256_movemask_ps(
      _mm256_castsi256_ps(_mm256_and_si256(covered, _mm256_cmpgt_epi32(l.entry, _mm256_set1_epi32(-1)))));
  if (in_value == 0) return;
  alignas(32) int32_t code[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(code), code_index8(l));
  for (int lane = 0; lane < 8; ++lane)
    if (in_value & (1 << lane)) __builtin_prefetch(&f.codes[code[lane]]);
}

// The length of the 8 vectors `v`, as length8, where that is finite. Past ~1.8e19 voxels the squares overflow to
// inf, which would cull everything: those lanes as hypot_f (in double), as the scalar kernel takes them.
VOXFMT_AVX2 inline __m256 finite_length8(const __m256 v[3]) {
  const __m256 length = length8(v[0], v[1], v[2]);
  if (_mm256_movemask_ps(_mm256_cmp_ps(length, _mm256_set1_ps(3.40282347e+38f), _CMP_GT_OQ)) == 0) return length;
  alignas(32) float o[3][8], d[8];
  for (int a = 0; a < 3; ++a) _mm256_store_ps(o[a], v[a]);
  _mm256_store_ps(d, length);
  for (int lane = 0; lane < 8; ++lane)
    if (d[lane] > 3.40282347e+38f) d[lane] = hypot_f(make_vec3(o[0][lane], o[1][lane], o[2][lane]), 0.0f);
  return _mm256_load_ps(d);
}

// Pass 3: the bounds (lower_bound: the nearest voxel's bound less the offset to it; outside the grid the distance
// to the object's box).
VOXFMT_AVX2 inline void bounds8(const Field& f, const Lanes& l, float* out) {
  const float box_min[3] = {f.object_min.x, f.object_min.y, f.object_min.z};
  const float box_max[3] = {f.object_max.x, f.object_max.y, f.object_max.z};
  __m256 outside[3];
  for (int a = 0; a < 3; ++a)
    outside[a] = max_f8(
        max_f8(_mm256_sub_ps(_mm256_set1_ps(box_min[a]), l.x[a]), _mm256_sub_ps(l.x[a], _mm256_set1_ps(box_max[a]))),
        _mm256_setzero_ps());
  const __m256 box_distance = finite_length8(outside);
  if (_mm256_movemask_ps(l.covered) == 0) {
    _mm256_storeu_ps(out, box_distance);
    return;
  }
  const __m256i covered_i = _mm256_castps_si256(l.covered);
  const __m256i in_value = _mm256_and_si256(covered_i, _mm256_cmpgt_epi32(l.entry, _mm256_set1_epi32(-1)));
  const __m256i in_coarse = _mm256_andnot_si256(in_value, covered_i);
  const __m256 band_edge = _mm256_set1_ps(f.band_edge);
  const __m256 offset =
      length8(_mm256_sub_ps(l.x[0], _mm256_cvtepi32_ps(l.v[0])), _mm256_sub_ps(l.x[1], _mm256_cvtepi32_ps(l.v[1])),
              _mm256_sub_ps(l.x[2], _mm256_cvtepi32_ps(l.v[2])));
  const __m256 near = _mm256_cmp_ps(offset, band_edge, _CMP_LT_OQ);
  __m256 value = _mm256_setzero_ps();
  __m256i stored = _mm256_setzero_si256();
  if (_mm256_movemask_epi8(in_value) != 0) {
    const __m256i code = _mm256_srai_epi32(_mm256_slli_epi32(gather16(f.codes, code_index8(l), in_value), 16), 16);
    stored = _mm256_and_si256(in_value,
                              _mm256_cmpeq_epi32(_mm256_and_si256(code, _mm256_set1_epi32(1)), _mm256_set1_epi32(1)));
    const __m256 step = _mm256_blendv_ps(_mm256_set1_ps(f.decode_step[0]), _mm256_set1_ps(f.decode_step[1]),
                                         _mm256_castsi256_ps(stored));
    value = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srai_epi32(code, 1)), step);
  }
  // Where the lattice cell is read: coarse voxels, and positive estimates near enough for their lattice points
  // to bound u (nearest_voxel_bound). A coarse outside voxel's value is positive.
  const __m256 positive_estimate_lanes = _mm256_and_ps(_mm256_castsi256_ps(_mm256_andnot_si256(stored, in_value)),
                                                       _mm256_cmp_ps(value, _mm256_setzero_ps(), _CMP_GT_OQ));
  const __m256 coarse_outside =
      _mm256_castsi256_ps(_mm256_and_si256(in_coarse, _mm256_cmpeq_epi32(l.entry, _mm256_set1_epi32(kCoarseOutside))));
  const __m256 use_corners = _mm256_and_ps(_mm256_or_ps(positive_estimate_lanes, coarse_outside), near);
  const __m256i cell_lanes = _mm256_or_si256(in_coarse, _mm256_castps_si256(use_corners));
  Cell8 cell;
  if (_mm256_movemask_epi8(cell_lanes) != 0) lattice_cells8(f, l.v, cell_lanes, cell);
  if (_mm256_movemask_epi8(in_coarse) != 0)
    value = _mm256_blendv_ps(coarse_values8(f, cell, l.entry), value, _mm256_castsi256_ps(in_value));
  // value_lower_bound.
  const __m256 estimate_slack = _mm256_blendv_ps(_mm256_set1_ps(f.estimate_slack),
                                                 _mm256_set1_ps(f.value_estimate_slack), _mm256_castsi256_ps(in_value));
  const __m256 positive_estimate =
      max_f8(band_edge, _mm256_sub_ps(_mm256_mul_ps(_mm256_sub_ps(value, _mm256_set1_ps(f.estimate_offset)),
                                                    _mm256_set1_ps(f.estimate_shrink)),
                                      estimate_slack));
  const __m256 estimate = _mm256_blendv_ps(_mm256_sub_ps(value, estimate_slack), positive_estimate,
                                           _mm256_cmp_ps(value, _mm256_setzero_ps(), _CMP_GT_OQ));
  const __m256 bound =
      _mm256_blendv_ps(estimate, _mm256_sub_ps(value, _mm256_set1_ps(f.stored_slack)), _mm256_castsi256_ps(stored));
  __m256 inside = _mm256_sub_ps(bound, offset);
  if (_mm256_movemask_ps(use_corners) != 0)
    inside = _mm256_blendv_ps(inside, max_f8(inside, corners_bound8(f, cell, l.x)), use_corners);
  _mm256_storeu_ps(out, _mm256_blendv_ps(box_distance, inside, l.covered));
}

// As the scalar batch: up to 64 points at a time, each pass over all of them before the next, so that the cache
// misses of a batch (the table entries, then the codes) overlap. A last group of fewer than 8 points is padded
// with copies of its first.
VOXFMT_AVX2 void lower_bounds_avx2(const Field& f, const Vec3* u, size_t n, float* out) {
  constexpr size_t kGroups = 8;
  Lanes lanes[kGroups];
  Vec3 padded[8];
  float tail[8];
  for (size_t begin = 0; begin < n; begin += 8 * kGroups) {
    const size_t count = n - begin < 8 * kGroups ? n - begin : 8 * kGroups;
    const size_t groups = (count + 7) / 8;
    for (size_t g = 0; g < groups; ++g) {
      const Vec3* points = u + begin + 8 * g;
      const size_t in_group = count - 8 * g < 8 ? count - 8 * g : 8;
      if (in_group < 8) {
        for (size_t p = 0; p < 8; ++p) padded[p] = points[p < in_group ? p : 0];
        points = padded;
      }
      locate8(f, points, lanes[g]);
    }
    for (size_t g = 0; g < groups; ++g) entries8(f, lanes[g]);
    for (size_t g = 0; g < groups; ++g) {
      const size_t in_group = count - 8 * g < 8 ? count - 8 * g : 8;
      if (in_group == 8) {
        bounds8(f, lanes[g], out + begin + 8 * g);
      } else {
        bounds8(f, lanes[g], tail);
        for (size_t p = 0; p < in_group; ++p) out[begin + 8 * g + p] = tail[p];
      }
    }
  }
}
#endif

bool supported(SimdKernel kernel) {
#if defined(VOXFMT_HAVE_AVX2_KERNEL)
  __builtin_cpu_init();
  return kernel == SimdKernel::Scalar || __builtin_cpu_supports("avx2");
#else
  return kernel == SimdKernel::Scalar;
#endif
}

SimdKernel detect() {
  const char* setting = std::getenv("VOXFMT_SIMD");
  if (setting && std::strcmp(setting, "off") == 0) return SimdKernel::Scalar;
  return supported(SimdKernel::Avx2) ? SimdKernel::Avx2 : SimdKernel::Scalar;
}

std::atomic<int>& chosen_kernel() {
  static std::atomic<int> kernel{int(detect())};
  return kernel;
}

}  // namespace

SimdKernel simd_kernel() { return SimdKernel(chosen_kernel().load(std::memory_order_relaxed)); }

bool use_simd_kernel(SimdKernel kernel) {
  if (!supported(kernel)) return false;
  chosen_kernel().store(int(kernel), std::memory_order_relaxed);
  return true;
}

const char* simd_kernel_name(SimdKernel kernel) { return kernel == SimdKernel::Avx2 ? "avx2" : "scalar"; }

bool lower_bounds_with(SimdKernel kernel, const Field& f, const Vec3* u, size_t n, float* out) {
  if (kernel == SimdKernel::Scalar) {
    lower_bounds_scalar(f, u, n, out);
    return true;
  }
#if defined(VOXFMT_HAVE_AVX2_KERNEL)
  if (!f.gather_safe || !supported(kernel)) return false;
  lower_bounds_avx2(f, u, n, out);
  return true;
#else
  return false;
#endif
}

void lower_bounds_dispatched(const Field& f, const Vec3* u, size_t n, float* out) {
#if defined(VOXFMT_HAVE_AVX2_KERNEL)
  if (f.gather_safe && simd_kernel() == SimdKernel::Avx2) return lower_bounds_avx2(f, u, n, out);
#endif
  lower_bounds_scalar(f, u, n, out);
}

}  // namespace voxfmt::runtime::core
