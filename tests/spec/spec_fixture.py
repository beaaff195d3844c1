"""The analytic "sphere fixture", written from spec/voxfmt-format.md alone.

Both sides agree on this asset: the C++ example program `write_sphere_asset` writes it (format 2.0), and
`write_fixture_h5py` below writes it with h5py alone (no libvoxfmt), so that each side can read what the
other one wrote.

Fixture (all lengths in metres):
  * sphere centre c = (0.1, -0.2, 0.3), radius r = 0.25, voxel size h = 0.05, margin 2 voxels,
    distance_band = 2.0 voxels;
  * grid origin = c - (r + 2h) on each axis, dims W = H = D = 15, voxel centre origin + h*(i, j, k);
  * d(p) = |p - c| - r, the exact signed distance (negative inside);
  * N = 200 points on a Fibonacci sphere with inward float32 normals;
  * a complete 4-ary tree in breadth-first order, sphere_centers = points,
    sphere_radii = max distance from the node's point to the points of its subtree;
  * bounds c -/+ r, unit-density mass properties of the ball, provenance of `write_sphere_asset`.

Voxelmap, format 2.0 (§3.2, §3.3), as `encode_voxelmap` bakes it:
  * a distance is stored where |d| <= distance_band*h (+1e-12), code 2*round(d/q)+1 with q = distance_quantum
    (default band*h/16383, as `voxfmt build`);
  * lattice point (a, b, c) = voxel (min(8a, W-1), ...) holds |d| there, rounded *up* to float32 (never below
    the exact distance), lattice_error = [1e-5, 0] (float32 rounding is ~1e-6 voxel here);
  * every voxel without a stored distance gets the estimate sign(d) * max(L, (band - 1/2) h), L the lattice
    interpolated trilinearly with §3.3's weights, code 2*round(estimate/e) with e = estimate_quantum (default h/16);
  * a brick is a value brick where it has a stored distance or voxels on both sides (d < 0 inside), else coarse
    (-1 outside, -2 inside); value bricks take the rows of brick_values in table order; codes past the grid are 0.
  The 15^3 fixture has 2x2x2 bricks, all of them value bricks; FINE_GRID (the same sphere at h = 0.01, 57^3
  voxels, 8x8x8 bricks, the last one voxel wide) also has coarse bricks inside and outside.

Legacy voxelmap, format 1.1 (§3.4), written by `write_fixture_h5py(legacy=True)` for the tests that keep 1.x
files readable: distances[k, j, i] = float32(d) where |d| <= distance_band*h (+1e-12), NaN elsewhere;
layers[k, j, i] = floor(-d/h + 1/2) (float64) for every voxel.

Only the Python standard library, numpy and h5py are used.
"""

import collections
import functools
import json
import math

import h5py
import numpy as np

# ---------------------------------------------------------------------------------------------------------
# Fixture parameters
# ---------------------------------------------------------------------------------------------------------

CENTER = (0.1, -0.2, 0.3)
RADIUS = 0.25
VOXEL_SIZE = 0.05
MARGIN = 2
DISTANCE_BAND = 2.0
DIM = 15  # W = H = D
N_POINTS = 200
BRANCHING = 4
BAND_SLACK = 1e-12

BRICK_EDGE = 8
LATTICE_ERROR = (1e-5, 0.0)  # [eps0 (voxels), eps1]: the h5py writer's lattice is exact but for float32 rounding up

GENERATOR = "write_sphere_asset"

# The voxel grid of a sphere fixture: voxel edge, margin (voxels) and distance band (voxels). The grid is the
# sphere's box grown by the margin: origin c - (r + margin*h), W = H = D = round(2 (r + margin*h) / h) + 1.
Grid = collections.namedtuple("Grid", "voxel_size margin band")
FIXTURE_GRID = Grid(VOXEL_SIZE, MARGIN, DISTANCE_BAND)  # what write_sphere_asset writes: 15^3, 2^3 bricks
FINE_GRID = Grid(0.01, 3, 2.5)  # 57^3 voxels, 8^3 bricks (the last one voxel wide), coarse bricks both sides

# dtype codes of the spec tables -> numpy kind+width (byte order added separately)
DTYPE_CODES = {"i16": "i2", "i32": "i4", "u32": "u4", "f32": "f4", "f64": "f8"}
# dtype codes -> the HDF5 predefined little-endian type names used by h5dump
H5DUMP_TYPES = {
    "i16": "H5T_STD_I16LE",
    "i32": "H5T_STD_I32LE",
    "u32": "H5T_STD_U32LE",
    "f32": "H5T_IEEE_F32LE",
    "f64": "H5T_IEEE_F64LE",
}

