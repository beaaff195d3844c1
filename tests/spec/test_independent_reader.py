"""Independent-reader tests: written from spec/voxfmt-format.md alone, never from the C++ sources.

  * C++ -> Python: the C++ sample writer's file (format 2.0) is read with h5py and checked against the spec
    tables (existence, kind, exact little-endian dtype, shape, the 2.0 voxelmap attributes), the generic rules of
    the spec, and the analytic sphere fixture (spec_fixture.py): its voxelmap is decoded with the spec's decoder
    (spec_support.decode_voxelmap: brick table, 16-bit codes, trilinear lattice) and compared voxel by voxel with
    the exact signed distance.
  * Python -> C++: format 2.0 files written with h5py alone (spec_fixture.write_fixture_h5py), including the
    variants the spec says readers must accept, are fed to `voxfmt validate --level full --json` and
    `voxfmt inspect --json`. Legacy 1.x files (dense layers and distances, §3.4), which 2.0 readers must still
    read, get the same treatment (TestLegacyPythonToCpp); `voxfmt upgrade` of such files must write what §3.4
    says a 2.0 reader sees in them (TestLegacyUpgrade, skipped where voxfmt has no upgrade subcommand).
  * h5dump -H of the C++-written file lists every required object with the spec's HDF5 type.
  * Self-checks run every C++ -> Python check on the h5py-written fixtures (2.0 at the fixture's grid and at a
    finer grid with coarse bricks, and the legacy 1.1 file), so the checks themselves are known to accept a
    conforming file.

Run:  VOXFMT_BIN=.../voxfmt VOXFMT_SAMPLE_WRITER=.../write_sphere_asset /usr/bin/python3 -m unittest -v
"""

import json
import math
import os
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
    "i32": h5py.h5t.STD_I32LE,
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


def first(mask, limit=5):
    """The first [k, j, i] indices where mask is true, for messages."""
    return np.argwhere(mask)[:limit].tolist()


class SpecFileChecks(object):
    """Checks of one asset file against the spec and the sphere fixture, whatever its voxelmap's format.
    Subclasses set cls.path, and cls.legacy / cls.format_version / cls.grid where they differ."""

    path = None
    legacy = False  # True: a 1.x file (§3.4 dense grids) instead of 2.0 bricks
    format_version = (2, 0)
    grid = sf.FIXTURE_GRID

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

    def objects(self):
        return sf.spec_objects(self.legacy)

    # -- structure ----------------------------------------------------------------------------------------

    def test_required_objects_exist_with_kind(self):
        with self.open() as f:
            for path, kind, _code, _shape, required in self.objects():
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

    def test_no_objects_of_the_other_voxelmap_format(self):
        """§3.4: a 1.x file has no brick or lattice objects; a 2.0 file replaced layers/distances by them."""
        other = ([p for p in sf.VOXELMAP_2_0_PATHS] if self.legacy
                 else [o[0] for o in sf.LEGACY_VOXELMAP_OBJECTS])
        with self.open() as f:
            g = f["/voxelmap"]
            for path in other:
                name = sf.split_path(path)[1]
                self.assertFalse(name in g or name in g.attrs, "%s in a %d.%d file" % ((path,) + self.format_version))

    def test_numeric_objects_exact_little_endian_dtype_and_shape(self):
        with self.open() as f:
            n = f["/pointshell/points"].shape[0]
            levels = f["/pointshell/level_offsets"].shape[0] - 1
            w, h, d = (int(x) for x in f["/voxelmap"].attrs["dims"])
            v = f["/voxelmap/brick_values"].shape[0] if "brick_values" in f["/voxelmap"] else None
            for path, kind, code, shape, _required in self.objects():
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
                want = sf.resolve_shape(shape, n=n, dims=(w, h, d), levels=levels, value_bricks=v)
                if want == ():
                    self.assertEqual(space.get_simple_extent_type(), h5py.h5s.SCALAR,
                                     "%s must have a scalar dataspace" % path)
                else:
                    self.assertEqual(space.get_simple_extent_type(), h5py.h5s.SIMPLE, path)
                    self.assertEqual(tuple(space.shape), want, "%s shape" % path)

    def test_strings_are_fixed_length_utf8_scalars(self):
        """§1: writers MUST write fixed-length, null-terminated, UTF-8 scalar strings."""
        with self.open() as f:
            for path, kind, code, _shape, _required in self.objects():
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
            self.assertEqual(self.num_attr(f, "/format_version").tolist(), list(self.format_version))
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

    # -- voxelmap attributes common to 1.x and 2.0 -----------------------------------------------------------

    def test_voxelmap_attributes(self):
        with self.open() as f:
            origin = self.num_attr(f, "/voxelmap/origin")
            h = float(self.num_attr(f, "/voxelmap/voxel_size"))
            dims = self.num_attr(f, "/voxelmap/dims").tolist()
            order = self.text_attr(f, "/voxelmap/index_order")
            band = float(self.num_attr(f, "/voxelmap/distance_band"))
            margin = f["/voxelmap"].attrs.get("margin")
            shell = f["/voxelmap"].attrs.get("shell_thickness")
        self.assertTrue(np.all(np.isfinite(origin)))
        self.assertTrue(math.isfinite(h) and 1e-9 <= h <= 1e6, "voxel_size %r outside [1e-9, 1e6]" % h)
        self.assertTrue(all(x >= 1 for x in dims))
        if self.legacy:  # §3.4: W*H*D <= 2^31 - 1
            self.assertLessEqual(dims[0] * dims[1] * dims[2], 2 ** 31 - 1)
        else:  # §3.2: (BW + 1)(BH + 1)(BD + 1) <= 2^31 - 1
            bw, bh, bd = sf.brick_counts_of(dims)
            self.assertLessEqual((bw + 1) * (bh + 1) * (bd + 1), 2 ** 31 - 1)
        self.assertEqual(order, "zyx")
        self.assertTrue(math.isfinite(band) and 1 <= band <= 32767)
        np.testing.assert_allclose(origin, sf.origin(self.grid), rtol=0, atol=1e-12)
        self.assertAlmostEqual(h, self.grid.voxel_size, delta=1e-15)
        self.assertEqual(dims, sf.dims(self.grid).tolist())
        self.assertEqual(band, self.grid.band)
        if margin is not None:
            self.assertEqual(int(margin), self.grid.margin)
        self.assertIsNone(shell, "the sphere is a solid: no shell_thickness (§3.1 shell mode)")

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
        for path, kind, code, shape, required in self.objects():
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


