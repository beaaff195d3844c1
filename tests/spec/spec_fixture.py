"""The analytic "sphere fixture", written from spec/voxfmt-format.md alone.

Both sides agree on this asset: the C++ example program `write_sphere_asset` writes exactly it, and
`write_fixture_h5py` below writes it with h5py alone (no libvoxfmt), so that each side can read what the
other one wrote.

Fixture (all lengths in metres):
  * sphere centre c = (0.1, -0.2, 0.3), radius r = 0.25, voxel size h = 0.05, margin 2 voxels,
    distance_band = 2.0 voxels;
  * grid origin = c - (r + 2h) on each axis, dims W = H = D = 15, voxel centre origin + h*(i, j, k);
  * d(p) = |p - c| - r; distances[k, j, i] = float32(d) where |d| <= distance_band*h (+1e-12), NaN elsewhere;
    layers[k, j, i] = floor(-d/h + 1/2) (float64) for every voxel;
  * N = 200 points on a Fibonacci sphere with inward float32 normals;
  * a complete 4-ary tree in breadth-first order, sphere_centers = points,
    sphere_radii = max distance from the node's point to the points of its subtree;
  * bounds c -/+ r, unit-density mass properties of the ball, provenance of `write_sphere_asset`.

Only the Python standard library, numpy and h5py are used.
"""

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

GENERATOR = "write_sphere_asset"

# dtype codes of the spec tables -> numpy kind+width (byte order added separately)
DTYPE_CODES = {"i16": "i2", "u32": "u4", "f32": "f4", "f64": "f8"}
# dtype codes -> the HDF5 predefined little-endian type names used by h5dump
H5DUMP_TYPES = {
    "i16": "H5T_STD_I16LE",
    "u32": "H5T_STD_U32LE",
    "f32": "H5T_IEEE_F32LE",
    "f64": "H5T_IEEE_F64LE",
}

# ---------------------------------------------------------------------------------------------------------
# The objects defined by spec/voxfmt-format.md (sections 2-6): path, kind, dtype code, shape, required.
# An attribute of group G named a has path "G/a" (the root's attributes are "/a"); names are unique within a
# group in the spec, so the path is unambiguous. Shapes: "scalar" or a tuple whose items are ints or the
# symbols "N", "W", "H", "D", "L+1".
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
    # section 3: voxelmap
    ("/voxelmap", "group", None, None, True),
    ("/voxelmap/origin", "attr", "f64", (3,), True),
    ("/voxelmap/voxel_size", "attr", "f64", "scalar", True),
    ("/voxelmap/dims", "attr", "u32", (3,), True),
    ("/voxelmap/index_order", "attr", "str", "scalar", True),
    ("/voxelmap/distance_band", "attr", "f64", "scalar", True),
    ("/voxelmap/margin", "attr", "u32", "scalar", False),
    ("/voxelmap/layers", "dset", "i16", ("D", "H", "W"), True),
    ("/voxelmap/distances", "dset", "f32", ("D", "H", "W"), True),
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

SPEC_BY_PATH = {o[0]: o for o in SPEC_OBJECTS}


def split_path(path):
    """'/voxelmap/origin' -> ('/voxelmap', 'origin'); '/format' -> ('/', 'format')."""
    parent, _, name = path.rpartition("/")
    return (parent or "/"), name


def resolve_shape(shape, n=N_POINTS, dims=(DIM, DIM, DIM), levels=None):
    """Turn a symbolic spec shape into a concrete tuple; 'scalar' -> ()."""
    if shape == "scalar":
        return ()
    if levels is None:
        levels = len(level_offsets_expected()) - 1
    w, h, d = dims
    sym = {"N": n, "W": w, "H": h, "D": d, "L+1": levels + 1}
    return tuple(sym[s] if isinstance(s, str) else s for s in shape)


# ---------------------------------------------------------------------------------------------------------
# Expected values
# ---------------------------------------------------------------------------------------------------------

def center():
    return np.array(CENTER, dtype=np.float64)


def origin():
    return center() - (RADIUS + MARGIN * VOXEL_SIZE)


def dims():
    """[W, H, D]."""
    return np.array([DIM, DIM, DIM], dtype=np.uint32)


@functools.lru_cache(maxsize=None)
def _signed_distance_grid():
    """float64 signed distance at every voxel centre, shape [D, H, W] (x fastest)."""
    o = origin()
    c = center()
    idx = np.arange(DIM, dtype=np.float64)
    px = o[0] + VOXEL_SIZE * idx  # along i (x)
    py = o[1] + VOXEL_SIZE * idx  # along j (y)
    pz = o[2] + VOXEL_SIZE * idx  # along k (z)
    dz = (pz - c[2])[:, None, None]
    dy = (py - c[1])[None, :, None]
    dx = (px - c[0])[None, None, :]
    d = np.sqrt(dx * dx + dy * dy + dz * dz) - RADIUS
    d.setflags(write=False)
    return d