# ---------------------------------------------------------------------------------------------------------
# The objects defined by spec/voxfmt-format.md (sections 2-6), format 2.0: path, kind, dtype code, shape,
# required. An attribute of group G named a has path "G/a" (the root's attributes are "/a"); names are unique
# within a group in the spec, so the path is unambiguous. Shapes: "scalar" or a tuple whose items are ints or
# the symbols "N", "W", "H", "D", "BW", "BH", "BD", "BW+1", "BH+1", "BD+1", "V", "L+1".
# ---------------------------------------------------------------------------------------------------------

SPEC_OBJECTS = [
    # section 2: root
    ("/format", "attr", "str", "scalar", True),
    ("/format_version", "attr", "u32", (2,), True),
    ("/units", "attr", "str", "scalar", True),
    ("/frame", "attr", "str", "scalar", True),
    ("/up_axis", "attr", "str", "scalar", True),
    ("/bounds_min", "attr", "f64", (3,), True),
    ("/bounds_max", "attr", "f64", (3,), True),
    # section 3: voxelmap (3.2 bricks, 3.3 lattice)
    ("/voxelmap", "group", None, None, True),
    ("/voxelmap/origin", "attr", "f64", (3,), True),
    ("/voxelmap/voxel_size", "attr", "f64", "scalar", True),
    ("/voxelmap/dims", "attr", "u32", (3,), True),
    ("/voxelmap/index_order", "attr", "str", "scalar", True),
    ("/voxelmap/distance_band", "attr", "f64", "scalar", True),
    ("/voxelmap/margin", "attr", "u32", "scalar", False),
    ("/voxelmap/shell_thickness", "attr", "f64", "scalar", False),
    ("/voxelmap/brick_edge", "attr", "u32", "scalar", True),
    ("/voxelmap/distance_quantum", "attr", "f64", "scalar", True),
    ("/voxelmap/estimate_quantum", "attr", "f64", "scalar", True),
    ("/voxelmap/lattice_error", "attr", "f64", (2,), True),
    ("/voxelmap/bricks", "dset", "i32", ("BD", "BH", "BW"), True),
    ("/voxelmap/brick_values", "dset", "i16", ("V", 512), True),
    ("/voxelmap/lattice", "dset", "f32", ("BD+1", "BH+1", "BW+1"), True),
    # section 4: pointshell
    ("/pointshell", "group", None, None, True),
    ("/pointshell/points", "dset", "f64", ("N", 3), True),
    ("/pointshell/normals", "dset", "f32", ("N", 3), True),
    ("/pointshell/sphere_centers", "dset", "f64", ("N", 3), True),
    ("/pointshell/sphere_radii", "dset", "f64", ("N",), True),
    ("/pointshell/child_begin", "dset", "u32", ("N",), True),
    ("/pointshell/child_count", "dset", "u32", ("N",), True),
    ("/pointshell/level_offsets", "dset", "u32", ("L+1",), True),
    ("/pointshell/point_spacing", "attr", "f64", "scalar", False),
    ("/pointshell/branching", "attr", "f64", "scalar", False),
    # section 5: mass properties
    ("/mass_properties", "group", None, None, True),
    ("/mass_properties/volume", "attr", "f64", "scalar", True),
    ("/mass_properties/center_of_mass", "attr", "f64", (3,), True),
    ("/mass_properties/inertia", "attr", "f64", (3, 3), True),
    # section 6: provenance
    ("/provenance", "group", None, None, True),
    ("/provenance/generator", "attr", "str", "scalar", True),
    ("/provenance/generator_version", "attr", "str", "scalar", True),
    ("/provenance/source_file", "attr", "str", "scalar", True),
    ("/provenance/source_sha256", "attr", "str", "scalar", True),
    ("/provenance/build_parameters", "attr", "str", "scalar", True),
    ("/provenance/dependency_versions", "attr", "str", "scalar", True),
    ("/provenance/build_warnings", "attr", "str", "scalar", True),
    ("/provenance/created_utc", "attr", "str", "scalar", False),
]

# The objects 2.0 added to the voxelmap (§3.2, §3.3); a 1.x file has none of them.
VOXELMAP_2_0_PATHS = ("/voxelmap/brick_edge", "/voxelmap/distance_quantum", "/voxelmap/estimate_quantum",
                      "/voxelmap/lattice_error", "/voxelmap/bricks", "/voxelmap/brick_values", "/voxelmap/lattice")
VOXELMAP_2_0_DATASETS = ("/voxelmap/bricks", "/voxelmap/brick_values", "/voxelmap/lattice")