class VoxelmapChecks(SpecFileChecks):
    """The 2.0 voxelmap (§3.1-§3.3) of the sphere fixture, decoded with spec_support.decode_voxelmap and compared
    with the exact signed distance d = |p - c| - r."""

    @classmethod
    def decoded(cls):
        if getattr(cls, "_decoded", None) is None or cls._decoded_path != cls.path:
            cls._decoded = ss.decode_voxelmap(cls.path)
            cls._decoded_path = cls.path
        return cls._decoded

    def exact(self):
        return sf.signed_distance_grid(self.grid)

    # -- structure ------------------------------------------------------------------------------------------

    def test_fixture_shapes(self):
        bw, bh, bd = sf.brick_counts_of(sf.dims(self.grid))
        with self.open() as f:
            self.assertEqual(f["/pointshell/points"].shape, (sf.N_POINTS, 3))
            self.assertEqual(f["/pointshell/level_offsets"].shape, (len(sf.level_offsets_expected()),))
            self.assertEqual(f["/voxelmap/bricks"].shape, (bd, bh, bw))
            self.assertEqual(f["/voxelmap/lattice"].shape, (bd + 1, bh + 1, bw + 1))
            table = f["/voxelmap/bricks"][()]
            self.assertEqual(f["/voxelmap/brick_values"].shape, (int(np.count_nonzero(table >= 0)), 512),
                             "brick_values must have one row per value brick (V = the number of value bricks)")

    def test_should_voxelmap_datasets_chunked_shuffle_deflate(self):
        """§1 SHOULD: the voxelmap's datasets chunked with shuffle and deflate (`voxfmt build`: 32^3 entries of
        bricks and lattice, 64 bricks of brick_values per chunk; no chunk here may be larger)."""
        with self.open() as f:
            for p in sf.VOXELMAP_2_0_DATASETS:
                ds = f[p]
                self.assertIsNotNone(ds.chunks, "%s is not chunked" % p)
                if p == "/voxelmap/brick_values":
                    self.assertLessEqual(ds.chunks[0], 64, "%s chunk %r" % (p, ds.chunks))
                else:
                    self.assertLessEqual(int(np.prod(ds.chunks)), 32 ** 3, "%s chunk %r" % (p, ds.chunks))
                self.assertTrue(ds.shuffle, "%s: no shuffle filter" % p)
                self.assertEqual(ds.compression, "gzip", "%s: no deflate filter" % p)

    def test_voxelmap_2_0_attributes(self):
        """§3.2: brick_edge 8; quanta finite, > 0 and coarse enough that 16383 steps reach the band; lattice_error
        finite with eps0 >= 0 and 0 <= eps1 <= 1."""
        with self.open() as f:
            edge = self.num_attr(f, "/voxelmap/brick_edge")
            dq = float(self.num_attr(f, "/voxelmap/distance_quantum"))
            eq = float(self.num_attr(f, "/voxelmap/estimate_quantum"))
            err = self.num_attr(f, "/voxelmap/lattice_error").astype(np.float64)
            h = float(self.num_attr(f, "/voxelmap/voxel_size"))
            band = float(self.num_attr(f, "/voxelmap/distance_band"))
        self.assertEqual(int(edge), 8)
        for name, q in (("distance_quantum", dq), ("estimate_quantum", eq)):
            self.assertTrue(math.isfinite(q) and q > 0, "%s %r" % (name, q))
            self.assertGreaterEqual(16383 * q, band * h * (1 - 1e-12), "%s %r too small for the band" % (name, q))
        self.assertEqual(err.shape, (2,))
        self.assertTrue(np.all(np.isfinite(err)), "lattice_error %r" % err.tolist())
        self.assertGreaterEqual(err[0], 0.0)
        self.assertTrue(0.0 <= err[1] <= 1.0, "lattice_error eps1 %r" % err[1])

    def test_brick_table_entries_and_rows(self):
        """§3.2: every entry is -1, -2 or a row of brick_values ("nothing else"), and the V rows are the V value
        bricks: each row belongs to exactly one brick."""
        with self.open() as f:
            table = f["/voxelmap/bricks"][()].astype(np.int64)
            v = f["/voxelmap/brick_values"].shape[0]
        self.assertFalse(np.any((table < -2) | (table >= v)), "entries outside {-2, -1, 0..V-1}: %s"
                         % sorted(set(table[(table < -2) | (table >= v)].tolist())))
        rows = np.sort(table[table >= 0])
        np.testing.assert_array_equal(rows, np.arange(v), "value brick rows not a permutation of 0..V-1")

    def test_codes_past_the_grid_are_zero(self):
        """§3.2: codes at positions past the grid are ignored; writers write 0."""
        vm = self.decoded()
        w, h, d = vm.dims
        e = ss.BRICK_EDGE
        for (bk, bj, bi), n in np.ndenumerate(vm.bricks):
            if n < 0:
                continue
            codes = vm.codes[n].reshape(e, e, e)
            outside = np.ones((e, e, e), dtype=bool)
            outside[:max(0, min(e, d - e * bk)), :max(0, min(e, h - e * bj)), :max(0, min(e, w - e * bi))] = False
            self.assertFalse(np.any(codes[outside] != 0), "brick (%d, %d, %d): a code past the grid is not 0"
                             % (bi, bj, bk))

    # -- values ---------------------------------------------------------------------------------------------

    def test_stored_distances_within_half_a_quantum(self):
        """§3.1: a stored distance is the exact d at the voxel centre rounded to a multiple of distance_quantum."""
        vm = self.decoded()
        d = self.exact()
        err = np.abs(vm.values - d)
        tol = vm.distance_quantum / 2 * (1 + 1e-9) + 1e-15
        bad = vm.stored & (err > tol)
        self.assertFalse(np.any(bad), "stored distances off by more than distance_quantum/2 = %g at [k,j,i] %s: "
                         "max error %g" % (vm.distance_quantum / 2, first(bad), float(err[vm.stored].max())))
        # and really a multiple of the quantum: the code's integer
        self.assertTrue(np.allclose(vm.values[vm.stored] / vm.distance_quantum,
                                    np.rint(vm.values[vm.stored] / vm.distance_quantum), rtol=0, atol=1e-6))

    def test_stored_exactly_within_the_band(self):
        """The fixture stores a distance exactly where |d| <= band*h (both writers; the spec demands at least
        |d| <= (band - 1/2) h and at most |d| <= band*h). Voxels within 1e-9 voxel of the band edge, where the
        exact d and its floating-point evaluation may disagree, may go either way."""
        vm = self.decoded()
        d = self.exact()
        edge = self.grid.band * self.grid.voxel_size
        tie = np.abs(np.abs(d) - edge) <= 1e-9 * self.grid.voxel_size
        within = np.abs(d) <= edge
        missing = within & ~vm.stored & ~tie
        extra = vm.stored & ~within & ~tie
        self.assertFalse(np.any(missing), "no stored distance where |d| <= band*h: [k,j,i] %s" % first(missing))
        self.assertFalse(np.any(extra), "a stored distance where |d| > band*h: [k,j,i] %s" % first(extra))
        must = np.abs(d) <= (self.grid.band - 0.5) * self.grid.voxel_size
        self.assertTrue(np.all(vm.stored[must]), "§3.1: |d| <= (band - 1/2) h MUST be stored")

    def test_signs_everywhere(self):
        """§3.1: every voxel's value has the sign of its side of the surface, inside negative (a stored distance
        within half a quantum of the surface may have either)."""
        vm = self.decoded()
        d = self.exact()
        near = np.abs(d) <= vm.distance_quantum / 2
        wrong = ~near & (np.sign(vm.values) != np.sign(d))
        self.assertFalse(np.any(wrong), "wrong sign at [k,j,i] %s: values %s, exact d %s"
                         % (first(wrong), vm.values[wrong][:5].tolist(), d[wrong][:5].tolist()))

    def test_lattice_within_lattice_error(self):
        """§3.3: u <= l <= (1 + eps1) u + eps0 h at every lattice point, u the exact unsigned distance at voxel
        (min(8a, W-1), min(8b, H-1), min(8c, D-1)). "Never below u" is checked to 4 float64 ulps of u, the
        rounding of this test's own evaluation of u."""
        vm = self.decoded()
        u = sf.lattice_exact(self.grid)
        lat = vm.lattice
        self.assertTrue(np.all(np.isfinite(lat)) and np.all(lat >= 0), "lattice values must be finite and >= 0")
        eps0, eps1 = vm.lattice_error
        below = lat < u - 4 * np.spacing(u)
        self.assertFalse(np.any(below), "lattice below the exact distance at [c,b,a] %s: %s < %s"
                         % (first(below), lat[below][:5].tolist(), u[below][:5].tolist()))
        above = lat > (1 + eps1) * u + eps0 * vm.voxel_size
        self.assertFalse(np.any(above), "lattice beyond lattice_error %r at [c,b,a] %s"
                         % (vm.lattice_error, first(above)))

    def test_lattice_exact_but_for_float_rounding(self):
        """Both writers of the fixture compute the sphere's lattice exactly: within 2 float32 steps of u."""
        vm = self.decoded()
        u = sf.lattice_exact(self.grid)
        off = np.abs(vm.lattice - u) > 2 * f32_ulp(u)
        self.assertFalse(np.any(off), "lattice not the exact distance at [c,b,a] %s" % first(off))

    def test_estimate_codes_follow_the_files_rule(self):
        """§3.2: an even code is the estimate of §3.1, never 0. 2.2: settled, exactly (§3.1's least paths);
        2.0, 2.1: sign * max(L, (band - 1/2) h), rounded to the nearest estimate_quantum, L interpolated trilinearly
        with §3.3's weights."""
        vm = self.decoded()
        est = vm.value_brick & ~vm.stored
        self.assertTrue(np.any(est), "the fixture has value-brick voxels without a stored distance")
        zero = est & (vm.code >> 1 == 0)
        self.assertFalse(np.any(zero), "an estimate code is 0 at [k,j,i] %s" % first(zero))
        sign = np.where(self.exact() < 0, -1.0, 1.0)
        if vm.format_version >= (2, 2):
            want = sign * ss.settled_estimate_steps(vm) * vm.estimate_quantum
            bad = est & (vm.values != want)
            self.assertFalse(np.any(bad), "coded estimates are not the settled ones at [k,j,i] %s: coded %s, settled %s"
                             % (first(bad), vm.values[bad][:5].tolist(), want[bad][:5].tolist()))
            return
        err = np.abs(vm.values - sign * vm.lattice_estimate)
        tol = vm.estimate_quantum / 2 * (1 + 1e-9) + 1e-12 * vm.voxel_size
        bad = est & (err > tol)
        self.assertFalse(np.any(bad), "coded estimates differ from the lattice's by more than estimate_quantum/2 "
                         "at [k,j,i] %s: coded %s, lattice %s" % (first(bad), vm.values[bad][:5].tolist(),
                                                                 (sign * vm.lattice_estimate)[bad][:5].tolist()))

    def test_estimates_outside_the_band(self):
        """§3.1: a voxel without a stored distance is at least (band - 1/2) h from the surface, and so is its
        estimate; stored distances lie within the band (by at most half a quantum)."""
        vm = self.decoded()
        d = self.exact()
        h, band = vm.voxel_size, vm.distance_band
        ns = ~vm.stored
        self.assertTrue(np.all(np.abs(d[ns]) >= (band - 0.5) * h - 1e-12), "an unstored voxel inside band - 1/2")
        self.assertTrue(np.all(np.abs(vm.values[ns]) >= (band - 0.5) * h - vm.estimate_quantum / 2 - 1e-12),
                        "an estimate nearer than (band - 1/2) h")
        self.assertTrue(np.all(np.abs(vm.values[vm.stored]) <= band * h + vm.distance_quantum / 2 + 1e-12),
                        "a stored distance beyond the band")

    def test_estimate_accuracy_bound(self):
        """§3.1, accuracy of estimates, with m = |estimate|, e = estimate_quantum, q = distance_quantum. Coarse
        bricks and 2.0/2.1 value bricks: u <= m + B h + e/2 and u >= (m - eps0 h) / (1 + eps1) - B h - e/2, B the
        weighted distance to the cell's lattice points. 2.2 value bricks: u <= m + q/2 (but for the lattice's
        float rounding, 10^-6 u) and u >= (m - eps0 h - 5 e) / (1 + eps1) - 8 sqrt(3) h."""
        vm = self.decoded()
        u = np.abs(self.exact())
        m = np.abs(vm.values)
        h, e = vm.voxel_size, vm.estimate_quantum
        eps0, eps1 = vm.lattice_error
        ns = ~vm.stored
        slack = 1e-12 * h
        over = ns & (u > m + vm.spread * h + e / 2 + slack)
        under = ns & (u < (m - eps0 * h) / (1 + eps1) - vm.spread * h - e / 2 - slack)
        if vm.format_version >= (2, 2):
            settled = ns & vm.value_brick
            over = (over & ~settled) | (settled & (u > m + vm.distance_quantum / 2 + 1e-6 * u + slack))
            under = (under & ~settled) | (settled & (u < (m - eps0 * h - 5 * e) / (1 + eps1) - 8 * np.sqrt(3) * h
                                                     - slack))
        self.assertFalse(np.any(over), "estimate too small for the exact distance at [k,j,i] %s" % first(over))
        self.assertFalse(np.any(under), "estimate too large for the exact distance at [k,j,i] %s" % first(under))

    def test_brick_classification(self):
        """§3.2: a brick with a stored distance (here: with a voxel within (band - 1/2) h, which MUST be stored),
        or with voxels on both sides, is a value brick; a coarse brick's voxels all lie on its side (-2 inside)."""
        vm = self.decoded()
        d = self.exact()
        e = ss.BRICK_EDGE
        must_store = np.abs(d) <= (vm.distance_band - 0.5) * vm.voxel_size
        for (bk, bj, bi), n in np.ndenumerate(vm.bricks):
            sl = (slice(bk * e, bk * e + e), slice(bj * e, bj * e + e), slice(bi * e, bi * e + e))
            inside = d[sl] < 0
            where = "brick (%d, %d, %d)" % (bi, bj, bk)
            if must_store[sl].any() or (inside.any() and not inside.all()):
                self.assertGreaterEqual(n, 0, "%s needs a value brick, table says %d" % (where, n))
            if n == ss.COARSE_INSIDE:
                self.assertTrue(inside.all(), "%s: coarse inside (-2) but has outside voxels" % where)
            elif n == ss.COARSE_OUTSIDE:
                self.assertFalse(inside.any(), "%s: coarse outside (-1) but has inside voxels" % where)

    def test_brick_table_is_the_minimal_one(self):
        """Both writers of the fixture keep codes only where §3.2 requires (a stored distance, or voxels on both
        sides); every other brick is coarse with its side's sign. (The spec allows more value bricks; the
        fixture does not use them.)"""
        vm = self.decoded()
        d = self.exact()
        e = ss.BRICK_EDGE
        for (bk, bj, bi), n in np.ndenumerate(vm.bricks):
            sl = (slice(bk * e, bk * e + e), slice(bj * e, bj * e + e), slice(bi * e, bi * e + e))
            inside = d[sl] < 0
            needed = vm.stored[sl].any() or (inside.any() and not inside.all())
            want = "value" if needed else (ss.COARSE_INSIDE if inside.all() else ss.COARSE_OUTSIDE)
            got = "value" if n >= 0 else int(n)
            self.assertEqual(got, want, "brick (%d, %d, %d)" % (bi, bj, bk))

    def test_layers_derived_from_values(self):
        """§3.1: layer v = floor(-d^/h + 1/2). Where a distance is stored it is the exact d's layer (but at a tie,
        within a quantum of a half voxel); elsewhere inner voxels are >= 1 and outer ones <= -1."""
        vm = self.decoded()
        layers = vm.layers
        want = sf.layers_expected(self.grid).astype(np.int64)
        x = -self.exact() / vm.voxel_size + 0.5
        tie = np.abs(x - np.round(x)) <= vm.distance_quantum / vm.voxel_size
        bad = vm.stored & ~tie & (layers != want)
        self.assertFalse(np.any(bad), "layers differ at [k,j,i] %s: got %s expected %s"
                         % (first(bad), layers[bad][:5].tolist(), want[bad][:5].tolist()))
        inside = self.exact() < 0
        ns = ~vm.stored
        self.assertTrue(np.all(layers[ns & inside] >= 1), "inner voxel with layer < 1")
        self.assertTrue(np.all(layers[ns & ~inside] <= -1), "outer voxel with layer > -1")

    def test_index_order_zyx(self):
        """Element [k, j, i] of the decoded grid is voxel (i, j, k): check off-centre probe voxels."""
        vm = self.decoded()
        c = sf.center()
        for (i, j, k) in [(3, 7, 10), (10, 3, 7), (7, 10, 3), (2, 7, 7), (9, 5, 13)]:
            v = vm.values[k, j, i]
            if not vm.stored[k, j, i]:
                continue
            p = vm.voxel_center(i, j, k)
            self.assertAlmostEqual(v, np.linalg.norm(p - c) - sf.RADIUS, delta=vm.distance_quantum,
                                   msg="voxel (i,j,k)=(%d,%d,%d)" % (i, j, k))


