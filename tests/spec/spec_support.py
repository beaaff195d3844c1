"""Harness helpers shared by the independent-reader tests (no test cases here), and the spec's voxelmap decoder.

`decode_voxelmap` reads a format 2.0 voxelmap (spec §3.2, §3.3) and `decode_legacy_voxelmap` a 1.x one the way
§3.4 says a 2.0 reader sees it, both into dense numpy arrays of a whole (small) grid. Both are written from
spec/voxfmt-format.md alone, never from the C++ sources: they are what the tests compare the analytic sphere,
and `voxfmt inspect`'s figures, against.

Configuration (environment):
  VOXFMT_BIN            path to the `voxfmt` command-line tool
  VOXFMT_SAMPLE_WRITER  path to a program run as `WRITER OUT.h5` that writes the sphere fixture
  H5DUMP                optional, defaults to /usr/bin/h5dump
"""

import json
import math
import os
import re
import subprocess
import unittest

import h5py
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SPEC_DIR = os.path.normpath(os.path.join(HERE, "..", "..", "spec"))

VOXFMT_BIN = os.environ.get("VOXFMT_BIN", "")
SAMPLE_WRITER = os.environ.get("VOXFMT_SAMPLE_WRITER", "")
H5DUMP = os.environ.get("H5DUMP", "/usr/bin/h5dump")

TIMEOUT = 60  # a read that sleeps is retried once after 5 s (isolated_read.cpp); sanitizer builds are slow


def _is_exe(p):
    return bool(p) and os.path.isfile(p) and os.access(p, os.X_OK)


def have_bin():
    return _is_exe(VOXFMT_BIN)


def have_writer():
    return _is_exe(SAMPLE_WRITER)


def have_h5dump():
    return _is_exe(H5DUMP)


requires_bin = unittest.skipUnless(have_bin(), "VOXFMT_BIN not set or not executable")
requires_writer = unittest.skipUnless(have_writer(), "VOXFMT_SAMPLE_WRITER not set or not executable")
requires_h5dump = unittest.skipUnless(have_h5dump(), "h5dump not found")


