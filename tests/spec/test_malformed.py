"""Malformed files: one spec violation at a time, written with h5py from a valid fixture.

For every case `voxfmt validate FILE --json` must exit 1, list the expected issue code with severity
"error" (codes from spec/issue-codes.md), and `voxfmt inspect FILE` must exit non-zero with a message on
stderr naming the file. Neither may crash (a negative return code, i.e. a signal, is a failure).

Run:  VOXFMT_BIN=.../voxfmt /usr/bin/python3 -m unittest -v test_malformed
"""

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


class MalformedBase(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-malformed-")
        cls.good = sf.write_fixture_h5py(os.path.join(cls.tmp, "good.vox.h5"))

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def bad(self, name, **kw):
        return sf.write_fixture_h5py(os.path.join(self.tmp, name + ".vox.h5"), **kw)

    def raw_file(self, name, data):
        path = os.path.join(self.tmp, name)
        with open(path, "wb") as fh:
            fh.write(data)
        return path

    def assert_not_crashed(self, proc):
        self.assertGreaterEqual(proc.returncode, 0, "process killed by signal %d\n%s"
                                % (-proc.returncode, describe(proc)))

    def assert_inspect_fails(self, path):
        proc = ss.run([ss.VOXFMT_BIN, "inspect", path])
        self.assert_not_crashed(proc)
        self.assertNotEqual(proc.returncode, 0, "inspect accepted a malformed file\n" + describe(proc))
        self.assertTrue(proc.stderr.strip(), "inspect printed no message on stderr\n" + describe(proc))
        self.assertTrue(path in proc.stderr or os.path.basename(path) in proc.stderr,
                        "inspect's error message does not name the file\n" + describe(proc))

    def assert_rejected(self, path, codes, path_contains=None, message_re=None):
        """validate exits 1 with an error issue whose code is one of `codes`; inspect fails."""
        if isinstance(codes, str):
            codes = (codes,)
        for c in codes:
            self.assertIn(c, ss.ISSUE_CODES, "test bug: %s is not a spec code" % c)
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
        self.assert_not_crashed(proc)
        self.assertEqual(proc.returncode, 1, "validate must exit 1 (invalid)\n" + describe(proc))
        entry = ss.check_validate_json(self, proc, [path])[path]
        self.assertFalse(entry["valid"], describe(proc))
        hits = [i for i in entry["issues"] if i["code"] in codes and i["severity"] == "error"]
        self.assertTrue(hits, "expected an error issue with code in %s; got %s"
                        % (list(codes), [(i["code"], i["severity"], i["path"]) for i in entry["issues"]]))
        if path_contains is not None:
            self.assertTrue(any(path_contains in i["path"] for i in hits),
                            "no %s issue with a path mentioning %s: %s" % (codes, path_contains, hits))
        if message_re is not None:
            self.assertTrue(any(re.search(message_re, i["message"]) for i in hits),
                            "no %s issue message matching %r: %s" % (codes, message_re, hits))
        self.assert_inspect_fails(path)
        return entry


@ss.requires_bin
class TestMalformed(MalformedBase):
    """The cases of the brief."""

    def test_good_file_is_valid(self):
        """Control: the unmodified base file is accepted (otherwise every case below is meaningless)."""
        proc = ss.run([ss.VOXFMT_BIN, "validate", self.good, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))

    def test_text_file_not_hdf5(self):
        path = self.raw_file("text.vox.h5", b"this is not an HDF5 file\n" * 40)
        self.assert_rejected(path, "NOT_HDF5")

    def test_truncated_to_half(self):
        with open(self.good, "rb") as fh:
            data = fh.read()
        path = self.raw_file("truncated.vox.h5", data[:len(data) // 2])
        self.assert_rejected(path, ("NOT_HDF5", "READ_FAILED"))

    def test_missing_dataset_normals(self):
        path = self.bad("no_normals", omit=["/pointshell/normals"])
        self.assert_rejected(path, "MISSING_OBJECT", path_contains="/pointshell/normals")

    def test_missing_group_mass_properties(self):
        path = self.bad("no_mass", omit=["/mass_properties"])
        self.assert_rejected(path, "MISSING_OBJECT", path_contains="/mass_properties")

    def test_missing_root_attribute_format_version(self):
        path = self.bad("no_format_version", omit=["/format_version"])
        self.assert_rejected(path, "MISSING_OBJECT")

    def test_layers_float32(self):
        path = self.bad("layers_f32", dtypes={"/voxelmap/layers": "<f4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/voxelmap/layers")

    def test_points_int32(self):
        path = self.bad("points_i32", dtypes={"/pointshell/points": "<i4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/pointshell/points")

    def test_points_shape_n_by_2(self):
        path = self.bad("points_n2", values={"/pointshell/points": sf.points_expected()[:, :2]})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="/pointshell/points")

    def test_distances_shape_not_dims(self):
        path = self.bad("dist_shape", values={"/voxelmap/distances": sf.distances_expected()[:, :, :-1]})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="/voxelmap/distances")

    def test_child_begin_past_n(self):
        cb = sf.child_begin_expected()
        self.assertEqual(int(sf.child_count_expected()[5]), 4)
        cb[5] = sf.N_POINTS + 1  # node 5 keeps child_count 4: range [201, 205) lies outside [0, N)
        path = self.bad("child_past_n", values={"/pointshell/child_begin": cb})
        self.assert_rejected(path, "CHILD_RANGE_INVALID")

    def test_major_version_2(self):
        path = self.bad("v2", format_version=(2, 0))
        self.assert_rejected(path, "VERSION_UNSUPPORTED", message_re=r"(?<![0-9])2(?![0-9])")

    def test_format_name_mismatch(self):
        path = self.bad("notvox", values={"/format": "notvox"})
        self.assert_rejected(path, "FORMAT_NAME_MISMATCH")

    def test_units_mm(self):
        path = self.bad("units_mm", values={"/units": "mm"})
        self.assert_rejected(path, "BAD_ATTRIBUTE_VALUE", path_contains="units")

    def test_voxel_size_zero(self):
        path = self.bad("h_zero", values={"/voxelmap/voxel_size": np.float64(0.0)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="voxel")

    def test_voxel_size_nan(self):
        path = self.bad("h_nan", values={"/voxelmap/voxel_size": np.float64("nan")})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="voxel")

    def test_level_offsets_not_ending_at_n(self):
        lo = sf.level_offsets_expected()
        lo[-1] = sf.N_POINTS - 1
        path = self.bad("lo_end", values={"/pointshell/level_offsets": lo})
        self.assert_rejected(path, "LEVEL_OFFSETS_INVALID")

    def test_build_parameters_not_json(self):
        path = self.bad("bp_not_json", values={"/provenance/build_parameters": "not json"})
        self.assert_rejected(path, "INVALID_JSON", path_contains="build_parameters")

    def test_source_sha256_bad(self):
        path = self.bad("sha_xyz", values={"/provenance/source_sha256": "xyz"})
        self.assert_rejected(path, "BAD_SHA256")

    def test_missing_file(self):
        path = os.path.join(self.tmp, "does-not-exist.vox.h5")
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
        self.assert_not_crashed(proc)
        self.assertEqual(proc.returncode, 2, describe(proc))
        if proc.stdout.strip():
            entry = ss.check_validate_json(self, proc, [path])[path]
            self.assertFalse(entry["valid"])
            self.assertIn(("FILE_NOT_FOUND", "error"),
                          [(i["code"], i["severity"]) for i in entry["issues"]], describe(proc))
        self.assert_inspect_fails(path)

    def test_validate_good_and_bad(self):
        bad = self.bad("pair_bad", values={"/units": "mm"})
        proc = ss.run([ss.VOXFMT_BIN, "validate", self.good, bad, "--json"])
        self.assert_not_crashed(proc)
        self.assertEqual(proc.returncode, 1, describe(proc))
        entries = ss.check_validate_json(self, proc, [self.good, bad])
        self.assertTrue(entries[self.good]["valid"], describe(proc))
        self.assertFalse(entries[bad]["valid"], describe(proc))
        self.assertIn("BAD_ATTRIBUTE_VALUE", [i["code"] for i in entries[bad]["issues"]])
        # same verdict with the order reversed
        proc = ss.run([ss.VOXFMT_BIN, "validate", bad, self.good, "--json"])
        self.assertEqual(proc.returncode, 1, describe(proc))
        entries = ss.check_validate_json(self, proc, [bad, self.good])
        self.assertTrue(entries[self.good]["valid"])
        self.assertFalse(entries[bad]["valid"])


@ss.requires_bin
class TestMalformedMore(MalformedBase):
    """Further one-rule violations derived from the spec tables and issue-codes.md (beyond the brief)."""

    def test_empty_file(self):
        self.assert_rejected(self.raw_file("empty.vox.h5", b""), "NOT_HDF5")

    def test_dataset_where_group_required(self):
        path = self.bad("normals_group", omit=["/pointshell/normals"],
                        post=lambda f: f.create_group("/pointshell/normals"))
        self.assert_rejected(path, "WRONG_KIND", path_contains="/pointshell/normals")

    def test_normals_float64(self):
        path = self.bad("normals_f64", dtypes={"/pointshell/normals": "<f8"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/pointshell/normals")

    def test_layers_unsigned(self):
        path = self.bad("layers_u16", dtypes={"/voxelmap/layers": "<u2"},
                        values={"/voxelmap/layers": np.abs(sf.layers_expected())})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/voxelmap/layers")

    def test_child_count_signed(self):
        path = self.bad("cc_i32", dtypes={"/pointshell/child_count": "<i4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="child_count")

    def test_format_version_signed(self):
        path = self.bad("fv_i32", dtypes={"/format_version": "<i4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="format_version")

    def test_units_numeric(self):
        path = self.bad("units_num", values={"/units": np.uint32(1)}, dtypes={"/units": "<u4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="units")

    def test_format_version_three_elements(self):
        path = self.bad("fv_3", format_version=(1, 0, 0))
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="format_version")

    def test_voxel_size_not_scalar(self):
        path = self.bad("h_array", values={"/voxelmap/voxel_size": np.array([sf.VOXEL_SIZE, sf.VOXEL_SIZE])})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="voxel_size")

    def test_layers_shape_swapped(self):
        lay = np.zeros((sf.DIM, sf.DIM, sf.DIM + 1), dtype=np.int16)
        path = self.bad("layers_shape", values={"/voxelmap/layers": lay})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="/voxelmap/layers")

    def test_index_order_xyz(self):
        path = self.bad("order_xyz", values={"/voxelmap/index_order": "xyz"})
        self.assert_rejected(path, "BAD_ATTRIBUTE_VALUE", path_contains="index_order")

    def test_up_axis_bad(self):
        path = self.bad("up_Y", values={"/up_axis": "Y"})
        self.assert_rejected(path, "BAD_ATTRIBUTE_VALUE", path_contains="up_axis")

    def test_frame_bad(self):
        path = self.bad("frame_lh", values={"/frame": "left-handed"})
        self.assert_rejected(path, "BAD_ATTRIBUTE_VALUE", path_contains="frame")

    def test_bounds_min_greater_than_max(self):
        bmin, bmax = sf.bounds_expected()
        path = self.bad("bounds_swapped", values={"/bounds_min": bmax, "/bounds_max": bmin})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE")

    def test_negative_sphere_radius(self):
        r = sf.sphere_radii_expected()
        r[3] = -1.0
        path = self.bad("neg_radius", values={"/pointshell/sphere_radii": r})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="sphere_radii")

    def test_distance_band_below_one(self):
        path = self.bad("band_half", values={"/voxelmap/distance_band": np.float64(0.5)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="distance_band")

    def test_volume_zero(self):
        path = self.bad("vol0", values={"/mass_properties/volume": np.float64(0.0)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="volume")

    def test_point_infinite(self):
        pts = sf.points_expected()
        pts[7, 1] = np.inf
        path = self.bad("pt_inf", values={"/pointshell/points": pts})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="points")

    def test_origin_nan(self):
        o = sf.origin()
        o[2] = np.nan
        path = self.bad("origin_nan", values={"/voxelmap/origin": o})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="origin")

    def test_stored_distance_infinite(self):
        d = sf.distances_expected()
        k, j, i = np.argwhere(~np.isnan(d))[0]
        d[k, j, i] = np.inf
        path = self.bad("dist_inf", values={"/voxelmap/distances": d})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="distances")

    def test_level_offsets_second_not_one(self):
        lo = np.array([0, 2, 5, 21, 85, 200], dtype=np.uint32)
        path = self.bad("lo_second", values={"/pointshell/level_offsets": lo})
        self.assert_rejected(path, ("LEVEL_OFFSETS_INVALID",))

    def test_level_offsets_not_increasing(self):
        lo = np.array([0, 1, 5, 5, 85, 200], dtype=np.uint32)
        path = self.bad("lo_flat", values={"/pointshell/level_offsets": lo})
        self.assert_rejected(path, "LEVEL_OFFSETS_INVALID")

    def test_children_ranges_out_of_node_order(self):
        """Nodes 1 and 2 swap their children ranges: every point still once, but not breadth-first order."""
        cb = sf.child_begin_expected()
        cb[1], cb[2] = cb[2], cb[1]
        path = self.bad("bfs_swap", values={"/pointshell/child_begin": cb})
        self.assert_rejected(path, "TREE_NOT_BREADTH_FIRST")

    def test_point_shared_by_two_parents(self):
        """Node 2's children range overlaps node 1's: point 8 is missing from level 2's cover."""
        cb = sf.child_begin_expected()
        cb[2] = cb[1] + 1
        path = self.bad("bfs_shared", values={"/pointshell/child_begin": cb})
        self.assert_rejected(path, ("TREE_NOT_BREADTH_FIRST",))

    def test_normal_not_unit(self):
        n = sf.normals_expected()
        n[11] *= np.float32(1.01)
        path = self.bad("normal_long", values={"/pointshell/normals": n})
        self.assert_rejected(path, "NORMAL_NOT_UNIT", path_contains="normals")

    def test_build_warnings_wrong_json_type(self):
        path = self.bad("bw_object", values={"/provenance/build_warnings": "{}"})
        self.assert_rejected(path, "INVALID_JSON", path_contains="build_warnings")

    def test_dependency_versions_wrong_json_type(self):
        path = self.bad("dv_array", values={"/provenance/dependency_versions": "[]"})
        self.assert_rejected(path, "INVALID_JSON", path_contains="dependency_versions")

    def test_source_sha256_uppercase(self):
        path = self.bad("sha_upper", values={"/provenance/source_sha256": "AB" * 32})
        self.assert_rejected(path, "BAD_SHA256")

    def test_source_sha256_63_digits(self):
        path = self.bad("sha_63", values={"/provenance/source_sha256": "a" * 63})
        self.assert_rejected(path, "BAD_SHA256")

    def test_corrupt_chunk_fletcher32(self):
        """A flipped byte in a fletcher32-protected chunk of /voxelmap/layers -> READ_FAILED."""
        path = self.bad("bad_chunk", fletcher32=True)
        with h5py.File(path, "r") as f:
            info = f["/voxelmap/layers"].id.get_chunk_info(0)
            offset, size = info.byte_offset, info.size
        with open(path, "r+b") as fh:
            fh.seek(offset + size // 2)
            b = fh.read(1)
            fh.seek(offset + size // 2)
            fh.write(bytes([b[0] ^ 0xFF]))
        self.assert_rejected(path, "READ_FAILED")

    def test_missing_file_among_good(self):
        """A file that cannot be opened at all makes validate exit 2 even next to a good file."""
        missing = os.path.join(self.tmp, "also-missing.vox.h5")
        proc = ss.run([ss.VOXFMT_BIN, "validate", self.good, missing, "--json"])
        self.assert_not_crashed(proc)
        self.assertEqual(proc.returncode, 2, describe(proc))
        if proc.stdout.strip():
            entries = ss.check_validate_json(self, proc, [self.good, missing])
            self.assertTrue(entries[self.good]["valid"])
            self.assertIn("FILE_NOT_FOUND", [i["code"] for i in entries[missing]["issues"]])

    def test_usage_errors(self):
        for args in (["validate"], ["no-such-subcommand", self.good], ["inspect"]):
            proc = ss.run([ss.VOXFMT_BIN] + args)
            self.assert_not_crashed(proc)
            self.assertEqual(proc.returncode, 2, "usage error must exit 2\n" + describe(proc))


@ss.requires_bin
class TestHostile(MalformedBase):
    """Damage that used to crash or mislead a reader (issue 15): the global heap of older files, sizes beyond
    what the format allows, filters it does not name."""

    def legacy_vlen_file(self, name):
        """A file as written before 2026-11: variable-length strings, whose bytes live in HDF5's global heap."""
        path = self.bad(name, string_mode="vlen")
        with open(path, "rb") as fh:
            data = fh.read()
        heap = data.find(b"GCOL")
        self.assertGreaterEqual(heap, 0, "the vlen fixture has no global heap collection")
        return path, bytearray(data), heap

    def test_damaged_global_heap_is_refused_without_a_crash(self):
        """Flipped bytes in the heap collection's header and first objects (HDF5 1.10 reads out of bounds on
        most of them: sizes, indices) are READ_FAILED or a finding, never a signal."""
        _, data, heap = self.legacy_vlen_file("vlen_base")
        hangs = {8, 9}  # the collection size: HDF5 loops; covered once below (it costs the reader's timeout)
        refused = 0
        for offset in [o for o in range(0, 64) if o not in hangs]:
            damaged = bytearray(data)
            damaged[heap + offset] ^= 0xFF
            path = self.raw_file("heap_%d.vox.h5" % offset, bytes(damaged))
            proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
            self.assert_not_crashed(proc)
            self.assertIn(proc.returncode, (0, 1), "offset %d\n%s" % (offset, describe(proc)))
            refused += proc.returncode == 1
        self.assertGreater(refused, 20, "too few damaged files refused: the test no longer damages the heap")

    def test_damaged_global_heap_read_failed_in_validate_and_inspect(self):
        _, data, heap = self.legacy_vlen_file("vlen_size")
        data[heap + 26] ^= 0xFF  # the size of heap object 1: HDF5 1.10 reads far out of bounds (SIGSEGV)
        path = self.raw_file("heap_object_size.vox.h5", bytes(data))
        self.assert_rejected(path, "READ_FAILED", message_re="damaged")

    def test_damaged_attribute_message_is_refused_without_a_crash(self):
        """A current file (fixed-length strings): the datatype size in the attribute message of /@format made
        huge; HDF5 1.10 reads out of bounds decoding it (SIGSEGV), so only the isolated read stands between."""
        path = self.bad("attr_message")
        with open(path, "rb") as fh:
            data = bytearray(fh.read())
        name = data.find(b"format\0")
        self.assertGreater(name, 8)
        data[name - 3] ^= 0xFF  # high byte of the message's datatype size (version-1 attribute message)
        path = self.raw_file("attr_message_damaged.vox.h5", bytes(data))
        self.assert_rejected(path, ("READ_FAILED", "NOT_HDF5"))

    def test_looping_global_heap_times_out(self):
        _, data, heap = self.legacy_vlen_file("vlen_loop")
        data[heap + 8] ^= 0xFF  # the collection's size: HDF5 1.10 never returns
        path = self.raw_file("heap_loop.vox.h5", bytes(data))
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"], timeout=60)
        self.assert_not_crashed(proc)
        self.assertEqual(proc.returncode, 1, describe(proc))

    def test_provenance_strings_longer_than_the_limit(self):
        """A 5 MB variable-length string (older files), and a fixed-length one just above the spec's 60,000 bytes
        (HDF5 cannot store a fixed-length attribute of 64 KiB in an object header)."""
        for mode, size in (("vlen", 5 << 20), ("fixed_nullterm", 62000)):
            path = self.bad("huge_string_" + mode, string_mode=mode,
                            values={"/provenance/build_parameters": "{\"x\": \"%s\"}" % ("a" * size)})
            self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="build_parameters")

    def test_voxel_size_1e300_small(self):
        path = self.bad("h_tiny", values={"/voxelmap/voxel_size": np.float64(1e-300)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="voxel_size")

    def test_distance_band_1e30(self):
        path = self.bad("band_huge", values={"/voxelmap/distance_band": np.float64(1e30)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="distance_band")

    def test_filter_the_format_does_not_name(self):
        path = self.bad("lzf", compression="lzf", shuffle=False)
        self.assert_rejected(path, "READ_FAILED", path_contains="/voxelmap/", message_re="filter")

    def test_one_voxel_chunks_over_a_huge_grid(self):
        """2^30 voxels in 1-voxel chunks, none written: refused before HDF5 walks 2^30 chunks."""
        def huge(f):
            del f["/voxelmap/layers"]
            f["/voxelmap"].create_dataset("layers", shape=(1024, 1024, 1024), dtype="<i2", chunks=(1, 1, 1))
            f["/voxelmap"].attrs.create("dims", np.array([1024, 1024, 1024], dtype="<u4"))
        path = self.bad("tiny_chunks", post=huge)
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="layers", message_re="chunks")


if __name__ == "__main__":
    unittest.main()