class LegacyVoxelmapChecks(SpecFileChecks):
    """The 1.x voxelmap (§3.4: dense layers and distances) of the legacy 1.1 sphere fixture."""

    legacy = True
    format_version = (1, 1)

    def test_fixture_shapes(self):
        with self.open() as f:
            self.assertEqual(f["/pointshell/points"].shape, (sf.N_POINTS, 3))
            self.assertEqual(f["/pointshell/level_offsets"].shape, (len(sf.level_offsets_expected()),))
            shape = tuple(int(x) for x in sf.dims(self.grid)[::-1])
            self.assertEqual(f["/voxelmap/layers"].shape, shape)
            self.assertEqual(f["/voxelmap/distances"].shape, shape)

    def test_should_grids_chunked_shuffle_deflate(self):
        """§1 SHOULD (1.x): voxel grids chunked (<= 32*32*32 voxels per chunk) with shuffle and deflate."""
        with self.open() as f:
            for p in sf.LEGACY_GRID_DATASETS:
                ds = f[p]
                self.assertIsNotNone(ds.chunks, "%s is not chunked" % p)
                self.assertLessEqual(int(np.prod(ds.chunks)), 32 ** 3, "%s chunk %r" % (p, ds.chunks))
                self.assertTrue(ds.shuffle, "%s: no shuffle filter" % p)
                self.assertEqual(ds.compression, "gzip", "%s: no deflate filter" % p)

    def test_distances_values(self):
        d64 = sf.signed_distance_grid(self.grid)
        mask = sf.stored_mask(self.grid)
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
        expected = sf.layers_expected(self.grid)
        diff = np.argwhere(layers.astype(np.int64) != expected.astype(np.int64))
        self.assertEqual(len(diff), 0, "layers differ at [k,j,i] %s: got %s expected %s"
                         % (diff[:5].tolist(), [int(layers[tuple(x)]) for x in diff[:5]],
                            [int(expected[tuple(x)]) for x in diff[:5]]))

    def test_layer_rules_generic(self):
        """§3.4 layer rules of 1.1 files, checked on the file's own data."""
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
        inside = sf.signed_distance_grid(self.grid) < 0
        ns = ~stored
        self.assertTrue(np.all(layers[ns & inside] >= 1), "inner voxel with layer < 1")
        self.assertTrue(np.all(layers[ns & ~inside] <= -1), "outer voxel with layer > -1")
        # 1.1: |delta| - 1/2 <= |layer| <= |delta| + 1/2 + sqrt(3), delta the exact depth in voxels
        depth = np.abs(sf.signed_distance_grid(self.grid)[ns]) / h
        self.assertTrue(np.all(np.abs(layers[ns]) >= depth - 0.5 - 1e-9), "a layer nearer the surface than exact")
        self.assertTrue(np.all(np.abs(layers[ns]) <= depth + 0.5 + math.sqrt(3) + 1e-9), "a layer too deep")
        # 6-neighbours differ by at most 1
        for axis in range(3):
            self.assertLessEqual(int(np.max(np.abs(np.diff(layers, axis=axis)))), 1,
                                 "6-neighbour layers differ by more than 1 along array axis %d" % axis)
        # every voxel with |d| <= band*h has its distance stored (analytic d)
        must = np.abs(sf.signed_distance_grid(self.grid)) <= band * h
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


    def test_read_as_bricks_per_3_4(self):
        """§3.4: read as 2.0 bricks, the 1.1 file's lattice ((|v| + 1/2) h, or the stored |d|) is within
        eps = [1 + sqrt 3, 0] of the exact distance and never below it, and every voxel keeps its side's sign."""
        vm = ss.decode_legacy_voxelmap(self.path)
        self.assertEqual(vm.lattice_error, [1 + math.sqrt(3), 0.0])
        u = sf.lattice_exact(self.grid)
        h = vm.voxel_size
        self.assertTrue(np.all(vm.lattice >= u - 1e-6 * h), "lattice below the exact distance")
        self.assertTrue(np.all(vm.lattice <= u + vm.lattice_error[0] * h), "lattice beyond eps0")
        d = sf.signed_distance_grid(self.grid)
        far = np.abs(d) > vm.distance_quantum
        self.assertTrue(np.all(np.sign(vm.values[far]) == np.sign(d[far])), "a converted value has the wrong sign")
        self.assertEqual(vm.stored_count, int(np.count_nonzero(sf.stored_mask(self.grid))))