def run(args, timeout=TIMEOUT):
    """Run a command, capture text output. Never raises on a non-zero exit."""
    return subprocess.run([str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          universal_newlines=True, timeout=timeout)


def describe(proc):
    return "command: %s\nexit: %s\nstdout:\n%s\nstderr:\n%s" % (
        " ".join(proc.args), proc.returncode, proc.stdout[-4000:], proc.stderr[-4000:])


def issue_codes():
    """{code: severity} parsed from spec/issue-codes.md."""
    codes = {}
    with open(os.path.join(SPEC_DIR, "issue-codes.md"), encoding="utf-8") as fh:
        for line in fh:
            m = re.match(r"^\|\s*`([A-Z0-9_]+)`\s*\|\s*(error|warning|info)\s*\|", line)
            if m:
                codes[m.group(1)] = m.group(2)
    if not codes:
        raise RuntimeError("no issue codes parsed from spec/issue-codes.md")
    return codes


ISSUE_CODES = issue_codes()


def same_file_name(reported, given):
    """The CLI may echo the path as given or canonicalised."""
    if reported == given:
        return True
    try:
        return os.path.realpath(reported) == os.path.realpath(given)
    except (TypeError, ValueError):
        return False


# ---------------------------------------------------------------------------------------------------------
# h5dump -H parser: {path: {"kind": GROUP|DATASET|ATTRIBUTE, "type": str, "type_lines": [...], "space": str}}
# Attribute paths are "<owner path>/<name>" ("/name" for the root group).
# ---------------------------------------------------------------------------------------------------------

_OPEN_RE = re.compile(r'^(GROUP|DATASET|ATTRIBUTE|DATATYPE|SOFTLINK|EXTERNAL_LINK) "(.*)" \{$')


def parse_h5dump(text):
    objects = {}
    stack = []  # entries: (kind, path) or ("BLOCK", None)
    current_type = None  # (path, lines) while inside a multi-line DATATYPE block

    def owner_path():
        for kind, path in reversed(stack):
            if kind in ("GROUP", "DATASET", "ATTRIBUTE"):
                return path
        return None

    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            continue
        if line.startswith("HDF5 ") and line.endswith("{") and not stack:
            stack.append(("FILE", None))
            continue
        m = _OPEN_RE.match(line)
        if m:
            kind, name = m.group(1), m.group(2)
            parent = owner_path()
            if kind == "GROUP" and name == "/" and parent is None:
                path = "/"
            elif parent in (None, "/"):
                path = "/" + name
            else:
                path = parent + "/" + name
            stack.append((kind, path))
            objects[path] = {"kind": kind, "type": None, "type_lines": [], "space": None}
            continue
        if line.startswith("DATATYPE"):
            body = line[len("DATATYPE"):].strip()
            path = owner_path()
            if body.endswith("{"):
                tname = body[:-1].strip()
                stack.append(("TYPEBLOCK", path))
                current_type = path
            else:
                tname = body
            if path in objects and objects[path]["type"] is None:
                objects[path]["type"] = tname
            continue
        if line.startswith("DATASPACE"):
            path = owner_path()
            if path in objects:
                objects[path]["space"] = line[len("DATASPACE"):].strip()
            if line.count("{") > line.count("}"):
                stack.append(("BLOCK", None))
            continue
        if line == "}":
            if stack:
                kind, _ = stack.pop()
                if kind == "TYPEBLOCK":
                    current_type = None
            continue
        if current_type is not None and current_type in objects:
            objects[current_type]["type_lines"].append(line)
            continue
        if line.endswith("{"):
            stack.append(("BLOCK", None))
    return objects


def parse_json_stdout(testcase, proc):
    try:
        return json.loads(proc.stdout)
    except ValueError as exc:
        testcase.fail("stdout is not JSON (%s)\n%s" % (exc, describe(proc)))


def check_validate_json(testcase, proc, files):
    """Check the `validate --json` document shape; return {given path: file entry}."""
    js = parse_json_stdout(testcase, proc)
    testcase.assertIsInstance(js, dict, describe(proc))
    testcase.assertIn("files", js, describe(proc))
    testcase.assertIsInstance(js["files"], list, describe(proc))
    testcase.assertEqual(len(js["files"]), len(files), describe(proc))
    entries = {}
    for entry in js["files"]:
        testcase.assertIsInstance(entry, dict)
        for key in ("file", "valid", "issues"):
            testcase.assertIn(key, entry, describe(proc))
        testcase.assertIsInstance(entry["valid"], bool)
        testcase.assertIsInstance(entry["issues"], list)
        for issue in entry["issues"]:
            for key in ("code", "severity", "path", "message"):
                testcase.assertIn(key, issue, "issue lacks %r: %r" % (key, issue))
            testcase.assertRegex(issue["code"], r"^[A-Z][A-Z0-9_]*$")
            testcase.assertIn(issue["severity"], ("error", "warning", "info"))
            testcase.assertIsInstance(issue["path"], str)
            testcase.assertIsInstance(issue["message"], str)
            testcase.assertIn(issue["code"], ISSUE_CODES,
                              "issue code %r is not listed in spec/issue-codes.md" % issue["code"])
            testcase.assertEqual(issue["severity"], ISSUE_CODES[issue["code"]],
                                 "issue %r: severity differs from spec/issue-codes.md" % issue)
        has_error = any(i["severity"] == "error" for i in entry["issues"])
        testcase.assertEqual(entry["valid"], not has_error,
                             "'valid' must be true iff there is no error-severity issue: %r" % entry)
        match = [f for f in files if same_file_name(entry["file"], f)]
        testcase.assertTrue(match, "reported file %r is none of %r" % (entry["file"], files))
        entries[match[0]] = entry
    testcase.assertEqual(sorted(entries), sorted(files), describe(proc))
    return entries


# ---------------------------------------------------------------------------------------------------------
# Voxelmap decoder (spec §3.1-§3.4), for grids small enough to hold densely: every array is [D, H, W] (z, y, x;
# x fastest), voxel (i, j, k) at [k, j, i].
# ---------------------------------------------------------------------------------------------------------

BRICK_EDGE = 8  # §3.2: brick_edge MUST be 8
COARSE_OUTSIDE = -1  # §3.2 brick table entries of coarse bricks
COARSE_INSIDE = -2


def _text(value):
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    return bytes(value).decode("utf-8") if isinstance(value, (bytes, np.bytes_)) else str(value)


def brick_counts(dims):
    """(BW, BH, BD) = ceil(dims / 8) (§1), for dims = [W, H, D]."""
    return tuple(-(-int(n) // BRICK_EDGE) for n in dims)


def lattice_voxels(n):
    """§3.3, one axis of n voxels: the voxel coordinate min(8a, n - 1) of every lattice index a = 0..ceil(n/8)."""
    nb = -(-int(n) // BRICK_EDGE)
    return np.minimum(BRICK_EDGE * np.arange(nb + 1), n - 1)


def lattice_axis_weights(n):
    """§3.3, one axis of n voxels: for every voxel coordinate i its brick b (the cell's lattice indices are b and
    b + 1) and the weight t = (i - x0) / (x1 - x0) of lattice index b + 1, x0 = min(8b, n - 1),
    x1 = min(8b + 8, n - 1), t = 0 where they coincide. Also x0 and x1."""
    i = np.arange(int(n))
    b = i // BRICK_EDGE
    x0 = np.minimum(BRICK_EDGE * b, n - 1)
    x1 = np.minimum(BRICK_EDGE * b + BRICK_EDGE, n - 1)
    span = x1 - x0
    t = np.where(span > 0, (i - x0) / np.maximum(span, 1), 0.0)
    return b, t, x0, x1


def float32_up(x):
    """float32 nearest to x, one step up where that fell below x (a lattice value is never below u, §3.3)."""
    x = np.asarray(x, dtype=np.float64)
    f = x.astype(np.float32)
    low = f.astype(np.float64) < x
    f[low] = np.nextafter(f[low], np.float32(np.inf))
    return f


def interpolate_lattice(lattice, dims):
    """§3.3: L, the trilinear interpolation of `lattice` ([BD + 1, BH + 1, BW + 1]) at every voxel, and B, the sum
    over the cell's 8 lattice points of each one's weight times its distance to the voxel, in voxels (§3.1,
    accuracy of estimates). Both float64 [D, H, W]."""
    w, h, d = (int(x) for x in dims)
    lat = np.asarray(lattice, dtype=np.float64)
    (bx, tx, x0, x1), (by, ty, y0, y1), (bz, tz, z0, z1) = (lattice_axis_weights(w), lattice_axis_weights(h),
                                                             lattice_axis_weights(d))
    ix, iy, iz = np.arange(w), np.arange(h), np.arange(d)
    interp = np.zeros((d, h, w), dtype=np.float64)
    spread = np.zeros((d, h, w), dtype=np.float64)
    for cz in (0, 1):
        wz = (tz if cz else 1.0 - tz)[:, None, None]
        ez = ((z1 if cz else z0) - iz).astype(np.float64)[:, None, None]
        for cy in (0, 1):
            wy = (ty if cy else 1.0 - ty)[None, :, None]
            ey = ((y1 if cy else y0) - iy).astype(np.float64)[None, :, None]
            for cx in (0, 1):
                wx = (tx if cx else 1.0 - tx)[None, None, :]
                ex = ((x1 if cx else x0) - ix).astype(np.float64)[None, None, :]
                weight = wz * wy * wx
                corner = lat[(bz + cz)[:, None, None], (by + cy)[None, :, None], (bx + cx)[None, None, :]]
                interp += weight * corner
                spread += weight * np.sqrt(ex * ex + ey * ey + ez * ez)
    return interp, spread


class DecodedVoxelmap(object):
    """A voxelmap decoded to dense arrays, as the spec defines it (attributes in metres unless noted):

      values        float64 [D, H, W]: every voxel's value d^ (§3.1): its stored distance where it has one, else
                    its estimate (the code of a value brick, or sign * max(L, (band - 1/2) h) in a coarse brick)
      stored        bool [D, H, W]: the voxel has a stored distance
      value_brick   bool [D, H, W]: the voxel lies in a value brick
      code          int64 [D, H, W]: the voxel's 16-bit code (0 in coarse bricks; None for a 1.x file)
      interpolated  float64 [D, H, W]: L, the lattice interpolated at the voxel (§3.3)
      spread        float64 [D, H, W]: B of §3.1's accuracy bound, in voxels
      lattice_estimate  float64 [D, H, W]: max(L, (band - 1/2) h), the magnitude §3.1 gives an estimate
      bricks        int64 [BD, BH, BW]: the brick table (value brick row n >= 0, -1 coarse outside, -2 inside)
      codes         int64 [V, 512] or None (1.x): the value bricks' codes, as stored
      lattice       float64 [BD + 1, BH + 1, BW + 1]: unsigned distances at the lattice points
      dims (W, H, D), voxel_size, origin, distance_band, distance_quantum, estimate_quantum,
      lattice_error [eps0, eps1], format_version
    """

    @property
    def layers(self):
        """§3.1: v = floor(-d^/h + 1/2), clamped to [-32767, 32767] (int64)."""
        v = np.floor(-self.values / self.voxel_size + 0.5)
        return np.clip(v, -32767, 32767).astype(np.int64)

    @property
    def brick_count(self):
        return int(self.bricks.size)

    @property
    def value_brick_count(self):
        return int(np.count_nonzero(self.bricks >= 0))

    @property
    def coarse_brick_count(self):
        return int(np.count_nonzero(self.bricks < 0))

    @property
    def stored_count(self):
        return int(np.count_nonzero(self.stored))

    def voxel_center(self, i, j, k):
        return np.asarray(self.origin, dtype=np.float64) + self.voxel_size * np.array([i, j, k], dtype=np.float64)

    def voxel_centers(self):
        """float64 [D, H, W, 3]: the centre origin + h * (i, j, k) of every voxel (§3)."""
        w, h, d = self.dims
        o = np.asarray(self.origin, dtype=np.float64)
        out = np.empty((d, h, w, 3), dtype=np.float64)
        out[..., 0] = (o[0] + self.voxel_size * np.arange(w))[None, None, :]
        out[..., 1] = (o[1] + self.voxel_size * np.arange(h))[None, :, None]
        out[..., 2] = (o[2] + self.voxel_size * np.arange(d))[:, None, None]
        return out


def _voxelmap_group(source):
    if isinstance(source, h5py.Group) and "voxelmap" in source:
        return source["voxelmap"]
    return source


def _common_attributes(out, g):
    a = g.attrs
    out.dims = tuple(int(x) for x in np.asarray(a["dims"]).reshape(-1))
    out.voxel_size = float(np.asarray(a["voxel_size"]))
    out.origin = np.asarray(a["origin"], dtype=np.float64).reshape(-1)
    out.distance_band = float(np.asarray(a["distance_band"]))
    out.index_order = _text(a["index_order"])
    if out.index_order != "zyx":
        raise ValueError("index_order %r: only zyx is defined (§3.2)" % out.index_order)
    if len(out.dims) != 3 or min(out.dims) < 1:
        raise ValueError("dims %r" % (out.dims,))
    root = g.file
    fv = root.attrs.get("format_version")
    out.format_version = tuple(int(x) for x in np.asarray(fv).reshape(-1)) if fv is not None else None


def decode_voxelmap(source):
    """Decode a format 2.0 voxelmap (§3.2, §3.3) into a DecodedVoxelmap.

    `source` is a file path, an open h5py.File or the /voxelmap group. Raises ValueError where the file breaks a
    rule the decoding depends on (a brick table entry that is no value brick's row, wrong shapes, brick_edge)."""
    if isinstance(source, (str, bytes, os.PathLike)):
        with h5py.File(source, "r") as f:
            return decode_voxelmap(f)
    g = _voxelmap_group(source)
    out = DecodedVoxelmap()
    _common_attributes(out, g)
    a = g.attrs
    if int(np.asarray(a["brick_edge"])) != BRICK_EDGE:
        raise ValueError("brick_edge %r, MUST be 8" % a["brick_edge"])
    out.distance_quantum = float(np.asarray(a["distance_quantum"]))
    out.estimate_quantum = float(np.asarray(a["estimate_quantum"]))
    out.lattice_error = [float(x) for x in np.asarray(a["lattice_error"]).reshape(-1)]
    w, h, d = out.dims
    bw, bh, bd = brick_counts(out.dims)
    bricks = np.asarray(g["bricks"][()]).astype(np.int64)
    codes = np.asarray(g["brick_values"][()]).astype(np.int64)
    lattice = np.asarray(g["lattice"][()]).astype(np.float64)
    if bricks.shape != (bd, bh, bw):
        raise ValueError("bricks shape %r, expected [BD, BH, BW] = %r" % (bricks.shape, (bd, bh, bw)))
    if codes.ndim != 2 or codes.shape[1] != BRICK_EDGE ** 3:
        raise ValueError("brick_values shape %r, expected [V, 512]" % (codes.shape,))
    if lattice.shape != (bd + 1, bh + 1, bw + 1):
        raise ValueError("lattice shape %r, expected %r" % (lattice.shape, (bd + 1, bh + 1, bw + 1)))
    nv = codes.shape[0]
    bad = (bricks < COARSE_INSIDE) | (bricks >= nv)
    if np.any(bad):
        raise ValueError("brick table entry %d at [bk, bj, bi] = %s is no value brick's row (V = %d) nor -1/-2"
                         % (int(bricks[tuple(np.argwhere(bad)[0])]), np.argwhere(bad)[0].tolist(), nv))
    out.bricks, out.codes, out.lattice = bricks, codes, lattice

    e = BRICK_EDGE
    code = np.zeros((bd * e, bh * e, bw * e), dtype=np.int64)
    in_value = np.zeros(code.shape, dtype=bool)
    coarse_sign = np.zeros(code.shape, dtype=np.float64)
    for (bk, bj, bi), n in np.ndenumerate(bricks):
        sl = (slice(bk * e, bk * e + e), slice(bj * e, bj * e + e), slice(bi * e, bi * e + e))
        if n >= 0:
            code[sl] = codes[n].reshape(e, e, e)  # column (lk*8 + lj)*8 + li -> [lk, lj, li]
            in_value[sl] = True
        else:
            coarse_sign[sl] = -1.0 if n == COARSE_INSIDE else 1.0
    code, in_value, coarse_sign = code[:d, :h, :w], in_value[:d, :h, :w], coarse_sign[:d, :h, :w]

    interp, spread = interpolate_lattice(lattice, out.dims)
    floor_mag = (out.distance_band - 0.5) * out.voxel_size
    out.interpolated, out.spread = interp, spread
    out.lattice_estimate = np.maximum(interp, floor_mag)
    out.value_brick = in_value
    out.code = np.where(in_value, code, 0)
    out.stored = in_value & ((code & 1) == 1)
    half = code >> 1  # arithmetic shift: floor(c / 2)
    out.values = np.where(out.stored, half * out.distance_quantum,
                          np.where(in_value, half * out.estimate_quantum, coarse_sign * out.lattice_estimate))
    return out


def settled_estimate_steps(vm):
    """§3.1, settled estimates (2.2): the magnitude, in steps of estimate_quantum, every value-brick voxel without a
    stored distance holds: the least of its seed (over its cell's 8 lattice points, ceil(l / q) plus the steps of a
    path to the point's voxel, at most 16383) and each of its 26 neighbours' magnitudes in value bricks plus that
    step's length (a stored distance's magnitude rounded up to a step). int64 [D, H, W]; -1 outside value bricks.
    Relaxed plainly, all voxels at once, until nothing changes."""
    far, top = 1 << 40, 16383
    h, q = vm.voxel_size, vm.estimate_quantum
    w, hh, d = (int(x) for x in vm.dims)
    step = [int(np.ceil(np.sqrt(k) * (h / q) - 1e-9)) for k in range(4)]

    def path(a, b, c):
        s = np.sort(np.abs(np.stack(np.broadcast_arrays(a, b, c))), axis=0)
        return np.minimum(s[0] * step[3] + (s[1] - s[0]) * step[2] + (s[2] - s[1]) * step[1], top)

    corner_steps = np.clip(np.ceil(vm.lattice / q - 1e-9), 0, top).astype(np.int64)
    (bx, _, x0, x1), (by, _, y0, y1), (bz, _, z0, z1) = (lattice_axis_weights(w), lattice_axis_weights(hh),
                                                         lattice_axis_weights(d))
    ix, iy, iz = np.arange(w)[None, None, :], np.arange(hh)[None, :, None], np.arange(d)[:, None, None]
    seed = np.full((d, hh, w), top, dtype=np.int64)
    for cz in (0, 1):
        for cy in (0, 1):
            for cx in (0, 1):
                corner = corner_steps[(bz + cz)[:, None, None], (by + cy)[None, :, None], (bx + cx)[None, None, :]]
                to = path((x1 if cx else x0)[None, None, :] - ix, (y1 if cy else y0)[None, :, None] - iy,
                          (z1 if cz else z0)[:, None, None] - iz)
                seed = np.minimum(seed, corner + to)
    source = np.minimum(np.ceil(np.abs(vm.code >> 1) * vm.distance_quantum / q - 1e-9), top).astype(np.int64)
    estimate = vm.value_brick & ~vm.stored
    m = np.where(vm.stored, source, np.where(estimate, seed, far))
    while True:
        padded = np.pad(m, 1, constant_values=far)
        best = m.copy()
        for dz in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    if dz == dy == dx == 0:
                        continue
                    n = padded[1 + dz:1 + dz + d, 1 + dy:1 + dy + hh, 1 + dx:1 + dx + w]
                    best = np.minimum(best, n + step[abs(dx) + abs(dy) + abs(dz)])
        lowered = estimate & (best < m)
        if not np.any(lowered):
            return np.where(vm.value_brick, m, -1)
        m = np.where(lowered, best, m)


def decode_legacy_voxelmap(source):
    """Decode a 1.0/1.1 voxelmap (§3.4: dense `layers` and `distances`) into a DecodedVoxelmap as a 2.0 reader
    sees it: a brick with a stored distance or with layers of both signs is a value brick (numbered in table
    order here; §3.4 does not fix the order), stored distances rounded to distance_band * h / 16383, every other
    brick coarse with its layers' sign, lattice values (|v| + 1/2) h from the layer at the lattice voxel (the
    stored |d| where there is one; as float32, the lattice's dtype, rounded up), lattice_error [1 + sqrt 3, 0]
    (1.1) or [1, 1/9] (1.0), and every voxel without a stored distance estimated from the lattice with its
    layer's sign (unrounded: §3.4 names no estimate step).

    Extra attributes: file_layers (int64) and file_distances (float64, NaN where not stored) as stored."""
    if isinstance(source, (str, bytes, os.PathLike)):
        with h5py.File(source, "r") as f:
            return decode_legacy_voxelmap(f)
    g = _voxelmap_group(source)
    out = DecodedVoxelmap()
    _common_attributes(out, g)
    w, h, d = out.dims
    layers = np.asarray(g["layers"][()]).astype(np.int64)
    dist = np.asarray(g["distances"][()]).astype(np.float64)
    if layers.shape != (d, h, w) or dist.shape != (d, h, w):
        raise ValueError("layers %r / distances %r, expected [D, H, W] = %r" % (layers.shape, dist.shape, (d, h, w)))
    out.file_layers, out.file_distances = layers, dist
    hv = out.voxel_size
    out.distance_quantum = out.distance_band * hv / 16383.0
    out.estimate_quantum = None
    minor = out.format_version[1] if out.format_version else 1
    out.lattice_error = [1.0, 1.0 / 9.0] if minor == 0 else [1.0 + math.sqrt(3.0), 0.0]
    stored = ~np.isnan(dist)
    out.stored = stored

    bw, bh, bd = brick_counts(out.dims)
    e = BRICK_EDGE
    bricks = np.empty((bd, bh, bw), dtype=np.int64)
    value_brick = np.zeros((d, h, w), dtype=bool)
    coarse_sign = np.zeros((d, h, w), dtype=np.float64)
    n = 0
    for bk in range(bd):
        for bj in range(bh):
            for bi in range(bw):
                sl = (slice(bk * e, bk * e + e), slice(bj * e, bj * e + e), slice(bi * e, bi * e + e))
                lay, st = layers[sl], stored[sl]
                if st.any() or ((lay > 0).any() and (lay < 0).any()):
                    bricks[bk, bj, bi] = n
                    n += 1
                    value_brick[sl] = True
                else:
                    inside = bool((lay > 0).all())
                    bricks[bk, bj, bi] = COARSE_INSIDE if inside else COARSE_OUTSIDE
                    coarse_sign[sl] = -1.0 if inside else 1.0
    out.bricks, out.codes = bricks, None

    lx, ly, lz = lattice_voxels(w), lattice_voxels(h), lattice_voxels(d)
    at = np.ix_(lz, ly, lx)
    lat = np.where(stored[at], np.abs(dist[at]), (np.abs(layers[at]) + 0.5) * hv)
    out.lattice = float32_up(lat).astype(np.float64)  # the lattice is f32 (§3.2), never below its value
    interp, spread = interpolate_lattice(out.lattice, out.dims)
    out.interpolated, out.spread = interp, spread
    out.lattice_estimate = np.maximum(interp, (out.distance_band - 0.5) * hv)
    out.value_brick = value_brick
    out.code = None
    layer_sign = np.where(layers > 0, -1.0, 1.0)
    sign = np.where(value_brick, layer_sign, coarse_sign)
    rounded = np.rint(np.where(stored, dist, 0.0) / out.distance_quantum) * out.distance_quantum
    out.values = np.where(stored, rounded, sign * out.lattice_estimate)
    return out