def signed_distance_grid():
    return _signed_distance_grid().copy()


def stored_mask():
    """True where the fixture stores a distance (|d| <= band*h + slack)."""
    return np.abs(_signed_distance_grid()) <= DISTANCE_BAND * VOXEL_SIZE + BAND_SLACK


def distances_expected():
    d = _signed_distance_grid()
    out = np.full(d.shape, np.nan, dtype=np.float32)
    m = stored_mask()
    out[m] = d[m].astype(np.float32)
    return out


def layers_expected():
    d = _signed_distance_grid()
    v = np.floor(-d / VOXEL_SIZE + 0.5)
    v = np.clip(v, -32767, 32767)
    return v.astype(np.int16)


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


def fixture_values():
    """Every object of the fixture as {path: value}; strings are Python str, arrays numpy arrays."""
    bmin, bmax = bounds_expected()
    build_parameters = {
        "shape": "sphere",
        "center": list(CENTER),
        "radius": RADIUS,
        "voxel_size": VOXEL_SIZE,
        "margin": MARGIN,
        "distance_band": DISTANCE_BAND,
        "points": N_POINTS,
        "branching": BRANCHING,
    }
    dependency_versions = {"h5py": h5py.version.version, "hdf5": h5py.version.hdf5_version,
                           "numpy": np.__version__}
    return {
        "/format": "voxfmt",
        "/format_version": np.array([1, 1], dtype=np.uint32),
        "/units": "m",
        "/frame": "right-handed",
        "/up_axis": "+Y",
        "/bounds_min": bmin,
        "/bounds_max": bmax,
        "/voxelmap/origin": origin(),
        "/voxelmap/voxel_size": np.float64(VOXEL_SIZE),
        "/voxelmap/dims": dims(),
        "/voxelmap/index_order": "zyx",
        "/voxelmap/distance_band": np.float64(DISTANCE_BAND),
        "/voxelmap/margin": np.uint32(MARGIN),
        "/voxelmap/layers": layers_expected(),
        "/voxelmap/distances": distances_expected(),
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


def write_fixture_h5py(path, *, values=None, dtypes=None, omit=(), string_mode="fixed_nullterm", byteorder="<",
                       format_version=None, grid_layout="chunked", grid_chunks=(8, 8, 8), shuffle=True,
                       compression="gzip", fletcher32=False, optional=True, extra_objects=False, post=None):
    """Write the sphere fixture to `path` with h5py alone, following the spec's dtypes exactly.

    Hooks for variants:
      values        {path: value} replacing fixture values (any shape; e.g. to corrupt data);
      dtypes        {path: numpy dtype string or "str"} overriding the stored dtype of one object;
      omit          paths not to write (a group path omits the group and everything in it);
      string_mode   "fixed_nullterm" (spec writer rule), "vlen" (files written before 2026-11), "fixed_nullpad"
                    (padded with extra NULs)
                    or "fixed_nullpad_exact" (null-padded type of exactly the string length, no NUL);
      byteorder     "<" (spec writer rule) or ">" for big-endian numeric data and attributes;
      format_version shortcut for values["/format_version"];
      grid_layout   "chunked" (grid_chunks, shuffle, gzip, optional fletcher32) or "contiguous";
      optional      write the OPTIONAL objects (margin, point_spacing, branching, created_utc);
      extra_objects add unknown groups/datasets/attributes (EXTRA_OBJECTS);
      post          callable(h5py.File) run last, before the file is closed.
    """
    vals = fixture_values()
    if format_version is not None:
        vals["/format_version"] = np.asarray(format_version, dtype=np.uint32)
    if values:
        vals.update(values)
    dtypes = dict(dtypes or {})
    omit = tuple(omit)

    def omitted(p):
        return any(p == o or p.startswith(o.rstrip("/") + "/") for o in omit)

    with h5py.File(path, "w") as f:
        for opath, kind, code, _shape, required in SPEC_OBJECTS:
            if omitted(opath) or (not required and not optional):
                continue
            if kind == "group":
                f.require_group(opath)
                continue
            parent_path, name = split_path(opath)
            if omitted(parent_path):
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
                if opath in ("/voxelmap/layers", "/voxelmap/distances") and grid_layout == "chunked":
                    kw["chunks"] = tuple(min(c, s) for c, s in zip(grid_chunks, data.shape))
                    if shuffle:
                        kw["shuffle"] = True
                    if compression:
                        kw["compression"] = compression
                    if fletcher32:
                        kw["fletcher32"] = True
                parent.create_dataset(name, data=data, dtype=np.dtype(dt), **kw)
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