class TestH5pyFixtureSelfCheck(VoxelmapChecks, unittest.TestCase):
    """The 2.0 checks above, run on the h5py-written fixture: proves they accept a conforming file."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-selfcheck-")
        cls.path = sf.write_fixture_h5py(os.path.join(cls.tmp, "sphere_h5py.vox.h5"))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_decoder_and_writer_interpolate_alike(self):
        """The decoder's vectorised §3.3 interpolation equals the writer's brick-by-brick one."""
        vm = self.decoded()
        np.testing.assert_allclose(vm.interpolated, sf._interpolate_per_brick(vm.lattice, vm.dims),
                                   rtol=0, atol=1e-15)


class TestH5pyFineGridSelfCheck(VoxelmapChecks, unittest.TestCase):
    """The 2.0 checks on the same sphere at h = 0.01 (57^3 voxels, 8^3 bricks, the last one voxel wide, so that
    §3.3's t = 0 case occurs): coarse bricks inside (-2) and outside (-1) and partial edge bricks are exercised."""

    grid = sf.FINE_GRID

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-selfcheck-fine-")
        cls.path = sf.write_fixture_h5py(os.path.join(cls.tmp, "sphere_fine_h5py.vox.h5"), grid=cls.grid)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_has_coarse_bricks_of_both_signs(self):
        vm = self.decoded()
        self.assertEqual(vm.dims[0] % 8, 1, "the last brick column should be one voxel wide")
        self.assertGreater(int(np.count_nonzero(vm.bricks == ss.COARSE_INSIDE)), 0)
        self.assertGreater(int(np.count_nonzero(vm.bricks == ss.COARSE_OUTSIDE)), 0)
        self.assertGreater(vm.value_brick_count, 0)


class TestH5pyLegacyFixtureSelfCheck(LegacyVoxelmapChecks, unittest.TestCase):
    """The legacy 1.1 checks on the h5py-written 1.1 fixture that TestLegacyPythonToCpp feeds to voxfmt."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-selfcheck-legacy-")
        cls.path = sf.write_legacy_fixture_h5py(os.path.join(cls.tmp, "sphere_h5py_1_1.vox.h5"))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)


@ss.requires_writer
class TestCppToPython(VoxelmapChecks, unittest.TestCase):
    """The C++ sample writer's file (format 2.2, its voxelmap from voxfmt::make_voxelmap), read with h5py."""

    format_version = (2, 2)

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
        for level in ("quick", "full"):
            proc = ss.run([ss.VOXFMT_BIN, "validate", self.path, "--level", level, "--json"])
            self.assertEqual(proc.returncode, 0, describe(proc))
            entry = ss.check_validate_json(self, proc, [self.path])[self.path]
            self.assertTrue(entry["valid"])
            self.assertEqual([i for i in entry["issues"] if i["severity"] in ("error", "warning")], [],
                             describe(proc))

    @ss.requires_bin
    def test_voxfmt_inspect_agrees_with_the_decoder(self):
        """`voxfmt inspect --json` of the writer's file reports what the spec's decoder reads from it."""
        proc = ss.run([ss.VOXFMT_BIN, "inspect", self.path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        js = ss.parse_json_stdout(self, proc)
        vm = self.decoded()
        self.assertEqual(js["format_version"], list(self.format_version))
        got = js["voxelmap"]
        self.assertEqual(got["dims"], list(vm.dims))
        self.assertEqual(got["stored_distances"], vm.stored_count)
        self.assertEqual(got["layer_min"], int(vm.layers.min()))
        self.assertEqual(got["layer_max"], int(vm.layers.max()))
        self.assertEqual((got["bricks"], got["value_bricks"], got["coarse_bricks"]),
                         (vm.brick_count, vm.value_brick_count, vm.coarse_brick_count))
        np.testing.assert_allclose(got["lattice_error"], vm.lattice_error, rtol=1e-12, atol=0)


class PythonToCppBase(object):
    """Files written with h5py alone, read by `voxfmt validate --level full` and `voxfmt inspect`. Subclasses set
    `legacy` (False: format 2.0; True: 1.x dense grids) and `version` (the default format_version)."""

    legacy = False
    version = (2, 0)

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-py2cpp-")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def write(self, name, **kw):
        return sf.write_fixture_h5py(os.path.join(self.tmp, name + ".vox.h5"), legacy=self.legacy, **kw)

    def decode(self, path):
        return ss.decode_legacy_voxelmap(path) if self.legacy else ss.decode_voxelmap(path)

    def validate(self, *paths, level="full"):
        proc = ss.run([ss.VOXFMT_BIN, "validate"] + list(paths) + ["--level", level, "--json"])
        self.assertGreaterEqual(proc.returncode, 0, "validate crashed (signal)\n" + describe(proc))
        return proc, ss.check_validate_json(self, proc, list(paths))

    def assert_valid(self, path):
        """0 errors at level full (which includes quick) and, separately, at level quick."""
        for level in ("full", "quick"):
            proc, entries = self.validate(path, level=level)
            self.assertEqual(proc.returncode, 0, describe(proc))
            entry = entries[path]
            self.assertTrue(entry["valid"], describe(proc))
            errors = [i for i in entry["issues"] if i["severity"] == "error"]
            self.assertEqual(errors, [], describe(proc))
            if level == "full":
                full = entry
        return full

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

    def check_inspect(self, path, format_version=None, grid=sf.FIXTURE_GRID):
        """inspect --json against the fixture and against the spec's decoding of the file (§3.4 for 1.x)."""
        format_version = format_version or self.version
        js = self.inspect(path)
        vm = self.decode(path)
        self.assertTrue(ss.same_file_name(js["file"], path), js["file"])
        self.assertEqual(js["file_size_bytes"], os.path.getsize(path))
        self.assertEqual(js["format_version"], list(format_version))
        self.assertEqual(js["units"], "m")
        self.assertEqual(js["frame"], "right-handed")
        self.assertEqual(js["up_axis"], "+Y")
        bmin, bmax = sf.bounds_expected()
        self.close(js["bounds_min"], bmin, "bounds_min")
        self.close(js["bounds_max"], bmax, "bounds_max")
        v = js["voxelmap"]
        self.assertEqual(v["dims"], sf.dims(grid).tolist())
        self.close(v["voxel_size"], grid.voxel_size, "voxel_size")
        self.close(v["origin"], sf.origin(grid), "origin")
        self.close(v["distance_band"], grid.band, "distance_band")
        stored = int(np.count_nonzero(sf.stored_mask(grid)))
        self.assertEqual(vm.stored_count, stored, "the fixture's file holds the fixture's stored distances")
        self.assertEqual(v["stored_distances"], stored)
        self.assertEqual(v["layer_min"], int(vm.layers.min()), "layer_min: floor(-d^/h + 1/2) of the values")
        self.assertEqual(v["layer_max"], int(vm.layers.max()), "layer_max: floor(-d^/h + 1/2) of the values")
        bw, bh, bd = sf.brick_counts_of(sf.dims(grid))
        self.assertEqual(v["bricks"], bw * bh * bd)
        self.assertEqual(v["bricks"], vm.brick_count)
        self.assertEqual(v["value_bricks"], vm.value_brick_count)
        self.assertEqual(v["coarse_bricks"], vm.coarse_brick_count)
        self.close(v["lattice_error"], vm.lattice_error, "lattice_error", rel=1e-12)
        self.assertIsInstance(v["memory_bytes"], int)
        self.assertGreater(v["memory_bytes"], 0)
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
        vals = sf.fixture_values(legacy=self.legacy, grid=grid)
        for key in ("generator", "generator_version", "source_file", "source_sha256"):
            self.assertEqual(pv[key], vals["/provenance/" + key], "provenance.%s" % key)
        self.assertEqual(pv["build_parameters"], json.loads(vals["/provenance/build_parameters"]))
        self.assertEqual(pv["dependency_versions"], json.loads(vals["/provenance/dependency_versions"]))
        self.assertEqual(pv["build_warnings"], [])
        self.assertIsInstance(js["warnings"], list)
        for w in js["warnings"]:
            self.assertIsInstance(w, str)
        return js

    def _accept(self, name, format_version=None, grid=sf.FIXTURE_GRID, **kw):
        format_version = format_version or self.version
        path = self.write(name, format_version=format_version, grid=grid, **kw)
        entry = self.assert_valid(path)
        self.check_inspect(path, format_version=format_version, grid=grid)
        return entry

    # -- the conforming fixture ---------------------------------------------------------------------------

    def test_validate_default_fixture(self):
        self.assert_valid(self.write("default"))

    def test_default_fixture_has_no_warnings(self):
        entry = self.assert_valid(self.write("default_w"))
        self.assertEqual([i for i in entry["issues"] if i["severity"] == "warning"], [],
                         "a conforming %d.%d file violates no SHOULD" % self.version)

    def test_inspect_default_fixture(self):
        self.check_inspect(self.write("default_i"))

    def test_validate_two_good_files(self):
        a, b = self.write("good_a"), self.write("good_b")
        proc, entries = self.validate(a, b)
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertTrue(entries[a]["valid"] and entries[b]["valid"])

    # -- variants readers must accept -----------------------------------------------------------------------

    def test_fixed_length_strings_null_terminated(self):
        self._accept("fixed_nullterm", string_mode="fixed_nullterm")

    def test_variable_length_strings_of_older_files(self):
        self._accept("vlen", string_mode="vlen")

    def test_fixed_length_strings_null_padded(self):
        self._accept("fixed_nullpad", string_mode="fixed_nullpad")

    def test_fixed_length_strings_null_padded_no_terminator(self):
        self._accept("fixed_nullpad_exact", string_mode="fixed_nullpad_exact")

    def grid_datasets(self):
        return sf.LEGACY_GRID_DATASETS if self.legacy else sf.VOXELMAP_2_0_DATASETS

    def test_big_endian_numeric_dtypes(self):
        """§1: readers SHOULD accept the big-endian variant of each type (HDF5 converts it)."""
        path = self.write("big_endian", byteorder=">")
        with h5py.File(path, "r") as f:  # the variant really is big-endian
            for p in self.grid_datasets():
                self.assertEqual(f[p].dtype.byteorder, ">", p)
            self.assertEqual(f["/voxelmap"].attrs.get_id("dims").dtype.str, ">u4")
        self.assert_valid(path)
        self.check_inspect(path)

    def test_contiguous_grids(self):
        path = self.write("contiguous", grid_layout="contiguous")
        with h5py.File(path, "r") as f:
            for p in self.grid_datasets():
                self.assertIsNone(f[p].chunks, p)
        self.assert_valid(path)
        self.check_inspect(path)

    def test_chunked_with_fletcher32(self):
        self._accept("fletcher32", fletcher32=True)

    def test_chunked_without_compression(self):
        self._accept("chunked_plain", shuffle=False, compression=None)

    def test_optional_objects_absent(self):
        self._accept("no_optional", optional=False)

    def test_newer_minor_version(self):
        entry = self._accept("minor7", format_version=(self.version[0], 7))
        codes = [(i["code"], i["severity"]) for i in entry["issues"]]
        self.assertIn(("VERSION_NEWER_MINOR", "warning"), codes)

    def test_newer_minor_inspect_warns(self):
        """§7 SHOULD: a reader warns that newer data may be ignored."""
        js = self.inspect(self.write("minor7_w", format_version=(self.version[0], 7)))
        self.assertEqual(js["format_version"], [self.version[0], 7])
        self.assertTrue(js["warnings"], "inspect reports no warning for format_version [%d, 7]" % self.version[0])

    def test_unknown_objects_ignored(self):
        entry = self._accept("extra", extra_objects=True)
        for issue in entry["issues"]:
            if issue["code"] == "UNKNOWN_OBJECT":
                self.assertEqual(issue["severity"], "info")

    def test_newer_minor_with_unknown_objects(self):
        entry = self._accept("minor7_extra", format_version=(self.version[0], 7), extra_objects=True)
        self.assertIn("VERSION_NEWER_MINOR", [i["code"] for i in entry["issues"]])

    def test_all_variants_combined(self):
        self._accept("combined", string_mode="fixed_nullpad", byteorder=">", grid_layout="contiguous",
                     extra_objects=True)


@ss.requires_bin
class TestPythonToCpp(PythonToCppBase, unittest.TestCase):
    """Format 2.0 files (bricks, codes, lattice) written with h5py alone from the spec."""

    def test_fine_grid_with_coarse_bricks(self):
        """57^3 voxels, 8^3 bricks: coarse bricks inside and outside, partial edge bricks, a one-voxel brick
        column (§3.3's t = 0), several chunks per dataset."""
        self._accept("fine", grid=sf.FINE_GRID)

    def test_value_bricks_in_reverse_order(self):
        """§3.2: entry n names row n, whatever the order; a reader follows the table."""
        self._accept("reversed", grid=sf.FINE_GRID, brick_order="reversed")

    def test_every_brick_a_value_brick(self):
        """§3.2 only says when a brick MUST be a value brick: one that could be coarse may keep codes."""
        path = self.write("all_value", grid=sf.FINE_GRID, value_bricks="all")
        self.assert_valid(path)
        js = self.check_inspect(path, grid=sf.FINE_GRID)
        self.assertEqual(js["voxelmap"]["coarse_bricks"], 0)
        self.assertEqual(js["voxelmap"]["value_bricks"], 512)

    def test_codes_past_the_grid_are_ignored(self):
        """§3.2: codes at positions past the grid are ignored: odd codes (stored distances far beyond the band)
        there must not count, nor be checked."""
        for name, grid, code in (("pad_fine", sf.FINE_GRID, 32767), ("pad_small", sf.FIXTURE_GRID, -32767)):
            self._accept(name, grid=grid, padding_code=code)

    def test_other_quanta(self):
        """distance_quantum and estimate_quantum are the file's (§3.2), not `voxfmt build`'s choices: h/1000 and
        h/8 here."""
        h = sf.FINE_GRID.voxel_size
        path = self.write("quanta", grid=sf.FINE_GRID, distance_quantum=h / 1000, estimate_quantum=h / 8)
        with h5py.File(path, "r") as f:
            self.assertEqual(float(f["/voxelmap"].attrs["distance_quantum"]), h / 1000)
        self.assert_valid(path)
        self.check_inspect(path, grid=sf.FINE_GRID)

    def test_chunks_as_voxfmt_build_writes_them(self):
        """§1: `voxfmt build`'s chunks: 32^3 entries of bricks and lattice, 64 bricks of brick_values."""
        self._accept("build_chunks", grid=sf.FINE_GRID, grid_chunks=(32, 32, 32), value_chunk_rows=64)

    def test_chunks_never_written_read_as_the_fill_value(self):
        """HDF5: a chunk never written reads as the dataset's fill value. The brick table in chunks of 2^3
        entries whose fill is the commonest entry, and only the chunks holding another entry written."""
        written = {}

        def sparse_bricks(f):
            table = f["/voxelmap/bricks"][()]
            values, counts = np.unique(table, return_counts=True)
            fill = values[np.argmax(counts)]
            del f["/voxelmap/bricks"]
            ds = f["/voxelmap"].create_dataset("bricks", shape=table.shape, dtype=table.dtype, chunks=(2, 2, 2),
                                               shuffle=True, compression="gzip", fillvalue=fill)
            for k in range(0, table.shape[0], 2):
                for j in range(0, table.shape[1], 2):
                    for i in range(0, table.shape[2], 2):
                        block = table[k:k + 2, j:j + 2, i:i + 2]
                        if (block != fill).any():
                            ds[k:k + 2, j:j + 2, i:i + 2] = block
            written["chunks"] = (ds.id.get_num_chunks(), int(np.prod([-(-s // 2) for s in table.shape])))

        self._accept("fill_chunks", grid=sf.FINE_GRID, post=sparse_bricks)
        self.assertLess(written["chunks"][0], written["chunks"][1], "every chunk was written: nothing is tested")

    def test_fine_grid_all_variants_combined(self):
        self._accept("fine_combined", grid=sf.FINE_GRID, string_mode="vlen", byteorder=">", fletcher32=True,
                     brick_order="reversed", padding_code=5, extra_objects=True)


@ss.requires_bin
class TestLegacyPythonToCpp(PythonToCppBase, unittest.TestCase):
    """Legacy 1.x files (dense layers and distances, §3.4) written with h5py alone: a 2.0 reader still reads and
    validates them (§7), and inspect reports them as §3.4's bricks."""

    legacy = True
    version = (1, 1)

    def test_older_minor_version(self):
        """1.0 files stay valid and readable (spec CHANGELOG 1.1, 2.0); §3.4: their lattice_error is [1, 1/9]."""
        entry = self._accept("minor0", format_version=(1, 0))
        self.assertFalse([i for i in entry["issues"] if i["severity"] == "error"])
        js = self.inspect(self.write("minor0_i", format_version=(1, 0)))
        self.close(js["voxelmap"]["lattice_error"], [1.0, 1.0 / 9.0], "1.0 lattice_error", rel=1e-12)

    def test_lattice_error_of_1_1(self):
        """§3.4: a 1.1 file read as bricks has lattice_error [1 + sqrt 3, 0]."""
        js = self.inspect(self.write("lattice_error_1_1"))
        self.close(js["voxelmap"]["lattice_error"], [1.0 + math.sqrt(3.0), 0.0], "1.1 lattice_error", rel=1e-12)

    def test_fine_grid_with_coarse_bricks(self):
        """§3.4 on 8^3 bricks: bricks without stored distances and one sign become coarse."""
        path = self.write("fine", grid=sf.FINE_GRID)
        self.assert_valid(path)
        js = self.check_inspect(path, grid=sf.FINE_GRID)
        self.assertGreater(js["voxelmap"]["coarse_bricks"], 0)


def have_upgrade():
    """`voxfmt upgrade` (spec §3.4) is listed by `voxfmt --help`."""
    if not ss.have_bin():
        return False
    proc = ss.run([ss.VOXFMT_BIN, "--help"])
    return proc.returncode == 0 and any(line.split()[:1] == ["upgrade"] for line in proc.stdout.splitlines())


@unittest.skipUnless(have_upgrade(), "voxfmt has no upgrade subcommand")
class TestLegacyUpgrade(unittest.TestCase):
    """§3.4: "A 2.0 reader reads a 1.x voxelmap as the bricks of §3.2 ... `voxfmt upgrade` writes that as a 2.0
    file." h5py-written 1.0 and 1.1 files are upgraded with voxfmt and the result is decoded with the spec's 2.0
    decoder: it must be what spec_support.decode_legacy_voxelmap reads from the 1.x file."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-upgrade-")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def upgrade(self, name, **kw):
        old = sf.write_legacy_fixture_h5py(os.path.join(self.tmp, name + "-1x.vox.h5"), **kw)
        new = os.path.join(self.tmp, name + "-2.0.vox.h5")
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", old, "-o", new, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        report = ss.parse_json_stdout(self, proc)
        self.assertEqual([f["status"] for f in report["files"]], ["upgraded"], describe(proc))
        proc = ss.run([ss.VOXFMT_BIN, "validate", new, "--level", "full", "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertTrue(ss.check_validate_json(self, proc, [new])[new]["valid"])
        return old, new

    def check_as_bricks(self, old, new, version):
        want = ss.decode_legacy_voxelmap(old)
        got = ss.decode_voxelmap(new)
        with h5py.File(new, "r") as f:
            self.assertEqual(f.attrs["format_version"].tolist(), [2, 2])
            self.assertNotIn("layers", f["/voxelmap"])
            self.assertNotIn("distances", f["/voxelmap"])
        self.assertEqual(got.dims, want.dims)
        np.testing.assert_allclose(got.lattice_error, want.lattice_error, rtol=1e-12, err_msg="§3.4 lattice_error")
        self.assertAlmostEqual(got.distance_quantum, got.distance_band * got.voxel_size / 16383, delta=1e-18)
        np.testing.assert_array_equal(got.stored, want.stored, "stored distances where the 1.x file has them")
        np.testing.assert_allclose(got.values[got.stored], want.values[want.stored], rtol=0,
                                   atol=1e-6 * got.distance_quantum, err_msg="stored distances on §3.4's steps")
        np.testing.assert_array_equal(np.minimum(got.bricks, 0), np.minimum(want.bricks, 0),
                                      "value bricks where §3.4 puts them, coarse bricks with their layers' sign")
        np.testing.assert_array_equal(got.lattice, want.lattice, "lattice (|v| + 1/2) h, or the stored |d|")
        est = ~got.stored & got.value_brick
        settled = ss.settled_estimate_steps(got) * got.estimate_quantum
        np.testing.assert_array_equal(np.abs(got.values[est]), settled[est], "value-brick estimates settled (§3.1)")
        coarse = ~got.value_brick
        err = np.abs(got.values - want.values)[coarse]
        self.assertLessEqual(float(err.max(initial=0.0)),
                             got.estimate_quantum / 2 * (1 + 1e-9) + 1e-12 * got.voxel_size,
                             "coarse estimates are the lattice's")
        self.assertEqual(list(want.lattice_error), [1.0, 1.0 / 9.0] if version == (1, 0) else
                         [1.0 + math.sqrt(3.0), 0.0])

    def test_upgrade_1_1(self):
        old, new = self.upgrade("sphere11")
        self.check_as_bricks(old, new, (1, 1))

    def test_upgrade_1_0(self):
        old, new = self.upgrade("sphere10", format_version=(1, 0))
        self.check_as_bricks(old, new, (1, 0))

    def test_upgrade_fine_grid_with_coarse_bricks(self):
        old, new = self.upgrade("fine11", grid=sf.FINE_GRID)
        self.check_as_bricks(old, new, (1, 1))
        self.assertGreater(ss.decode_voxelmap(new).coarse_brick_count, 0)

    def test_inspect_reads_both_alike(self):
        """inspect reports the same voxelmap for the 1.1 file and its upgrade (a 2.0 reader reads 1.x as 2.0)."""
        old, new = self.upgrade("inspect11", grid=sf.FINE_GRID)
        a, b = (ss.parse_json_stdout(self, ss.run([ss.VOXFMT_BIN, "inspect", p, "--json"]))["voxelmap"]
                for p in (old, new))
        for key in ("dims", "stored_distances", "bricks", "value_bricks", "coarse_bricks"):
            self.assertEqual(a[key], b[key], key)
        np.testing.assert_allclose(a["lattice_error"], b["lattice_error"], rtol=1e-12)

    def test_upgrade_settles_a_2_1_file_and_leaves_a_2_2_file_alone(self):
        """§7: upgrade writes 2.2 from a 2.1 file (interpolated estimates): the same bricks, lattice and stored
        codes, its value-brick estimates settled (§3.1); the 2.2 file it wrote is current."""
        old = sf.write_fixture_h5py(os.path.join(self.tmp, "fine21.vox.h5"), grid=sf.FINE_GRID, format_version=[2, 1])
        new = os.path.join(self.tmp, "fine21-2.2.vox.h5")
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", old, "-o", new, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        report = ss.parse_json_stdout(self, proc)
        self.assertEqual([(f["status"], f["from"]) for f in report["files"]], [("upgraded", [2, 1])])
        want, got = ss.decode_voxelmap(old), ss.decode_voxelmap(new)
        self.assertEqual(got.format_version, (2, 2))
        np.testing.assert_array_equal(got.bricks, want.bricks)
        np.testing.assert_array_equal(got.lattice, want.lattice)
        np.testing.assert_array_equal(got.code[got.stored], want.code[want.stored])
        est = got.value_brick & ~got.stored
        changed = int(np.count_nonzero(got.code[est] != want.code[est]))
        self.assertGreater(changed, 0, "2.1's estimates were not settled")
        np.testing.assert_array_equal(np.abs(got.code[est] >> 1), ss.settled_estimate_steps(got)[est])
        np.testing.assert_array_equal(np.sign(got.code[est]), np.sign(want.code[est]))
        again = ss.run([ss.VOXFMT_BIN, "upgrade", new, "-o", new + ".again", "--json"])
        self.assertEqual(again.returncode, 0, describe(again))
        self.assertEqual([f["status"] for f in ss.parse_json_stdout(self, again)["files"]], ["current"])

    def test_upgrade_copies_what_it_leaves_alone_and_never_rewrites_a_newer_file(self):
        """A current file (and one of a newer minor version, even with --force, whose rewrite would drop what this
        voxfmt does not know) is copied unchanged to an output elsewhere; an in-place upgrade reports the size the
        file had; one file named twice is upgraded once."""
        root = os.path.join(self.tmp, "alone")
        os.makedirs(root)
        old = sf.write_fixture_h5py(os.path.join(root, "old.vox.h5"), grid=sf.FINE_GRID, format_version=[2, 1])
        current = os.path.join(root, "current.vox.h5")
        self.assertEqual(ss.run([ss.VOXFMT_BIN, "upgrade", old, "-o", current]).returncode, 0)
        newer = os.path.join(root, "newer.vox.h5")
        shutil.copy(current, newer)
        with h5py.File(newer, "r+") as f:
            f.attrs["format_version"] = np.array([2, 3], dtype=f.attrs["format_version"].dtype)
            f["x_future"] = np.arange(3)
        for source, force, status in ((current, False, "current"), (newer, False, "newer"), (newer, True, "newer")):
            out = os.path.join(root, "copy-" + os.path.basename(source))
            proc = ss.run([ss.VOXFMT_BIN, "upgrade", source, "-o", out, "--json"] + (["--force"] if force else []))
            self.assertEqual(proc.returncode, 0, describe(proc))
            self.assertEqual([f["status"] for f in ss.parse_json_stdout(self, proc)["files"]], [status])
            with open(source, "rb") as a, open(out, "rb") as b:
                self.assertEqual(a.read(), b.read(), "not copied unchanged: " + out)
            os.remove(out)
        in_place = os.path.join(root, "in-place.vox.h5")
        shutil.copy(old, in_place)
        size = os.path.getsize(in_place)
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", in_place, "-o", in_place, "--json"])
        entry = ss.parse_json_stdout(self, proc)["files"][0]
        self.assertEqual((entry["status"], entry["bytes_before"]), ("upgraded", size), describe(proc))
        self.assertEqual(entry["bytes_after"], os.path.getsize(in_place))
        twice = os.path.join(root, "twice")
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", old, os.path.join(root, ".", "old.vox.h5"), "-o", twice, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertEqual([f["status"] for f in ss.parse_json_stdout(self, proc)["files"]], ["upgraded"])

    def test_upgrade_writes_only_under_its_output(self):
        """A link in the input folder is upgraded under OUTPUT by its own name, never through the link onto the
        file it points to; two inputs that would write one output are refused; an output folder inside the input
        is not read again as input."""
        root = os.path.join(self.tmp, "links")
        os.makedirs(os.path.join(root, "in"))
        target = sf.write_fixture_h5py(os.path.join(root, "a.vox.h5"), format_version=[2, 1])
        with open(target, "rb") as f:
            before = f.read()
        os.symlink("../a.vox.h5", os.path.join(root, "in", "s.vox.h5"))
        out = os.path.join(root, "out")
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "in"), "-o", out, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertEqual([f["output"] for f in ss.parse_json_stdout(self, proc)["files"]],
                         [os.path.join(out, "s.vox.h5")])
        with open(target, "rb") as f:
            self.assertEqual(f.read(), before, "the link's target was rewritten")
        for name in ("p", "q"):
            os.makedirs(os.path.join(root, name))
            shutil.copy(target, os.path.join(root, name, "x.vox.h5"))
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "p"), os.path.join(root, "q"), "-o", out])
        self.assertEqual(proc.returncode, 2, describe(proc))
        self.assertIn("two inputs would write the same output", proc.stderr)
        inside = os.path.join(root, "p", "new")
        for _ in range(2):
            proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "p"), "-o", inside, "--force", "-q"])
            self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertFalse(os.path.exists(os.path.join(inside, "new")), "the output was read again as input")
        alias = os.path.join(root, "alias")  # the same folder by another name is still the output
        os.symlink(inside, alias)
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "p"), "-o", alias + "/", "--force", "-q"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertFalse(os.path.exists(os.path.join(inside, "new")), "the output was read again as input")
        # In place, a link and the file it names are two outputs, not one refused twice (the link's is written
        # through it, to the file it names); the link stays a link.
        os.symlink("x.vox.h5", os.path.join(root, "q", "y.vox.h5"))
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "q"), "-o", os.path.join(root, "q"), "--force"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertTrue(os.path.islink(os.path.join(root, "q", "y.vox.h5")))
        # A trailing slash names a folder to make, for one file too.
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", target, "-o", os.path.join(root, "fresh") + "/"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        self.assertTrue(os.path.isfile(os.path.join(root, "fresh", "a.vox.h5")))

    def test_upgrade_refuses_an_output_that_is_another_input_and_a_folder_of_no_assets(self):
        """An output that another item reads (read later, in order) would be replaced before it is read: refused,
        as JSON too; a folder holding no asset is an error, not '0 upgraded'; a 1.x file of a newer minor is never
        rewritten; assets named in upper case are found."""
        root = os.path.join(self.tmp, "clash")
        for folder in ("aa/sub", "out/sub", "empty"):
            os.makedirs(os.path.join(root, folder))
        sf.write_legacy_fixture_h5py(os.path.join(root, "aa", "sub", "x.vox.h5"))
        kept = sf.write_fixture_h5py(os.path.join(root, "out", "sub", "x.vox.h5"), format_version=[2, 1])
        with open(kept, "rb") as f:
            before = f.read()
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "aa"), os.path.join(root, "out", "sub"), "-o",
                       os.path.join(root, "out"), "--json"])
        self.assertEqual(proc.returncode, 2, describe(proc))
        error = ss.parse_json_stdout(self, proc)
        self.assertEqual((error["status"], error["code"]), ("error", "BAD_OPTION"), describe(proc))
        self.assertIn("it would be replaced before it is read", error["message"])
        with open(kept, "rb") as f:
            self.assertEqual(f.read(), before, "an input was replaced")
        # The same through a link in the output folder, which the write would follow onto another input.
        os.makedirs(os.path.join(root, "in"))
        sf.write_legacy_fixture_h5py(os.path.join(root, "in", "a.vox.h5"))
        b = sf.write_fixture_h5py(os.path.join(root, "in", "b.vox.h5"), format_version=[2, 1])
        with open(b, "rb") as f:
            before = f.read()
        os.makedirs(os.path.join(root, "linked"))
        os.symlink(b, os.path.join(root, "linked", "a.vox.h5"))
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "in"), "-o", os.path.join(root, "linked")])
        self.assertEqual(proc.returncode, 2, describe(proc))
        with open(b, "rb") as f:
            self.assertEqual(f.read(), before, "an input was replaced through a link")
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "empty"), "-o", os.path.join(root, "o2")])
        self.assertEqual(proc.returncode, 2, describe(proc))
        self.assertIn("holds no asset", proc.stderr)
        newer = sf.write_legacy_fixture_h5py(os.path.join(root, "empty", "NEWER.VOX.H5"))
        with h5py.File(newer, "r+") as f:
            f.attrs["format_version"] = np.array([1, 2], dtype=f.attrs["format_version"].dtype)
            f["x_future"] = np.arange(3)
        proc = ss.run([ss.VOXFMT_BIN, "upgrade", os.path.join(root, "empty"), "-o", os.path.join(root, "o3"),
                       "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        entry = ss.parse_json_stdout(self, proc)["files"][0]
        self.assertEqual(entry["status"], "newer", describe(proc))
        self.assertIn("VERSION_NEWER_MINOR", [w["code"] for w in entry["warnings"]])
        with open(newer, "rb") as a, open(os.path.join(root, "o3", "NEWER.VOX.H5"), "rb") as b:
            self.assertEqual(a.read(), b.read(), "a newer file was not copied unchanged")


if __name__ == "__main__":
    unittest.main()