# §3.4: the dense grids of 1.0 and 1.1 files, in place of the 2.0 objects.
LEGACY_VOXELMAP_OBJECTS = [
    ("/voxelmap/layers", "dset", "i16", ("D", "H", "W"), True),
    ("/voxelmap/distances", "dset", "f32", ("D", "H", "W"), True),
]
LEGACY_GRID_DATASETS = ("/voxelmap/layers", "/voxelmap/distances")


def spec_objects(legacy=False):
    """SPEC_OBJECTS (format 2.0), or the object list of a 1.1 file (§3.4: layers/distances, no 2.0 objects)."""
    if not legacy:
        return list(SPEC_OBJECTS)
    out = []
    for obj in SPEC_OBJECTS:
        if obj[0] in VOXELMAP_2_0_PATHS:
            continue
        out.append(obj)
        if obj[0] == "/voxelmap/shell_thickness":
            out.extend(LEGACY_VOXELMAP_OBJECTS)
    return out


SPEC_BY_PATH = {o[0]: o for o in SPEC_OBJECTS + LEGACY_VOXELMAP_OBJECTS}


def split_path(path):
    """'/voxelmap/origin' -> ('/voxelmap', 'origin'); '/format' -> ('/', 'format')."""
    parent, _, name = path.rpartition("/")
    return (parent or "/"), name


