"""Independent-reader tests: written from spec/voxfmt-format.md alone, never from the C++ sources.

  * C++ -> Python: the C++ sample writer's file is read with h5py and checked against the spec tables
    (existence, kind, exact little-endian dtype, shape), the generic rules of the spec, and the analytic
    sphere fixture (spec_fixture.py).
  * Python -> C++: files written with h5py alone (spec_fixture.write_fixture_h5py), including the variants
    the spec says readers must accept, are fed to `voxfmt validate --json` and `voxfmt inspect --json`.
  * h5dump -H of the C++-written file lists every required object with the spec's HDF5 type.
  * A self-check runs every C++ -> Python check on the h5py-written fixture, so the checks themselves are
    known to accept a conforming file.

Run:  VOXFMT_BIN=.../voxfmt VOXFMT_SAMPLE_WRITER=.../write_sphere_asset /usr/bin/python3 -m unittest -v
"""

import json
import math
import os
import re
import shutil
import tempfile
import unittest

import h5py
import numpy as np

import spec_fixture as sf
import spec_support as ss
from spec_support import describe

H5T_EXPECTED = {
    "i16": h5py.h5t.STD_I16LE,
    "u32": h5py.h5t.STD_U32LE,
    "f32": h5py.h5t.IEEE_F32LE,
    "f64": h5py.h5t.IEEE_F64LE,
}
ALLOWED_FILTERS = {h5py.h5z.FILTER_DEFLATE: "deflate", h5py.h5z.FILTER_SHUFFLE: "shuffle",
                   h5py.h5z.FILTER_FLETCHER32: "fletcher32"}


def as_text(value):
    """An HDF5 string attribute as read by h5py (str for vlen, bytes for fixed-length) -> str."""
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value[()]
    if isinstance(value, (bytes, np.bytes_)):
        return bytes(value).decode("utf-8")
    if isinstance(value, str):
        return value
    raise TypeError("not a string attribute value: %r (%s)" % (value, type(value)))


def f32_ulp(x):
    return np.spacing(np.abs(np.float32(x))).astype(np.float64)


class SpecFileChecks(object):
    """Checks of one asset file against the spec and the sphere fixture. Subclasses set cls.path."""

    path = None

    # -- helpers ------------------------------------------------------------------------------------------

    @classmethod
    def open(cls):
        return h5py.File(cls.path, "r")

    def attr(self, f, path):
        parent, name = sf.split_path(path)
        self.assertIn(parent, f, "missing group %s" % parent)
        self.assertIn(name, f[parent].attrs, "missing attribute %s" % path)
        return f[parent].attrs[name]

    def text_attr(self, f, path):
        return as_text(self.attr(f, path))

    def num_attr(self, f, path):
        return np.asarray(self.attr(f, path))

    def dset(self, f, path):
        self.assertIn(path, f, "missing dataset %s" % path)
        return f[path][()]

    # -- structure ----------------------------------------------------------------------------------------

    def test_required_objects_exist_with_kind(self):
        with self.open() as f:
            for path, kind, _code, _shape, required in sf.SPEC_OBJECTS:
                parent, name = sf.split_path(path)
                if kind == "attr":
                    present = parent in f and isinstance(f[parent], h5py.Group) and name in f[parent].attrs
                else:
                    present = path in f
                if not required and not present:
                    continue
                self.assertTrue(present, "%s (%s) is REQUIRED and absent" % (path, kind))
                if kind == "group":
                    self.assertIsInstance(f.get(path, getlink=False), h5py.Group, "%s must be a group" % path)
                elif kind == "dset":
                    self.assertIsInstance(f[path], h5py.Dataset, "%s must be a dataset" % path)

    def test_numeric_objects_exact_little_endian_dtype_and_shape(self):
        with self.open() as f:
            n = f["/pointshell/points"].shape[0]
            levels = f["/pointshell/level_offsets"].shape[0] - 1
            w, h, d = (int(x) for x in f["/voxelmap"].attrs["dims"])
            for path, kind, code, shape, _required in sf.SPEC_OBJECTS:
                if kind == "group" or code == "str":
                    continue
                parent, name = sf.split_path(path)
                if kind == "attr":
                    if name not in f[parent].attrs:
                        continue  # absence of REQUIRED objects is another test
                    oid = f[parent].attrs.get_id(name)
                    tid, space, npdt = oid.get_type(), oid.get_space(), oid.dtype
                else:
                    if path not in f:
                        continue
                    ds = f[path]
                    tid, space, npdt = ds.id.get_type(), ds.id.get_space(), ds.dtype
                expected = H5T_EXPECTED[code]
                self.assertTrue(tid.equal(expected),
                                "%s: HDF5 type must be exactly %s (got class %d size %d order %d, dtype %s)"
                                % (path, sf.H5DUMP_TYPES[code], tid.get_class(), tid.get_size(),
                                   tid.get_order(), npdt.str))
                self.assertEqual(tid.get_order(), h5py.h5t.ORDER_LE, "%s must be little-endian" % path)
                self.assertEqual(npdt.str, "<" + sf.DTYPE_CODES[code], path)
                want = sf.resolve_shape(shape, n=n, dims=(w, h, d), levels=levels)
                if want == ():
                    self.assertEqual(space.get_simple_extent_type(), h5py.h5s.SCALAR,
                                     "%s must have a scalar dataspace" % path)
                else:
                    self.assertEqual(space.get_simple_extent_type(), h5py.h5s.SIMPLE, path)
                    self.assertEqual(tuple(space.shape), want, "%s shape" % path)

    def test_fixture_shapes(self):
        with self.open() as f:
            self.assertEqual(f["/pointshell/points"].shape, (sf.N_POINTS, 3))
            self.assertEqual(f["/pointshell/level_offsets"].shape, (len(sf.level_offsets_expected()),))
            self.assertEqual(f["/voxelmap/layers"].shape, (sf.DIM, sf.DIM, sf.DIM))
            self.assertEqual(f["/voxelmap/distances"].shape, (sf.DIM, sf.DIM, sf.DIM))

    def test_strings_are_fixed_length_utf8_scalars(self):
        """§1: writers MUST write fixed-length, null-terminated, UTF-8 scalar strings."""
        with self.open() as f:
            for path, kind, code, _shape, _required in sf.SPEC_OBJECTS:
                if code != "str":
                    continue
                parent, name = sf.split_path(path)
                if name not in f[parent].attrs:
                    continue
                aid = f[parent].attrs.get_id(name)
                tid = aid.get_type()
                self.assertEqual(tid.get_class(), h5py.h5t.STRING, "%s must be an HDF5 string" % path)
                self.assertFalse(tid.is_variable_str(), "%s must be a fixed-length string" % path)
                self.assertEqual(tid.get_strpad(), h5py.h5t.STR_NULLTERM, "%s must be null-terminated" % path)
                self.assertEqual(tid.get_cset(), h5py.h5t.CSET_UTF8, "%s must be UTF-8" % path)
                self.assertEqual(aid.get_space().get_simple_extent_type(), h5py.h5s.SCALAR,
                                 "%s must be scalar" % path)

    def test_no_filters_other_than_deflate_shuffle_fletcher32(self):
        with self.open() as f:
            dsets = []
            f.visititems(lambda name, obj: dsets.append(obj) if isinstance(obj, h5py.Dataset) else None)
            for ds in dsets:
                dcpl = ds.id.get_create_plist()
                for i in range(dcpl.get_nfilters()):
                    fid = dcpl.get_filter(i)[0]
                    self.assertIn(fid, ALLOWED_FILTERS, "%s uses filter id %d" % (ds.name, fid))

    def test_should_grids_chunked_shuffle_deflate(self):
        """§1 SHOULD: voxel grids chunked (<= 32*32*32 voxels per chunk) with shuffle and deflate."""
        with self.open() as f:
            for p in ("/voxelmap/layers", "/voxelmap/distances"):
                ds = f[p]
                self.assertIsNotNone(ds.chunks, "%s is not chunked" % p)
                self.assertLessEqual(int(np.prod(ds.chunks)), 32 ** 3, "%s chunk %r" % (p, ds.chunks))
                self.assertTrue(ds.shuffle, "%s: no shuffle filter" % p)
                self.assertEqual(ds.compression, "gzip", "%s: no deflate filter" % p)

    def test_superblock_readable_by_hdf5_1_8(self):
        """Intro: HDF5 1.8 file-format compatible -> superblock version 0, 1 or 2 (3 needs 1.10)."""
        sig = b"\x89HDF\r\n\x1a\n"
        with open(self.path, "rb") as fh:
            data = fh.read(1 << 16)
        off = 0
        while off < len(data) and data[off:off + 8] != sig:
            off = 512 if off == 0 else off * 2
        self.assertLess(off, len(data), "HDF5 signature not found")
        self.assertLessEqual(data[off + 8], 2, "superblock version %d" % data[off + 8])

    # -- root -----------------------------------------------------------------------------------------------

    def test_root_attributes(self):
        with self.open() as f:
            self.assertEqual(self.text_attr(f, "/format"), "voxfmt")
            self.assertEqual(self.num_attr(f, "/format_version").tolist(), [1, 1])
            self.assertEqual(self.text_attr(f, "/units"), "m")
            self.assertEqual(self.text_attr(f, "/frame"), "right-handed")
            self.assertEqual(self.text_attr(f, "/up_axis"), "+Y")

    def test_bounds(self):
        bmin_e, bmax_e = sf.bounds_expected()
        with self.open() as f:
            bmin = self.num_attr(f, "/bounds_min").astype(np.float64)
            bmax = self.num_attr(f, "/bounds_max").astype(np.float64)
            pts = self.dset(f, "/pointshell/points")
        self.assertTrue(np.all(np.isfinite(bmin)) and np.all(np.isfinite(bmax)))
        self.assertTrue(np.all(bmin <= bmax), "bounds_min > bounds_max: %r %r" % (bmin, bmax))
        np.testing.assert_allclose(bmin, bmin_e, rtol=0, atol=1e-12)
        np.testing.assert_allclose(bmax, bmax_e, rtol=0, atol=1e-12)
        # points lie on the surface, hence in its bounding box
        self.assertTrue(np.all(pts >= bmin - 1e-12) and np.all(pts <= bmax + 1e-12),
                        "a surface point lies outside [bounds_min, bounds_max]")

    # -- voxelmap -------------------------------------------------------------------------------------------

    def test_voxelmap_attributes(self):
        with self.open() as f:
            origin = self.num_attr(f, "/voxelmap/origin")
            h = float(self.num_attr(f, "/voxelmap/voxel_size"))
            dims = self.num_attr(f, "/voxelmap/dims").tolist()
            order = self.text_attr(f, "/voxelmap/index_order")
            band = float(self.num_attr(f, "/voxelmap/distance_band"))
            margin = f["/voxelmap"].attrs.get("margin")
        self.assertTrue(np.all(np.isfinite(origin)))
        self.assertTrue(math.isfinite(h) and h > 0)
        self.assertTrue(all(x >= 1 for x in dims) and dims[0] * dims[1] * dims[2] <= 2 ** 31 - 1)
        self.assertEqual(order, "zyx")
        self.assertTrue(math.isfinite(band) and band >= 1)
        np.testing.assert_allclose(origin, sf.origin(), rtol=0, atol=1e-12)
        self.assertAlmostEqual(h, sf.VOXEL_SIZE, delta=1e-15)
        self.assertEqual(dims, [sf.DIM] * 3)
        self.assertEqual(band, sf.DISTANCE_BAND)
        if margin is not None:
            self.assertEqual(int(margin), sf.MARGIN)

    def test_distances_values(self):
        d64 = sf.signed_distance_grid()
        mask = sf.stored_mask()
        with self.open() as f:
            dist = self.dset(f, "/voxelmap/distances")
        self.assertEqual((dist.dtype.kind, dist.dtype.itemsize), ("f", 4))
        stored = ~np.isnan(dist)
        wrong = np.argwhere(stored != mask)
        self.assertEqual(len(wrong), 0,
                         "NaN pattern differs from |d| <= band*h at [k,j,i] %s (stored=%s, d=%s)"
                         % (wrong[:5].tolist(), [bool(stored[tuple(x)]) for x in wrong[:5]],
                            [float(d64[tuple(x)]) for x in wrong[:5]]))
        self.assertTrue(np.all(np.isfinite(dist[stored])), "stored distances MUST be finite")
        err = np.abs(dist[stored].astype(np.float64) - d64[stored])
        tol = f32_ulp(d64[stored]) + 1e-15
        bad = np.argwhere(err > tol)
        self.assertEqual(len(bad), 0, "distances differ beyond float32 rounding: max err %g"
                         % (float(err.max()) if err.size else 0.0))

    def test_distances_nan_is_quiet(self):
        with self.open() as f:
            dist = self.dset(f, "/voxelmap/distances")
        bits = dist.astype("<f4").view("<u4")
        nan = np.isnan(dist)
        self.assertTrue(np.any(nan))
        self.assertTrue(np.all(bits[nan] & 0x00400000), "a not-stored voxel is a signalling NaN")

    def test_layers_values(self):
        with self.open() as f:
            layers = self.dset(f, "/voxelmap/layers")
        expected = sf.layers_expected()
        diff = np.argwhere(layers.astype(np.int64) != expected.astype(np.int64))
        self.assertEqual(len(diff), 0, "layers differ at [k,j,i] %s: got %s expected %s"
                         % (diff[:5].tolist(), [int(layers[tuple(x)]) for x in diff[:5]],
                            [int(expected[tuple(x)]) for x in diff[:5]]))

    def test_layer_rules_generic(self):
        """§3 layer rules, checked on the file's own data."""
        with self.open() as f:
            layers = self.dset(f, "/voxelmap/layers").astype(np.int64)
            dist = self.dset(f, "/voxelmap/distances").astype(np.float64)
            h = float(self.num_attr(f, "/voxelmap/voxel_size"))
            band = float(self.num_attr(f, "/voxelmap/distance_band"))
        stored = ~np.isnan(dist)
        # where stored: layer == floor(-d/h + 1/2) clamped (tolerate an exact tie broken by f32 rounding)
        x = -dist[stored] / h + 0.5
        want = np.clip(np.floor(x), -32767, 32767)
        tie = np.abs(x - np.round(x)) < 1e-6
        bad = (layers[stored] != want) & ~tie
        self.assertFalse(np.any(bad), "layer != floor(-d/h + 1/2) where d is stored")
        # where not stored: magnitude >= floor(band + 1/2), sign of inside/outside (sphere: d < 0 inside)
        mag = math.floor(band + 0.5)
        self.assertTrue(np.all(np.abs(layers[~stored]) >= mag), "|layer| < floor(band+1/2) outside the band")
        inside = sf.signed_distance_grid() < 0
        ns = ~stored
        self.assertTrue(np.all(layers[ns & inside] >= 1), "inner voxel with layer < 1")
        self.assertTrue(np.all(layers[ns & ~inside] <= -1), "outer voxel with layer > -1")
        # 1.1: |delta| - 1/2 <= |layer| <= |delta| + 1/2 + sqrt(3), delta the exact depth in voxels
        depth = np.abs(sf.signed_distance_grid()[ns]) / h
        self.assertTrue(np.all(np.abs(layers[ns]) >= depth - 0.5 - 1e-9), "a layer nearer the surface than exact")
        self.assertTrue(np.all(np.abs(layers[ns]) <= depth + 0.5 + math.sqrt(3) + 1e-9), "a layer too deep")
        # 6-neighbours differ by at most 1
        for axis in range(3):
            self.assertLessEqual(int(np.max(np.abs(np.diff(layers, axis=axis)))), 1,
                                 "6-neighbour layers differ by more than 1 along array axis %d" % axis)
        # every voxel with |d| <= band*h has its distance stored (analytic d)
        must = np.abs(sf.signed_distance_grid()) <= band * h
        self.assertTrue(np.all(stored[must]), "a voxel with |d| <= band*h has no stored distance")

    def test_index_order_zyx(self):
        """Element [k, j, i] is voxel (i, j, k): check with an off-centre probe voxel."""
        with self.open() as f:
            dist = self.dset(f, "/voxelmap/distances").astype(np.float64)
            o = self.num_attr(f, "/voxelmap/origin")
            h = float(self.num_attr(f, "/voxelmap/voxel_size"))
        c = sf.center()
        for (i, j, k) in [(3, 7, 10), (10, 3, 7), (7, 10, 3), (2, 7, 7)]:
            v = dist[k, j, i]
            if np.isnan(v):
                continue
            p = o + h * np.array([i, j, k], dtype=np.float64)
            self.assertAlmostEqual(v, np.linalg.norm(p - c) - sf.RADIUS, delta=1e-6,
                                   msg="voxel (i,j,k)=(%d,%d,%d)" % (i, j, k))

    # -- pointshell ------------------------------------------------------------------------------------------

    def test_points(self):
        with self.open() as f:
            pts = self.dset(f, "/pointshell/points")
        self.assertTrue(np.all(np.isfinite(pts)))
        np.testing.assert_allclose(pts, sf.points_expected(), rtol=0, atol=1e-12)

    def test_normals(self):
        with self.open() as f:
            nrm = self.dset(f, "/pointshell/normals")
        self.assertEqual((nrm.dtype.kind, nrm.dtype.itemsize), ("f", 4))
        np.testing.assert_allclose(nrm.astype(np.float64), sf.normals_expected().astype(np.float64),
                                   rtol=0, atol=1e-6)
        length = np.linalg.norm(nrm.astype(np.float64), axis=1)
        self.assertTrue(np.all(np.abs(length - 1) <= 1e-3), "normal not unit within 1e-3")

    def test_normals_point_inward(self):
        with self.open() as f:
            nrm = self.dset(f, "/pointshell/normals").astype(np.float64)
            pts = self.dset(f, "/pointshell/points")
        self.assertTrue(np.all(np.sum(nrm * (sf.center() - pts), axis=1) > 0), "a normal points outward")

    def test_tree_arrays(self):
        with self.open() as f:
            cb = self.dset(f, "/pointshell/child_begin")
            cc = self.dset(f, "/pointshell/child_count")
            lo = self.dset(f, "/pointshell/level_offsets")
        np.testing.assert_array_equal(cb, sf.child_begin_expected())
        np.testing.assert_array_equal(cc, sf.child_count_expected())
        np.testing.assert_array_equal(lo, sf.level_offsets_expected())
        self.assertEqual(lo.tolist(), [0, 1, 5, 21, 85, 200])

    def test_tree_generic_invariants(self):
        """§4: breadth-first levels, children ranges in order covering the next level, every point once."""
        with self.open() as f:
            n = f["/pointshell/points"].shape[0]
            cb = self.dset(f, "/pointshell/child_begin").astype(np.int64)
            cc = self.dset(f, "/pointshell/child_count").astype(np.int64)
            lo = self.dset(f, "/pointshell/level_offsets").astype(np.int64).tolist()
        self.assertGreaterEqual(n, 1)
        self.assertGreaterEqual(len(lo), 2, "L >= 1 levels")
        self.assertEqual(lo[0], 0)
        self.assertEqual(lo[1], 1)
        self.assertTrue(all(a < b for a, b in zip(lo, lo[1:])), "level_offsets not strictly increasing")
        self.assertEqual(lo[-1], n)
        seen = np.zeros(n, dtype=np.int64)
        seen[0] += 1
        levels = len(lo) - 1
        for l in range(levels):
            nxt = lo[l + 1]
            for node in range(lo[l], lo[l + 1]):
                if cc[node] == 0:
                    self.assertLessEqual(cb[node], n, "leaf %d: child_begin > N" % node)
                    continue
                self.assertLess(l, levels - 1, "node %d on the last level has children" % node)
                self.assertEqual(cb[node], nxt, "node %d: children not contiguous in node order" % node)
                self.assertLessEqual(cb[node] + cc[node], lo[l + 2],
                                     "node %d: children beyond level %d" % (node, l + 1))
                seen[cb[node]:cb[node] + cc[node]] += 1
                nxt += cc[node]
            if l + 1 < levels:
                self.assertEqual(nxt, lo[l + 2], "children of level %d do not cover level %d" % (l, l + 1))
        self.assertTrue(np.all(seen == 1), "points not reached exactly once: %s"
                        % np.argwhere(seen != 1)[:10].ravel().tolist())

    def test_sphere_centers_and_radii(self):
        with self.open() as f:
            centers = self.dset(f, "/pointshell/sphere_centers")
            radii = self.dset(f, "/pointshell/sphere_radii")
        self.assertTrue(np.all(np.isfinite(centers)) and np.all(np.isfinite(radii)))
        self.assertTrue(np.all(radii >= 0))
        np.testing.assert_allclose(centers, sf.sphere_centers_expected(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(radii, sf.sphere_radii_expected(), rtol=0, atol=1e-9)

    def test_spheres_enclose_descendants(self):
        with self.open() as f:
            pts = self.dset(f, "/pointshell/points")
            centers = self.dset(f, "/pointshell/sphere_centers")
            radii = self.dset(f, "/pointshell/sphere_radii")
            cb = self.dset(f, "/pointshell/child_begin").astype(np.int64)
            cc = self.dset(f, "/pointshell/child_count").astype(np.int64)
        for node in range(pts.shape[0]):
            members = sf.subtree(node, cb, cc)
            dist = np.linalg.norm(pts[members] - centers[node], axis=1)
            self.assertLessEqual(float(dist.max()), radii[node] + 1e-12,
                                 "sphere of node %d does not enclose its subtree" % node)

    def test_optional_pointshell_attributes(self):
        with self.open() as f:
            g = f["/pointshell"]
            if "point_spacing" in g.attrs:
                ps = float(g.attrs["point_spacing"])
                self.assertTrue(math.isfinite(ps) and ps > 0, "point_spacing %r" % ps)
            if "branching" in g.attrs:
                self.assertEqual(int(g.attrs["branching"]), sf.BRANCHING)

    # -- mass properties ---------------------------------------------------------------------------------------

    def test_mass_properties(self):
        with self.open() as f:
            vol = float(self.num_attr(f, "/mass_properties/volume"))
            com = self.num_attr(f, "/mass_properties/center_of_mass").astype(np.float64)
            inertia = self.num_attr(f, "/mass_properties/inertia").astype(np.float64)
        self.assertTrue(math.isfinite(vol) and vol > 0)
        self.assertTrue(np.all(np.isfinite(com)) and np.all(np.isfinite(inertia)))
        np.testing.assert_array_equal(inertia, inertia.T, "inertia not symmetric")
        v_e = sf.volume_expected()
        self.assertLessEqual(abs(vol - v_e), 1e-12 * v_e, "volume %r expected %r" % (vol, v_e))
        np.testing.assert_allclose(com, sf.center(), rtol=1e-12, atol=1e-12 * np.linalg.norm(sf.center()))
        i_e = sf.inertia_expected()
        np.testing.assert_allclose(inertia, i_e, rtol=1e-12, atol=1e-12 * i_e[0, 0])

    # -- provenance --------------------------------------------------------------------------------------------

    def test_provenance(self):
        with self.open() as f:
            p = {name: self.text_attr(f, "/provenance/" + name)
                 for name in ("generator", "generator_version", "source_file", "source_sha256",
                              "build_parameters", "dependency_versions", "build_warnings")}
            created = f["/provenance"].attrs.get("created_utc")
        self.assertEqual(p["generator"], sf.GENERATOR)
        self.assertNotEqual(p["generator_version"], "")
        self.assertEqual(p["source_file"], "")
        self.assertEqual(p["source_sha256"], "")
        bp = json.loads(p["build_parameters"])
        self.assertIsInstance(bp, dict)
        for k, v in sf.build_parameters_expected().items():
            self.assertEqual(bp.get(k), v, "build_parameters[%r]" % k)
        dv = json.loads(p["dependency_versions"])
        self.assertIsInstance(dv, dict)
        for k, v in dv.items():
            self.assertIsInstance(v, str, "dependency_versions[%r] must be a version string" % k)
        bw = json.loads(p["build_warnings"])
        self.assertEqual(bw, [])
        if created is not None:
            self.assertRegex(as_text(created), r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(\.\d+)?Z$")

    # -- h5dump --------------------------------------------------------------------------------------------------

    @ss.requires_h5dump
    def test_h5dump_lists_every_required_object(self):
        proc = ss.run([ss.H5DUMP, "-H", self.path])
        self.assertEqual(proc.returncode, 0, describe(proc))
        objects = ss.parse_h5dump(proc.stdout)
        kinds = {"attr": "ATTRIBUTE", "dset": "DATASET", "group": "GROUP"}
        for path, kind, code, shape, required in sf.SPEC_OBJECTS:
            if not required:
                continue
            self.assertIn(path, objects, "h5dump -H does not list %s" % path)
            self.assertEqual(objects[path]["kind"], kinds[kind], path)
            token = '%s "%s"' % (kinds[kind], sf.split_path(path)[1])
            self.assertIn(token, proc.stdout)
            if code is None:
                continue
            if code == "str":
                self.assertEqual(objects[path]["type"], "H5T_STRING", path)
                self.assertNotIn("STRSIZE H5T_VARIABLE;", objects[path]["type_lines"], path)
                self.assertIn("STRPAD H5T_STR_NULLTERM;", objects[path]["type_lines"], path)
                self.assertIn("CSET H5T_CSET_UTF8;", objects[path]["type_lines"], path)
            else:
                self.assertEqual(objects[path]["type"], sf.H5DUMP_TYPES[code], path)
            if shape == "scalar":
                self.assertEqual(objects[path]["space"], "SCALAR", path)
            else:
                self.assertTrue(objects[path]["space"].startswith("SIMPLE"), path)


class TestH5pyFixtureSelfCheck(SpecFileChecks, unittest.TestCase):
    """The checks above, run on the h5py-written fixture: proves they accept a conforming file."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-selfcheck-")
        cls.path = sf.write_fixture_h5py(os.path.join(cls.tmp, "sphere_h5py.vox.h5"))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)


@ss.requires_writer
class TestCppToPython(SpecFileChecks, unittest.TestCase):
    """The C++ sample writer's file, read with h5py."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-cpp2py-")
        cls.path = os.path.join(cls.tmp, "sphere_cpp.vox.h5")
        proc = ss.run([ss.SAMPLE_WRITER, cls.path])
        if proc.returncode != 0 or not os.path.isfile(cls.path):
            raise AssertionError("sample writer failed\n" + describe(proc))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @ss.requires_bin
    def test_voxfmt_validates_writer_output(self):
        proc = ss.run([ss.VOXFMT_BIN, "validate", self.path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        entry = ss.check_validate_json(self, proc, [self.path])[self.path]
        self.assertTrue(entry["valid"])
        self.assertEqual([i for i in entry["issues"] if i["severity"] == "error"], [])


@ss.requires_bin
class TestPythonToCpp(unittest.TestCase):
    """Files written with h5py alone, read by `voxfmt validate` and `voxfmt inspect`."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-py2cpp-")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def write(self, name, **kw):
        return sf.write_fixture_h5py(os.path.join(self.tmp, name + ".vox.h5"), **kw)

    def validate(self, *paths):
        proc = ss.run([ss.VOXFMT_BIN, "validate"] + list(paths) + ["--json"])
        self.assertGreaterEqual(proc.returncode, 0, "validate crashed (signal)\n" + describe(proc))
        return proc, ss.check_validate_json(self, proc, list(paths))

    def assert_valid(self, path):
        proc, entries = self.validate(path)
        self.assertEqual(proc.returncode, 0, describe(proc))
        entry = entries[path]
        self.assertTrue(entry["valid"], describe(proc))
        errors = [i for i in entry["issues"] if i["severity"] == "error"]
        self.assertEqual(errors, [], describe(proc))
        return entry

    def inspect(self, path):
        proc = ss.run([ss.VOXFMT_BIN, "inspect", path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        return ss.parse_json_stdout(self, proc)

    def close(self, got, want, what, rel=1e-9):
        got = np.asarray(got, dtype=np.float64)
        want = np.asarray(want, dtype=np.float64)
        self.assertEqual(got.shape, want.shape, what)
        tol = rel * np.maximum(np.abs(want), 1.0)
        self.assertTrue(np.all(np.abs(got - want) <= tol), "%s: %r != %r" % (what, got.tolist(), want.tolist()))

    def check_inspect(self, path, format_version=(1, 1)):
        js = self.inspect(path)
        self.assertTrue(ss.same_file_name(js["file"], path), js["file"])
        self.assertEqual(js["file_size_bytes"], os.path.getsize(path))
        self.assertEqual(js["format_version"], list(format_version))
        self.assertEqual(js["units"], "m")
        self.assertEqual(js["frame"], "right-handed")
        self.assertEqual(js["up_axis"], "+Y")
        bmin, bmax = sf.bounds_expected()
        self.close(js["bounds_min"], bmin, "bounds_min")
        self.close(js["bounds_max"], bmax, "bounds_max")
        vm = js["voxelmap"]
        self.assertEqual(vm["dims"], [sf.DIM] * 3)
        self.close(vm["voxel_size"], sf.VOXEL_SIZE, "voxel_size")
        self.close(vm["origin"], sf.origin(), "origin")
        self.close(vm["distance_band"], sf.DISTANCE_BAND, "distance_band")
        self.assertEqual(vm["stored_distances"], int(np.count_nonzero(sf.stored_mask())))
        self.assertEqual(vm["layer_min"], int(sf.layers_expected().min()))
        self.assertEqual(vm["layer_max"], int(sf.layers_expected().max()))
        self.assertIsInstance(vm["memory_bytes"], int)
        self.assertGreater(vm["memory_bytes"], 0)
        ps = js["pointshell"]
        self.assertEqual(ps["points"], sf.N_POINTS)
        self.assertEqual(ps["levels"], 5)
        self.assertEqual(ps["points_per_level"], [1, 4, 16, 64, 115])
        self.assertEqual(ps["points_per_level"], sf.points_per_level_expected())
        self.assertEqual(ps["tree_depth"], 4)
        mp = js["mass_properties"]
        self.close(mp["volume"], sf.volume_expected(), "volume")
        self.close(mp["center_of_mass"], sf.center(), "center_of_mass")
        self.close(np.asarray(mp["inertia"]) / sf.inertia_expected()[0, 0],
                   sf.inertia_expected() / sf.inertia_expected()[0, 0], "inertia")
        pv = js["provenance"]
        vals = sf.fixture_values()
        for key in ("generator", "generator_version", "source_file", "source_sha256"):
            self.assertEqual(pv[key], vals["/provenance/" + key], "provenance.%s" % key)
        self.assertEqual(pv["build_parameters"], json.loads(vals["/provenance/build_parameters"]))
        self.assertEqual(pv["dependency_versions"], json.loads(vals["/provenance/dependency_versions"]))
        self.assertEqual(pv["build_warnings"], [])
        self.assertIsInstance(js["warnings"], list)
        for w in js["warnings"]:
            self.assertIsInstance(w, str)
        return js

    # -- the conforming fixture ---------------------------------------------------------------------------

    def test_validate_default_fixture(self):
        self.assert_valid(self.write("default"))

    def test_default_fixture_has_no_warnings(self):
        entry = self.assert_valid(self.write("default_w"))
        self.assertEqual([i for i in entry["issues"] if i["severity"] == "warning"], [],
                         "a conforming 1.0 file violates no SHOULD")

    def test_inspect_default_fixture(self):
        self.check_inspect(self.write("default_i"))

    def test_validate_two_good_files(self):
        a, b = self.write("good_a"), self.write("good_b")
        proc, entries = self.validate(a, b)
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertTrue(entries[a]["valid"] and entries[b]["valid"])

    # -- variants readers must accept -----------------------------------------------------------------------

    def _accept(self, name, format_version=(1, 1), **kw):
        path = self.write(name, format_version=format_version, **kw)
        entry = self.assert_valid(path)
        self.check_inspect(path, format_version=format_version)
        return entry

    def test_fixed_length_strings_null_terminated(self):
        self._accept("fixed_nullterm", string_mode="fixed_nullterm")

    def test_variable_length_strings_of_older_files(self):
        self._accept("vlen", string_mode="vlen")

    def test_fixed_length_strings_null_padded(self):
        self._accept("fixed_nullpad", string_mode="fixed_nullpad")

    def test_fixed_length_strings_null_padded_no_terminator(self):
        self._accept("fixed_nullpad_exact", string_mode="fixed_nullpad_exact")

    def test_big_endian_numeric_dtypes(self):
        path = self.write("big_endian", byteorder=">")
        with h5py.File(path, "r") as f:  # the variant really is big-endian
            self.assertEqual(f["/voxelmap/layers"].dtype.str, ">i2")
            self.assertEqual(f["/voxelmap"].attrs.get_id("dims").dtype.str, ">u4")
        self.assert_valid(path)
        self.check_inspect(path)

    def test_contiguous_grids(self):
        path = self.write("contiguous", grid_layout="contiguous")
        with h5py.File(path, "r") as f:
            self.assertIsNone(f["/voxelmap/layers"].chunks)
        self.assert_valid(path)
        self.check_inspect(path)

    def test_chunked_with_fletcher32(self):
        self._accept("fletcher32", fletcher32=True)

    def test_chunked_without_compression(self):
        self._accept("chunked_plain", shuffle=False, compression=None)

    def test_optional_objects_absent(self):
        self._accept("no_optional", optional=False)

    def test_older_minor_version(self):
        """1.0 files stay valid and readable (spec CHANGELOG 1.1)."""
        entry = self._accept("minor0", format_version=(1, 0))
        self.assertFalse([i for i in entry["issues"] if i["severity"] == "error"])

    def test_newer_minor_version(self):
        entry = self._accept("minor7", format_version=(1, 7))
        codes = [(i["code"], i["severity"]) for i in entry["issues"]]
        self.assertIn(("VERSION_NEWER_MINOR", "warning"), codes)

    def test_newer_minor_inspect_warns(self):
        """§7 SHOULD: a reader warns that newer data may be ignored."""
        js = self.inspect(self.write("minor7_w", format_version=(1, 7)))
        self.assertEqual(js["format_version"], [1, 7])
        self.assertTrue(js["warnings"], "inspect reports no warning for format_version [1, 7]")

    def test_unknown_objects_ignored(self):
        entry = self._accept("extra", extra_objects=True)
        for issue in entry["issues"]:
            if issue["code"] == "UNKNOWN_OBJECT":
                self.assertEqual(issue["severity"], "info")

    def test_newer_minor_with_unknown_objects(self):
        entry = self._accept("minor7_extra", format_version=(1, 7), extra_objects=True)
        self.assertIn("VERSION_NEWER_MINOR", [i["code"] for i in entry["issues"]])

    def test_all_variants_combined(self):
        self._accept("combined", string_mode="fixed_nullpad", byteorder=">", grid_layout="contiguous",
                     extra_objects=True)


if __name__ == "__main__":
    unittest.main()