def brick_counts_of(dims_whd):
    """(BW, BH, BD) = ceil(dims / 8) for dims [W, H, D] (§1)."""
    return tuple(-(-int(n) // BRICK_EDGE) for n in dims_whd)


def resolve_shape(shape, n=N_POINTS, dims=(DIM, DIM, DIM), levels=None, value_bricks=None):
    """Turn a symbolic spec shape into a concrete tuple; 'scalar' -> ()."""
    if shape == "scalar":
        return ()
    if levels is None:
        levels = len(level_offsets_expected()) - 1
    w, h, d = dims
    bw, bh, bd = brick_counts_of(dims)
    sym = {"N": n, "W": w, "H": h, "D": d, "L+1": levels + 1, "BW": bw, "BH": bh, "BD": bd,
           "BW+1": bw + 1, "BH+1": bh + 1, "BD+1": bd + 1, "V": value_bricks}
    return tuple(sym[s] if isinstance(s, str) else s for s in shape)


# ---------------------------------------------------------------------------------------------------------
# Expected values: the grid
# ---------------------------------------------------------------------------------------------------------

def center():
    return np.array(CENTER, dtype=np.float64)


def half_extent(grid=FIXTURE_GRID):
    return RADIUS + grid.margin * grid.voxel_size


def origin(grid=FIXTURE_GRID):
    return center() - half_extent(grid)


def dims(grid=FIXTURE_GRID):
    """[W, H, D]."""
    n = int(round(2 * half_extent(grid) / grid.voxel_size)) + 1
    return np.array([n, n, n], dtype=np.uint32)


@functools.lru_cache(maxsize=None)
def _signed_distance_grid(grid):
    """float64 signed distance at every voxel centre, shape [D, H, W] (x fastest)."""
    o = origin(grid)
    c = center()
    w, h, d = (int(x) for x in dims(grid))
    px = o[0] + grid.voxel_size * np.arange(w, dtype=np.float64)  # along i (x)
    py = o[1] + grid.voxel_size * np.arange(h, dtype=np.float64)  # along j (y)
    pz = o[2] + grid.voxel_size * np.arange(d, dtype=np.float64)  # along k (z)
    dz = (pz - c[2])[:, None, None]
    dy = (py - c[1])[None, :, None]
    dx = (px - c[0])[None, None, :]
    dist = np.sqrt(dx * dx + dy * dy + dz * dz) - RADIUS
    dist.setflags(write=False)
    return dist


def signed_distance_grid(grid=FIXTURE_GRID):
    return _signed_distance_grid(grid).copy()


def stored_mask(grid=FIXTURE_GRID):
    """True where the h5py fixture stores a distance (|d| <= band*h + slack), both 1.1 and 2.0."""
    return np.abs(_signed_distance_grid(grid)) <= grid.band * grid.voxel_size + BAND_SLACK


def distances_expected(grid=FIXTURE_GRID):
    """Legacy 1.1 `distances`: float32(d) where stored, NaN elsewhere."""
    d = _signed_distance_grid(grid)
    out = np.full(d.shape, np.nan, dtype=np.float32)
    m = stored_mask(grid)
    out[m] = d[m].astype(np.float32)
    return out


def layers_expected(grid=FIXTURE_GRID):
    """floor(-d/h + 1/2) of the exact d, clamped (the 1.1 fixture's `layers`; a 2.0 file's layers agree where a
    distance is stored)."""
    d = _signed_distance_grid(grid)
    v = np.floor(-d / grid.voxel_size + 0.5)
    v = np.clip(v, -32767, 32767)
    return v.astype(np.int16)


def lattice_exact(grid=FIXTURE_GRID):
    """float64 [BD + 1, BH + 1, BW + 1]: the exact unsigned distance at every lattice point's voxel (§3.3)."""
    d = _signed_distance_grid(grid)
    idx = [np.minimum(BRICK_EDGE * np.arange(nb + 1), int(n) - 1)
           for n, nb in zip(dims(grid), brick_counts_of(dims(grid)))]
    return np.abs(d[np.ix_(idx[2], idx[1], idx[0])])


def default_distance_quantum(grid=FIXTURE_GRID):
    """`voxfmt build`'s choice (§3.1): band*h/16383, the finest step whose codes still reach the band edge."""
    return grid.band * grid.voxel_size / 16383.0


def default_estimate_quantum(grid=FIXTURE_GRID):
    """`voxfmt build`'s choice (§3.2): h/16."""
    return grid.voxel_size / 16.0


def _round_up_f32(x):
    """float32 nearest to x, moved up one step where it fell below x (a lattice value is never below u)."""
    x = np.asarray(x, dtype=np.float64)
    f = x.astype(np.float32)
    low = f.astype(np.float64) < x
    f[low] = np.nextafter(f[low], np.float32(np.inf))
    return f


def _interpolate_per_brick(lattice, dims_whd):
    """§3.3 written out brick by brick (a second implementation beside spec_support.interpolate_lattice, so that
    the self-check compares two): L at every voxel, float64 [D, H, W]."""
    w, h, d = (int(x) for x in dims_whd)
    bw, bh, bd = brick_counts_of(dims_whd)
    lat = np.asarray(lattice, dtype=np.float64)
    e = BRICK_EDGE
    out = np.zeros((d, h, w), dtype=np.float64)

    def axis(b, n):
        x0, x1 = min(e * b, n - 1), min(e * b + e, n - 1)
        i = np.arange(e * b, min(e * b + e, n))
        t = (i - x0) / float(x1 - x0) if x1 > x0 else np.zeros(len(i))
        return slice(e * b, e * b + len(i)), t

    for bk in range(bd):
        sz, tz = axis(bk, d)
        for bj in range(bh):
            sy, ty = axis(bj, h)
            for bi in range(bw):
                sx, tx = axis(bi, w)
                acc = 0.0
                for cz in (0, 1):
                    for cy in (0, 1):
                        for cx in (0, 1):
                            wgt = ((tz if cz else 1 - tz)[:, None, None] * (ty if cy else 1 - ty)[None, :, None]
                                   * (tx if cx else 1 - tx)[None, None, :])
                            acc = acc + wgt * lat[bk + cz, bj + cy, bi + cx]
                out[sz, sy, sx] = acc
    return out


@functools.lru_cache(maxsize=None)
def _encode_voxelmap(grid, distance_quantum, estimate_quantum, brick_order, value_bricks, padding_code):
    d = _signed_distance_grid(grid)
    h, band = grid.voxel_size, grid.band
    dq = distance_quantum if distance_quantum is not None else default_distance_quantum(grid)
    eq = estimate_quantum if estimate_quantum is not None else default_estimate_quantum(grid)
    dims_whd = dims(grid)
    w, hh, dd = (int(x) for x in dims_whd)
    bw, bh, bd = brick_counts_of(dims_whd)
    e = BRICK_EDGE

    lattice = _round_up_f32(lattice_exact(grid))
    interp = _interpolate_per_brick(lattice, dims_whd)
    stored = stored_mask(grid)
    inside = d < 0
    estimate = np.where(inside, -1.0, 1.0) * np.maximum(interp, (band - 0.5) * h)
    n_stored = np.rint(d / dq).astype(np.int64)
    n_est = np.rint(estimate / eq).astype(np.int64)
    if np.any(np.abs(n_stored[stored]) > 16383) or np.any(np.abs(n_est[~stored]) > 16383):
        raise ValueError("a code does not fit in 16 bits: quanta too small for this grid")
    if np.any(n_est[~stored] == 0):
        raise ValueError("an estimate rounds to 0 (§3.2: never 0)")
    code = np.where(stored, 2 * n_stored + 1, 2 * n_est)

    padded = np.full((bd * e, bh * e, bw * e), padding_code, dtype=np.int64)
    padded[:dd, :hh, :w] = code
    table = np.empty((bd, bh, bw), dtype=np.int64)
    rows = []
    for bk in range(bd):
        for bj in range(bh):
            for bi in range(bw):
                sl = (slice(bk * e, bk * e + e), slice(bj * e, bj * e + e), slice(bi * e, bi * e + e))
                mixed = bool(inside[sl].any() and (~inside[sl]).any())
                if value_bricks == "all" or stored[sl].any() or mixed:
                    table[bk, bj, bi] = len(rows)
                    rows.append(padded[sl].reshape(-1))  # [lk, lj, li] -> column (lk*8 + lj)*8 + li
                elif value_bricks == "needed":
                    table[bk, bj, bi] = -2 if inside[sl].all() else -1
                else:
                    raise ValueError("value_bricks %r" % value_bricks)
    values = np.array(rows, dtype=np.int64).reshape(len(rows), e ** 3)
    if brick_order == "reversed":  # rows in the opposite order: readers must follow the table
        values = values[::-1]
        table = np.where(table >= 0, len(rows) - 1 - table, table)
    elif brick_order != "raster":
        raise ValueError("brick_order %r" % brick_order)
    out = {
        "/voxelmap/brick_edge": np.uint32(BRICK_EDGE),
        "/voxelmap/distance_quantum": np.float64(dq),
        "/voxelmap/estimate_quantum": np.float64(eq),
        "/voxelmap/lattice_error": np.array(LATTICE_ERROR, dtype=np.float64),
        "/voxelmap/bricks": table.astype(np.int32),
        "/voxelmap/brick_values": values.astype(np.int16),
        "/voxelmap/lattice": lattice,
    }
    for v in out.values():
        if isinstance(v, np.ndarray):
            v.setflags(write=False)
    return out


def encode_voxelmap(grid=FIXTURE_GRID, distance_quantum=None, estimate_quantum=None, brick_order="raster",
                    value_bricks="needed", padding_code=0):
    """The 2.0 voxelmap objects of the sphere (§3.2, §3.3) as {path: value}, baked as the module docstring says.

      distance_quantum, estimate_quantum  the steps (default band*h/16383 and h/16, `voxfmt build`'s);
      brick_order   "raster" (value brick n = the n-th value brick in table order) or "reversed";
      value_bricks  "needed" (coarse wherever §3.2 allows) or "all" (every brick a value brick, also allowed);
      padding_code  the code written at positions past the grid (writers write 0; readers ignore them).
    """
    enc = _encode_voxelmap(grid, distance_quantum, estimate_quantum, brick_order, value_bricks, padding_code)
    return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in enc.items()}


# ---------------------------------------------------------------------------------------------------------
# Expected values: point shell, mass properties, provenance
# ---------------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _points_and_normals():
    c = center()
    pts = np.empty((N_POINTS, 3), dtype=np.float64)
    nrm = np.empty((N_POINTS, 3), dtype=np.float64)
    for n in range(N_POINTS):
        z = 1.0 - 2.0 * (n + 0.5) / N_POINTS
        rho = math.sqrt(1.0 - z * z)
        phi = n * math.pi * (3.0 - math.sqrt(5.0))
        u = (rho * math.cos(phi), rho * math.sin(phi), z)
        pts[n] = (c[0] + RADIUS * u[0], c[1] + RADIUS * u[1], c[2] + RADIUS * u[2])
        nrm[n] = (-u[0], -u[1], -u[2])
    pts.setflags(write=False)
    nrm.setflags(write=False)
    return pts, nrm


def points_expected():
    return _points_and_normals()[0].copy()


def normals_expected():
    return _points_and_normals()[1].astype(np.float32)


def child_begin_expected():
    n = np.arange(N_POINTS, dtype=np.int64)
    return np.minimum(BRANCHING * n + 1, N_POINTS).astype(np.uint32)


def child_count_expected():
    n = np.arange(N_POINTS, dtype=np.int64)
    return np.clip(N_POINTS - (BRANCHING * n + 1), 0, BRANCHING).astype(np.uint32)


def level_offsets_expected():
    offs = [0, 1]
    while offs[-1] < N_POINTS:
        width = offs[-1] - offs[-2]
        offs.append(min(offs[-1] + BRANCHING * width, N_POINTS))
    return np.array(offs, dtype=np.uint32)  # [0, 1, 5, 21, 85, 200]


def points_per_level_expected():
    return [int(x) for x in np.diff(level_offsets_expected().astype(np.int64))]


def subtree(node, child_begin, child_count):
    """All node indices of node's subtree (node included), from the stored children ranges."""
    out = []
    stack = [int(node)]
    while stack:
        m = stack.pop()
        out.append(m)
        b, k = int(child_begin[m]), int(child_count[m])
        stack.extend(range(b, b + k))
    return out


def sphere_centers_expected():
    return points_expected()


def sphere_radii_expected():
    pts = _points_and_normals()[0]
    cb, cc = child_begin_expected(), child_count_expected()
    radii = np.zeros(N_POINTS, dtype=np.float64)
    for n in range(N_POINTS):
        members = subtree(n, cb, cc)
        diff = pts[members] - pts[n]
        radii[n] = float(np.max(np.sqrt(np.sum(diff * diff, axis=1))))
    return radii


def bounds_expected():
    c = center()
    return c - RADIUS, c + RADIUS


def volume_expected():
    return 4.0 / 3.0 * math.pi * RADIUS ** 3


def inertia_expected():
    return np.diag([2.0 / 5.0 * volume_expected() * RADIUS ** 2] * 3).astype(np.float64)


def point_spacing_expected():
    """Mean nearest-neighbour distance of the finest (complete) shell."""
    pts = _points_and_normals()[0]
    diff = pts[:, None, :] - pts[None, :, :]
    dist = np.sqrt(np.sum(diff * diff, axis=2))
    np.fill_diagonal(dist, np.inf)
    return float(np.mean(np.min(dist, axis=1)))


def build_parameters_expected():
    """The only member both sides agree on is shape == "sphere"; the rest is free."""
    return {"shape": "sphere"}


def fixture_values(legacy=False, grid=FIXTURE_GRID, **encode):
    """Every object of the fixture as {path: value}; strings are Python str, arrays numpy arrays.

    legacy=False: format 2.0 (bricks, lattice; `encode` as for encode_voxelmap); legacy=True: format 1.1 (§3.4:
    dense layers and distances)."""
    bmin, bmax = bounds_expected()
    build_parameters = {
        "shape": "sphere",
        "center": list(CENTER),
        "radius": RADIUS,
        "voxel_size": grid.voxel_size,
        "margin": grid.margin,
        "distance_band": grid.band,
        "points": N_POINTS,
        "branching": BRANCHING,
    }
    dependency_versions = {"h5py": h5py.version.version, "hdf5": h5py.version.hdf5_version,
                           "numpy": np.__version__}
    vals = {
        "/format": "voxfmt",
        "/format_version": np.array([1, 1] if legacy else [2, 0], dtype=np.uint32),
        "/units": "m",
        "/frame": "right-handed",
        "/up_axis": "+Y",
        "/bounds_min": bmin,
        "/bounds_max": bmax,
        "/voxelmap/origin": origin(grid),
        "/voxelmap/voxel_size": np.float64(grid.voxel_size),
        "/voxelmap/dims": dims(grid),
        "/voxelmap/index_order": "zyx",
        "/voxelmap/distance_band": np.float64(grid.band),
        "/voxelmap/margin": np.uint32(grid.margin),
        "/pointshell/points": points_expected(),
        "/pointshell/normals": normals_expected(),
        "/pointshell/sphere_centers": sphere_centers_expected(),
        "/pointshell/sphere_radii": sphere_radii_expected(),
        "/pointshell/child_begin": child_begin_expected(),
        "/pointshell/child_count": child_count_expected(),
        "/pointshell/level_offsets": level_offsets_expected(),
        "/pointshell/point_spacing": np.float64(point_spacing_expected()),
        "/pointshell/branching": np.float64(BRANCHING),
        "/mass_properties/volume": np.float64(volume_expected()),
        "/mass_properties/center_of_mass": center(),
        "/mass_properties/inertia": inertia_expected(),
        "/provenance/generator": GENERATOR,
        "/provenance/generator_version": "0.0.0-h5py-fixture",
        "/provenance/source_file": "",
        "/provenance/source_sha256": "",
        "/provenance/build_parameters": json.dumps(build_parameters),
        "/provenance/dependency_versions": json.dumps(dependency_versions),
        "/provenance/build_warnings": "[]",
        "/provenance/created_utc": "2026-11-22T03:14:00Z",
    }
    if legacy:
        if encode:
            raise TypeError("encode options %s apply to 2.0 files only" % sorted(encode))
        vals["/voxelmap/layers"] = layers_expected(grid)
        vals["/voxelmap/distances"] = distances_expected(grid)
    else:
        vals.update(encode_voxelmap(grid, **encode))
    return vals


# ---------------------------------------------------------------------------------------------------------
# Writing with h5py alone
# ---------------------------------------------------------------------------------------------------------

STRING_MODES = ("vlen", "fixed_nullterm", "fixed_nullpad", "fixed_nullpad_exact")

# Unknown objects a future minor version might add (readers MUST ignore them).
EXTRA_OBJECTS = {
    "/x_future_note": ("attr", "str", "added by a later version"),
    "/x_future": ("group", None, None),
    "/x_future/data": ("dset", "<f8", np.arange(4, dtype=np.float64)),
    "/x_future/kind": ("attr", "str", "unknown"),
    "/voxelmap/x_future_flag": ("attr", "<u4", np.uint32(1)),
    "/pointshell/x_future_weights": ("dset", "<f4", np.ones(N_POINTS, dtype=np.float32)),
    "/provenance/x_future_comment": ("attr", "str", "ignore me"),
}


def _write_string_attr(obj, name, value, mode):
    if mode == "vlen":
        obj.attrs.create(name, value, dtype=h5py.string_dtype("utf-8"))
        return
    raw = value.encode("utf-8")
    if mode == "fixed_nullterm":
        size, pad = len(raw) + 1, h5py.h5t.STR_NULLTERM
    elif mode == "fixed_nullpad":
        size, pad = len(raw) + 5, h5py.h5t.STR_NULLPAD
    elif mode == "fixed_nullpad_exact":  # the string fills the buffer: no NUL byte at all
        size, pad = max(len(raw), 1), h5py.h5t.STR_NULLPAD
    else:
        raise ValueError("unknown string mode %r" % mode)
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(size)
    tid.set_strpad(pad)
    tid.set_cset(h5py.h5t.CSET_UTF8)
    space = h5py.h5s.create(h5py.h5s.SCALAR)
    if name in obj.attrs:
        del obj.attrs[name]
    aid = h5py.h5a.create(obj.id, name.encode("utf-8"), tid, space)
    aid.write(np.array(raw.ljust(size, b"\0"), dtype="S%d" % size), mtype=tid)


def _numeric_dtype(code, byteorder):
    return np.dtype(byteorder + DTYPE_CODES[code])


def settle_estimates(f):
    """§3.1, 2.2: rewrite the value-brick estimates of the open file `f` settled (the interpolated ones of 2.0 and
    2.1 do not follow 2.2's rule)."""
    import spec_support  # not at the top: spec_support reads files, this module writes them

    vm = spec_support.decode_voxelmap(f)
    steps = spec_support.settled_estimate_steps(vm)
    dense = np.where(vm.value_brick & ~vm.stored, np.where(vm.code < 0, -2, 2) * steps, vm.code)
    codes = np.array(f["/voxelmap/brick_values"][()], dtype=np.int64)
    e = BRICK_EDGE
    d, h, w = dense.shape
    for (bk, bj, bi), n in np.ndenumerate(vm.bricks):
        if n >= 0:
            block = codes[n].reshape(e, e, e)
            z, y, x = min(e, d - bk * e), min(e, h - bj * e), min(e, w - bi * e)
            block[:z, :y, :x] = dense[bk * e:bk * e + z, bj * e:bj * e + y, bi * e:bi * e + x]
            codes[n] = block.reshape(-1)
    f["/voxelmap/brick_values"][...] = codes.astype(np.int16)


def write_fixture_h5py(path, *, legacy=False, grid=FIXTURE_GRID, values=None, dtypes=None, omit=(),
                       string_mode="fixed_nullterm", byteorder="<", format_version=None, grid_layout="chunked",
                       grid_chunks=(8, 8, 8), value_chunk_rows=4, shuffle=True, compression="gzip", fletcher32=False,
                       optional=True, extra_objects=False, post=None, **encode):
    """Write the sphere fixture to `path` with h5py alone, following the spec's dtypes exactly.

    What is written:
      legacy        False: format 2.0 (§3.2, §3.3: bricks, brick_values, lattice); True: a 1.1 file (§3.4: the
                    dense layers and distances of every 1.x file, which 2.0 readers still read);
      grid          FIXTURE_GRID (what write_sphere_asset writes) or another Grid of the same sphere (FINE_GRID);
      encode        2.0 only, passed to encode_voxelmap: distance_quantum, estimate_quantum, brick_order,
                    value_bricks, padding_code.
    Hooks for variants:
      values        {path: value} replacing fixture values (any shape; e.g. to corrupt data);
      dtypes        {path: numpy dtype string or "str"} overriding the stored dtype of one object;
      omit          paths not to write (a group path omits the group and everything in it);
      string_mode   "fixed_nullterm" (spec writer rule), "vlen" (files written before 2026-11), "fixed_nullpad"
                    (padded with extra NULs)
                    or "fixed_nullpad_exact" (null-padded type of exactly the string length, no NUL);
      byteorder     "<" (spec writer rule) or ">" for big-endian numeric data and attributes;
      format_version shortcut for values["/format_version"];
      grid_layout   "chunked" or "contiguous", for the voxelmap's datasets (2.0: bricks, lattice and brick_values;
                    1.1: layers and distances). Chunked: grid_chunks entries of bricks/lattice/layers/distances,
                    value_chunk_rows bricks of brick_values per chunk (small, so that even the 15^3 fixture
                    spans several chunks, edge chunks included), with shuffle, compression (gzip) and fletcher32
                    as asked;
      optional      write the OPTIONAL objects (margin, point_spacing, branching, created_utc; never
                    shell_thickness: the fixture is a solid);
      extra_objects add unknown groups/datasets/attributes (EXTRA_OBJECTS);
      post          callable(h5py.File) run last, before the file is closed.
    """
    vals = fixture_values(legacy=legacy, grid=grid, **encode)
    if format_version is not None:
        vals["/format_version"] = np.asarray(format_version, dtype=np.uint32)
    settle = (not legacy and tuple(int(x) for x in vals["/format_version"]) >= (2, 2)
              and "/voxelmap/brick_values" not in (values or {}))
    if values:
        vals.update(values)
    dtypes = dict(dtypes or {})
    omit = tuple(omit)
    grid_datasets = LEGACY_GRID_DATASETS if legacy else VOXELMAP_2_0_DATASETS

    def omitted(p):
        return any(p == o or p.startswith(o.rstrip("/") + "/") for o in omit)

    with h5py.File(path, "w") as f:
        for opath, kind, code, _shape, required in spec_objects(legacy):
            if omitted(opath) or (not required and not optional):
                continue
            if kind == "group":
                f.require_group(opath)
                continue
            parent_path, name = split_path(opath)
            if omitted(parent_path) or opath not in vals:
                continue
            parent = f.require_group(parent_path)
            value = vals[opath]
            dt = dtypes.get(opath)
            if dt is None:
                dt = "str" if code == "str" else _numeric_dtype(code, byteorder)
            if kind == "attr":
                if isinstance(dt, str) and dt == "str":
                    _write_string_attr(parent, name, str(value), string_mode)
                else:
                    parent.attrs.create(name, np.asarray(value).astype(dt), dtype=np.dtype(dt))
            else:
                data = np.asarray(value).astype(dt)
                kw = {}
                if opath in grid_datasets and grid_layout == "chunked" and data.size > 0:
                    if opath == "/voxelmap/brick_values" and data.ndim == 2:
                        want = (value_chunk_rows, data.shape[1])
                    elif data.ndim == len(grid_chunks):
                        want = grid_chunks
                    else:  # a malformed rank (tests of WRONG_SHAPE)
                        want = (grid_chunks[0],) * data.ndim
                    kw["chunks"] = tuple(max(1, min(c, s)) for c, s in zip(want, data.shape))
                    if shuffle:
                        kw["shuffle"] = True
                    if compression:
                        kw["compression"] = compression
                    if fletcher32:
                        kw["fletcher32"] = True
                parent.create_dataset(name, data=data, dtype=np.dtype(dt), **kw)
        if settle and "/voxelmap/brick_values" in f:
            settle_estimates(f)
        if extra_objects:
            for opath, (kind, dt, value) in EXTRA_OBJECTS.items():
                if kind == "group":
                    f.require_group(opath)
                    continue
                parent_path, name = split_path(opath)
                parent = f.require_group(parent_path)
                if kind == "attr" and dt == "str":
                    _write_string_attr(parent, name, value, string_mode)
                elif kind == "attr":
                    parent.attrs.create(name, np.asarray(value).astype(dt), dtype=np.dtype(dt))
                else:
                    parent.create_dataset(name, data=np.asarray(value).astype(dt), dtype=np.dtype(dt))
        if post is not None:
            post(f)
    return path


def write_legacy_fixture_h5py(path, **kw):
    """write_fixture_h5py(path, legacy=True, ...): the sphere as a format 1.1 file (§3.4)."""
    return write_fixture_h5py(path, legacy=True, **kw)


def replace_dataset(f, path, data=None, **create):
    """For `post` hooks: delete dataset `path` and create it again from `data` (default: its own data) with
    h5py.create_dataset options `create` (dtype, chunks, compression, ...)."""
    old = f[path]
    if data is None:
        data = old[()]
    attrs = {k: old.attrs[k] for k in old.attrs}
    parent, name = split_path(path)
    del f[path]
    ds = f[parent].create_dataset(name, data=data, **create)
    for k, v in attrs.items():
        ds.attrs[k] = v
    return ds
