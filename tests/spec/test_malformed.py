"""Malformed files: one spec violation at a time, written with h5py from a valid fixture.

For every case `voxfmt validate FILE --json` must exit 1, list the expected issue code with severity
"error" (codes from spec/issue-codes.md), and `voxfmt inspect FILE` must exit non-zero with a message on
stderr naming the file. Neither may crash (a negative return code, i.e. a signal, is a failure).

The base file is the format 2.0 sphere fixture (spec_fixture.write_fixture_h5py); TestMalformedBricks breaks the
2.0 voxelmap (§3.2 bricks and codes, §3.3 lattice), TestMalformedLegacy a 1.1 file's dense grids (§3.4), which
2.0 readers still read and judge by the 1.x rules.

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
        """validate exits 1 with an error issue whose code is one of `codes`, and inspect, a loader, refuses the
        file too (spec §8: every consumer refuses what validate finds an error, full-level rules included)."""
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

    def assert_not_found_at_quick_level(self, path, code):
        """issue-codes.md: `code` is a full-level (semantic) finding; the quick level does not look for it, and
        this file breaks no quick-level rule, so `--level quick` finds it valid."""
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--level", "quick", "--json"])
        self.assert_not_crashed(proc)
        entry = ss.check_validate_json(self, proc, [path])[path]
        self.assertNotIn(code, [i["code"] for i in entry["issues"]], describe(proc))
        self.assertEqual(proc.returncode, 0, "a full-level violation only, yet quick finds errors\n" + describe(proc))


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

    def test_points_int32(self):
        path = self.bad("points_i32", dtypes={"/pointshell/points": "<i4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/pointshell/points")

    def test_points_shape_n_by_2(self):
        path = self.bad("points_n2", values={"/pointshell/points": sf.points_expected()[:, :2]})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="/pointshell/points")

    def test_child_begin_past_n(self):
        cb = sf.child_begin_expected()
        self.assertEqual(int(sf.child_count_expected()[5]), 4)
        cb[5] = sf.N_POINTS + 1  # node 5 keeps child_count 4: range [201, 205) lies outside [0, N)
        path = self.bad("child_past_n", values={"/pointshell/child_begin": cb})
        self.assert_rejected(path, "CHILD_RANGE_INVALID")

    def test_major_version_3(self):
        """§7: a major version the reader does not know (2.0 readers know 1 and 2) is refused, naming it."""
        path = self.bad("v3", format_version=(3, 0))
        self.assert_rejected(path, "VERSION_UNSUPPORTED", message_re=r"(?<![0-9])3(?![0-9])")

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

    def test_max_issues_limits_the_list_never_the_verdict(self):
        # A note first (an unknown object) and an error: listing one finding must still say INVALID, exit 1,
        # and list the error.
        bad = self.bad("note_then_error", values={"/mass_properties/volume": np.float64(-1)})
        with h5py.File(bad, "a") as f:
            f["aaa_notes"] = np.arange(3)
        for args in (["--json"], []):
            proc = ss.run([ss.VOXFMT_BIN, "validate", bad, "--max-issues", "1", *args])
            self.assert_not_crashed(proc)
            self.assertEqual(proc.returncode, 1, describe(proc))
            self.assertIn("VALUE_OUT_OF_RANGE", proc.stdout, describe(proc))
        proc = ss.run([ss.VOXFMT_BIN, "validate", bad, "--max-issues", "1", "--json"])
        entry = ss.check_validate_json(self, proc, [bad])[bad]
        self.assertFalse(entry["valid"])
        self.assertEqual(len(entry["issues"]), 1)
        self.assertGreaterEqual(entry["issues_found"], 2)
        self.assertIn("INVALID", ss.run([ss.VOXFMT_BIN, "validate", bad, "--max-issues", "1"]).stdout)


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

    def test_fixed_length_string_filling_its_type_beyond_the_limit(self):
        """§1: a string of more than 60,000 bytes is VALUE_OUT_OF_RANGE, also where it is null-padded and fills
        its type of 60,001 bytes without a null (it was read as 60,001 bytes of text); 60,000 such bytes are
        fine."""
        def params(size):
            return "{\"x\": \"%s\"}" % ("a" * (size - 9))
        self.assertEqual(len(params(60001)), 60001)
        path = self.bad("nullpad_60001", string_mode="fixed_nullpad_exact",
                        values={"/provenance/build_parameters": params(60001)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="build_parameters")
        path = self.bad("nullpad_60000", string_mode="fixed_nullpad_exact",
                        values={"/provenance/build_parameters": params(60000)})
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))

    def test_shell_thickness_not_finite(self):
        """§3.2: shell_thickness finite, > 0. NaN or infinity is NON_FINITE_VALUE (issue-codes.md), as for every
        other attribute that must be finite; 0 is VALUE_OUT_OF_RANGE."""
        for name, value, code in (("nan", np.nan, "NON_FINITE_VALUE"), ("inf", np.inf, "NON_FINITE_VALUE"),
                                  ("zero", 0.0, "VALUE_OUT_OF_RANGE")):
            path = self.bad("shell_" + name, values={"/voxelmap/shell_thickness": np.float64(value)})
            entry = self.assert_rejected(path, code, path_contains="shell_thickness")
            self.assertEqual([i["code"] for i in entry["issues"] if "shell_thickness" in i["path"]], [code])

    def test_point_spacing_past_the_object(self):
        """§4: point_spacing at most 16 times the bounds' diagonal. 1e300 m validated, and Bullet padded the shape's
        box by half of it (an infinite box in single precision)."""
        path = self.bad("spacing_huge", values={"/pointshell/point_spacing": np.float64(1e300)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="point_spacing",
                             message_re="16 times the object's diagonal")

    def test_voxel_size_1e300_small(self):
        path = self.bad("h_tiny", values={"/voxelmap/voxel_size": np.float64(1e-300)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="voxel_size")

    def test_distance_band_1e30(self):
        path = self.bad("band_huge", values={"/voxelmap/distance_band": np.float64(1e30)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="distance_band")



def code_position(table, i, j, k):
    """(row of brick_values, column) of voxel (i, j, k) (§3.2: column (lk*8 + lj)*8 + li), or None in a coarse
    brick."""
    n = int(table[k // 8, j // 8, i // 8])
    if n < 0:
        return None
    return n, ((k % 8) * 8 + (j % 8)) * 8 + (i % 8)


def voxel_where(mask):
    """The first voxel (i, j, k) where mask ([D, H, W]) is true."""
    k, j, i = np.argwhere(mask)[0]
    return int(i), int(j), int(k)


@ss.requires_bin
class TestMalformedBricks(MalformedBase):
    """Format 2.0 voxelmaps (§3.2 bricks and codes, §3.3 lattice) with one violation each, codes from
    issue-codes.md: structure and ranges (quick level) and the semantic rules (full level: DISTANCE_OUTSIDE_BAND,
    ESTIMATE_MISMATCH, SIGN_MISMATCH)."""

    H = sf.VOXEL_SIZE
    BAND = sf.DISTANCE_BAND

    def encoded(self, grid=sf.FIXTURE_GRID, **kw):
        return sf.encode_voxelmap(grid, **kw)

    def with_code(self, name, i, j, k, code, grid=sf.FIXTURE_GRID, **write):
        """A file whose voxel (i, j, k) has `code` (a function of the old code), everything else conforming."""
        enc = self.encoded(grid, **{key: write[key] for key in ("distance_quantum", "estimate_quantum")
                                    if key in write})
        values = enc["/voxelmap/brick_values"]
        pos = code_position(enc["/voxelmap/bricks"], i, j, k)
        self.assertIsNotNone(pos, "test bug: voxel (%d, %d, %d) lies in a coarse brick" % (i, j, k))
        old = int(values[pos])
        values[pos] = code(old)
        extra = dict(write.pop("values", {}))
        extra["/voxelmap/brick_values"] = values
        return self.bad(name, grid=grid, values=extra, **write), old

    # -- control ----------------------------------------------------------------------------------------------

    def test_good_files_are_valid(self):
        """Controls: the 2.0 fixture and its fine grid (coarse bricks) are accepted at both levels."""
        for path in (self.good, self.bad("good_fine", grid=sf.FINE_GRID)):
            for level in ("quick", "full"):
                proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--level", level, "--json"])
                self.assertEqual(proc.returncode, 0, describe(proc))

    # -- brick table ------------------------------------------------------------------------------------------

    def test_brick_entry_past_the_last_row(self):
        """§3.2: entry n >= 0 names row n of brick_values; n = V names none."""
        table = self.encoded()["/voxelmap/bricks"]
        v = self.encoded()["/voxelmap/brick_values"].shape[0]
        table[1, 0, 1] = v
        path = self.bad("brick_past_v", values={"/voxelmap/bricks": table})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="bricks")

    def test_brick_entry_minus_3(self):
        """§3.2: -1, -2 or a row; "nothing else"."""
        table = self.encoded(sf.FINE_GRID)["/voxelmap/bricks"]
        k = np.argwhere(table == -1)[0]
        table[tuple(k)] = -3
        path = self.bad("brick_minus3", grid=sf.FINE_GRID, values={"/voxelmap/bricks": table})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="bricks")

    def test_brick_values_one_row_short(self):
        """The table names row V - 1 of V value bricks, the dataset holds V - 1 rows."""
        values = self.encoded()["/voxelmap/brick_values"][:-1]
        path = self.bad("rows_short", values={"/voxelmap/brick_values": values})
        self.assert_rejected(path, ("VALUE_OUT_OF_RANGE", "WRONG_SHAPE"))

    # -- dtypes -----------------------------------------------------------------------------------------------

    def test_wrong_dtypes(self):
        """§1: readers MUST reject any other class, width or signedness than the table's (i32 bricks, i16
        brick_values, f32 lattice, u32 brick_edge, f64 quanta and lattice_error)."""
        cases = [
            ("/voxelmap/bricks", "<i2"), ("/voxelmap/bricks", "<i8"), ("/voxelmap/bricks", "<u4"),
            ("/voxelmap/bricks", "<f4"),
            ("/voxelmap/brick_values", "<i4"), ("/voxelmap/brick_values", "<u2"), ("/voxelmap/brick_values", "<f4"),
            ("/voxelmap/lattice", "<f8"), ("/voxelmap/lattice", "<f2"), ("/voxelmap/lattice", "<i4"),
            ("/voxelmap/brick_edge", "<i4"), ("/voxelmap/brick_edge", "<u2"),
            ("/voxelmap/distance_quantum", "<f4"), ("/voxelmap/estimate_quantum", "<f4"),
            ("/voxelmap/lattice_error", "<f4"),
        ]
        for path_, dt in cases:
            with self.subTest(object=path_, dtype=dt):
                name = "dtype_%s_%s" % (sf.split_path(path_)[1], dt.strip("<"))
                path = self.bad(name, dtypes={path_: dt})
                self.assert_rejected(path, "WRONG_DTYPE", path_contains=sf.split_path(path_)[1])

    def test_big_endian_is_not_a_wrong_dtype(self):
        """§1: the big-endian variant of the same type is accepted (control for the cases above)."""
        path = self.bad("be_voxelmap", dtypes={"/voxelmap/bricks": ">i4", "/voxelmap/brick_values": ">i2",
                                               "/voxelmap/lattice": ">f4"})
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))

    # -- shapes -----------------------------------------------------------------------------------------------

    def test_wrong_shapes(self):
        """§3.2: bricks [BD, BH, BW], brick_values [V, 512], lattice [BD + 1, BH + 1, BW + 1], lattice_error [2],
        brick_edge and the quanta scalar."""
        enc = self.encoded()
        table, values, lattice = (enc["/voxelmap/bricks"], enc["/voxelmap/brick_values"], enc["/voxelmap/lattice"])
        cases = [
            ("/voxelmap/bricks", np.concatenate([table, table[:, :, :1]], axis=2)),
            ("/voxelmap/bricks", table.reshape(2, 4)),
            ("/voxelmap/brick_values", values[:, :511]),
            ("/voxelmap/brick_values", values.reshape(-1)),
            ("/voxelmap/brick_values", values.reshape(-1, 8, 8, 8)),
            ("/voxelmap/lattice", lattice[:-1, :-1, :-1]),
            ("/voxelmap/lattice", lattice.reshape(9, 3)),
            ("/voxelmap/lattice_error", np.array([1e-5, 0.0, 0.0])),
            ("/voxelmap/brick_edge", np.array([8, 8], dtype=np.uint32)),
            ("/voxelmap/distance_quantum", np.array([1.0, 1.0]) * sf.default_distance_quantum()),
        ]
        for n, (path_, value) in enumerate(cases):
            with self.subTest(object=path_, shape=value.shape):
                path = self.bad("shape_%d" % n, values={path_: value})
                self.assert_rejected(path, "WRONG_SHAPE", path_contains=sf.split_path(path_)[1])

    def test_dims_disagree_with_the_brick_table(self):
        """dims [17, 15, 15] asks for BW = 3 bricks along x; the table has 2."""
        path = self.bad("dims_17", values={"/voxelmap/dims": np.array([17, 15, 15], dtype=np.uint32)})
        self.assert_rejected(path, "WRONG_SHAPE")

    def test_dims_beyond_the_lattice_limit(self):
        """§3.2: (BW + 1)(BH + 1)(BD + 1) <= 2^31 - 1; 65535^3 voxels give 8193^3 lattice points."""
        path = self.bad("dims_huge", values={"/voxelmap/dims": np.array([65535] * 3, dtype=np.uint32)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="dims")

    # -- missing objects --------------------------------------------------------------------------------------

    def test_missing_2_0_objects(self):
        """§3.2: brick_edge, distance_quantum, estimate_quantum, lattice_error, bricks, brick_values and lattice
        are REQUIRED."""
        for path_ in sf.VOXELMAP_2_0_PATHS:
            with self.subTest(object=path_):
                path = self.bad("missing_" + sf.split_path(path_)[1], omit=[path_])
                self.assert_rejected(path, "MISSING_OBJECT", path_contains=sf.split_path(path_)[1])

    def test_lattice_a_group(self):
        path = self.bad("lattice_group", omit=["/voxelmap/lattice"],
                        post=lambda f: f.create_group("/voxelmap/lattice"))
        self.assert_rejected(path, "WRONG_KIND", path_contains="lattice")

    def test_dense_1_x_grids_labelled_2_0(self):
        """A 1.1 file's voxelmap (layers, distances) under format_version [2, 0]: the 2.0 objects are missing."""
        path = sf.write_legacy_fixture_h5py(os.path.join(self.tmp, "dense_as_2_0.vox.h5"), format_version=(2, 0))
        self.assert_rejected(path, "MISSING_OBJECT", path_contains="/voxelmap")

    def test_bricks_labelled_1_1(self):
        """A 2.0 voxelmap under format_version [1, 1]: §3.4's layers and distances are missing."""
        path = self.bad("bricks_as_1_1", format_version=(1, 1))
        self.assert_rejected(path, "MISSING_OBJECT", path_contains="/voxelmap")

    # -- lattice values ---------------------------------------------------------------------------------------

    def test_lattice_negative(self):
        """§3.2: lattice distances are >= 0."""
        lattice = self.encoded()["/voxelmap/lattice"]
        lattice[1, 1, 1] = -lattice[1, 1, 1]
        path = self.bad("lattice_negative", values={"/voxelmap/lattice": lattice})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="lattice")

    def test_lattice_not_finite(self):
        """§3.2: lattice distances are finite."""
        for bad_value in (np.nan, np.inf):
            with self.subTest(value=bad_value):
                lattice = self.encoded()["/voxelmap/lattice"]
                lattice[2, 0, 1] = bad_value
                path = self.bad("lattice_%s" % bad_value, values={"/voxelmap/lattice": lattice})
                self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="lattice")

    # -- attributes -------------------------------------------------------------------------------------------

    def test_brick_edge_not_8(self):
        for edge in (16, 0, 4):
            with self.subTest(brick_edge=edge):
                path = self.bad("edge_%d" % edge, values={"/voxelmap/brick_edge": np.uint32(edge)})
                self.assert_rejected(path, "BAD_ATTRIBUTE_VALUE", path_contains="brick_edge")

    def test_quanta_too_small_for_the_band(self):
        """§3.2: 16383 * quantum >= distance_band * h (codes are 15-bit), for either quantum."""
        small = self.BAND * self.H / 16383 * 0.99
        for name in ("distance_quantum", "estimate_quantum"):
            with self.subTest(attribute=name):
                path = self.bad(name + "_small", values={"/voxelmap/" + name: np.float64(small)})
                self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains=name)

    def test_quanta_not_positive(self):
        for name in ("distance_quantum", "estimate_quantum"):
            for value in (0.0, -sf.default_distance_quantum()):
                with self.subTest(attribute=name, value=value):
                    path = self.bad("%s_%g" % (name, value), values={"/voxelmap/" + name: np.float64(value)})
                    self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains=name)

    def test_quanta_not_finite(self):
        for name in ("distance_quantum", "estimate_quantum"):
            for value in (np.nan, np.inf):
                with self.subTest(attribute=name, value=value):
                    path = self.bad("%s_%s" % (name, value), values={"/voxelmap/" + name: np.float64(value)})
                    self.assert_rejected(path, "NON_FINITE_VALUE", path_contains=name)

    def test_lattice_error_out_of_range(self):
        """§3.2: eps0 >= 0, 0 <= eps1 <= 1, both finite."""
        for n, err in enumerate(((-0.1, 0.0), (1e-5, 1.5), (1e-5, -0.1))):
            with self.subTest(lattice_error=err):
                path = self.bad("lattice_error_%d" % n, values={"/voxelmap/lattice_error": np.array(err)})
                self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="lattice_error")
        path = self.bad("lattice_error_nan", values={"/voxelmap/lattice_error": np.array([np.nan, 0.0])})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="lattice_error")

    def test_lattice_error_or_shell_thickness_past_what_a_reader_holds(self):
        """§3.2 (2.2): eps0 <= 32767 voxels and T <= 32767 voxels. A lattice error of 1e300 lifted the lattice's
        ceiling to infinity: lattice values of 3e38 m validated, and the runtime read NaN distances."""
        path = self.bad("lattice_error_huge", values={"/voxelmap/lattice_error": np.array([1e300, 0.1])})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="lattice_error")
        path = self.bad("lattice_error_32768", values={"/voxelmap/lattice_error": np.array([32768.0, 0.0])})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="lattice_error")
        path = self.bad("shell_too_thick", values={"/voxelmap/shell_thickness": np.float64(40000 * self.H)})
        entry = self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="shell_thickness")
        self.assertIn("32767 voxels", " ".join(i["message"] for i in entry["issues"]))

    # -- semantic rules (full level) ----------------------------------------------------------------------------

    def test_stored_distance_beyond_the_band(self):
        """§3.1: distances are stored only for |d| <= distance_band * h. With a distance_quantum coarse enough for
        4 bands (allowed: 16383 q >= band h), a voxel 2.5-3 voxels out gets its exact distance as a stored code:
        right value, right sign, but beyond the band -> DISTANCE_OUTSIDE_BAND (full level)."""
        q = 4 * self.BAND * self.H / 16383
        d = sf.signed_distance_grid()
        i, j, k = voxel_where((d > (self.BAND + 0.5) * self.H) & (d < (self.BAND + 1.0) * self.H))
        path, old = self.with_code("beyond_band", i, j, k, lambda c: 2 * int(round(d[k, j, i] / q)) + 1,
                                   distance_quantum=q)
        self.assertEqual(old % 2, 0, "test bug: the voxel had a stored distance already")
        self.assert_rejected(path, "DISTANCE_OUTSIDE_BAND", path_contains="/voxelmap")
        self.assert_not_found_at_quick_level(path, "DISTANCE_OUTSIDE_BAND")

    def test_band_edge_is_half_a_quantum_beyond_the_band(self):
        """issue-codes.md: DISTANCE_OUTSIDE_BAND is a stored distance beyond band*h by more than half a quantum.
        With q = 4 band h / 16383 the band edge is 4095.75 q: a stored 4096 q (0.25 q beyond) is accepted, 4097 q
        (1.25 q beyond) is not."""
        q = 4 * self.BAND * self.H / 16383
        d = sf.signed_distance_grid()
        i, j, k = voxel_where((d > (self.BAND + 0.5) * self.H) & (d < (self.BAND + 1.0) * self.H))
        inside, _ = self.with_code("band_edge_4096", i, j, k, lambda c: 2 * 4096 + 1, distance_quantum=q)
        proc = ss.run([ss.VOXFMT_BIN, "validate", inside, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))
        beyond, _ = self.with_code("band_edge_4097", i, j, k, lambda c: 2 * 4097 + 1, distance_quantum=q)
        self.assert_rejected(beyond, "DISTANCE_OUTSIDE_BAND", path_contains="/voxelmap")

    def test_estimate_code_disagrees_with_the_lattice(self):
        """§3.2: an even code MUST be the lattice's estimate rounded to the nearest step; here 8 steps (half a
        voxel) farther out at the grid's corner voxel -> ESTIMATE_MISMATCH (full level)."""
        path, old = self.with_code("estimate_off", 0, 0, 0, lambda c: c + 2 * 8)
        self.assertEqual(old % 2, 0)
        self.assertGreater(old, 0)
        self.assert_rejected(path, "ESTIMATE_MISMATCH", path_contains="/voxelmap")
        self.assert_not_found_at_quick_level(path, "ESTIMATE_MISMATCH")

    def test_estimate_code_one_step_off(self):
        """§3.2: the code is the estimate rounded to the *nearest* step. At the corner voxel the unrounded estimate
        lies within 0.1 step of the coded one (checked here with the spec's decoder), so one step more is at least
        0.9 step (> half a step) from it -> ESTIMATE_MISMATCH (full level)."""
        vm = ss.decode_voxelmap(self.good)
        unrounded = vm.lattice_estimate[0, 0, 0]  # outside: positive
        self.assertLess(abs(unrounded - vm.values[0, 0, 0]), 0.1 * vm.estimate_quantum)
        for step in (1, -1):
            with self.subTest(step=step):
                path, old = self.with_code("estimate_step_%d" % step, 0, 0, 0, lambda c: c + 2 * step)
                self.assertEqual(old % 2, 0)
                self.assert_rejected(path, "ESTIMATE_MISMATCH", path_contains="/voxelmap")

    def test_sign_rule_only_for_closed_surfaces(self):
        """issue-codes.md: SIGN_MISMATCH is checked for closed surfaces only. The flipped centre voxel of
        test_estimate_sign_flipped_inside, in an asset whose build warnings say OPEN_BORDER, is valid."""
        warnings = '[{"code": "OPEN_BORDER", "message": "the surface has holes"}]'
        path, old = self.with_code("estimate_sign_open", 7, 7, 7, lambda c: -c,
                                   values={"/provenance/build_warnings": warnings})
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))

    def test_estimate_code_zero(self):
        """§3.2: an estimate is never 0 (a 0 code would be an even code of estimate 0)."""
        path, old = self.with_code("estimate_zero", 0, 0, 0, lambda c: 0)
        self.assertEqual(old % 2, 0)
        self.assert_rejected(path, "ESTIMATE_MISMATCH", path_contains="/voxelmap")

    def test_lattice_raised_under_unchanged_codes(self):
        """The lattice point at the grid's far corner (voxel (14, 14, 14)) one voxel higher, lattice_error
        widened to allow it (so the lattice itself stays valid): the value bricks' codes no longer are its
        interpolation -> ESTIMATE_MISMATCH (full level)."""
        lattice = self.encoded()["/voxelmap/lattice"]
        lattice[2, 2, 2] += np.float32(self.H)
        path = self.bad("lattice_raised", values={"/voxelmap/lattice": lattice,
                                                  "/voxelmap/lattice_error": np.array([2.0, 0.0])})
        self.assert_rejected(path, "ESTIMATE_MISMATCH", path_contains="/voxelmap")
        self.assert_not_found_at_quick_level(path, "ESTIMATE_MISMATCH")

    def test_stored_sign_flipped_deep_in_the_band(self):
        """A stored distance of about -1.5 voxels (inside) written as +1.5: its 6-neighbours are inside and
        |d1| + |d2| > h, so the surface cannot pass between them -> SIGN_MISMATCH (full level)."""
        d = sf.signed_distance_grid()
        i, j, k = voxel_where((d < -1.4 * self.H) & (d > -1.6 * self.H))
        path, old = self.with_code("stored_sign", i, j, k, lambda c: -(c >> 1) * 2 + 1)
        self.assertEqual(old % 2, 1)
        self.assertLess(old >> 1, 0)
        self.assert_rejected(path, "SIGN_MISMATCH", path_contains="/voxelmap")
        self.assert_not_found_at_quick_level(path, "SIGN_MISMATCH")

    def test_estimate_sign_flipped_inside(self):
        """The sphere's centre voxel (an estimate, 5 voxels deep) coded outside: SIGN_MISMATCH (full level)."""
        path, old = self.with_code("estimate_sign", 7, 7, 7, lambda c: -c)
        self.assertEqual(old % 2, 0)
        self.assertLess(old, 0)
        self.assert_rejected(path, "SIGN_MISMATCH", path_contains="/voxelmap")
        self.assert_not_found_at_quick_level(path, "SIGN_MISMATCH")

    def test_coarse_brick_sign_flipped(self):
        """FINE_GRID: a coarse inside brick (-2) amid inside bricks marked outside (-1) -> SIGN_MISMATCH."""
        table = self.encoded(sf.FINE_GRID)["/voxelmap/bricks"]
        inside = np.argwhere(table == -2)
        self.assertGreater(len(inside), 0)
        table[tuple(inside[len(inside) // 2])] = -1
        path = self.bad("coarse_sign", grid=sf.FINE_GRID, values={"/voxelmap/bricks": table})
        self.assert_rejected(path, "SIGN_MISMATCH", path_contains="/voxelmap")
        self.assert_not_found_at_quick_level(path, "SIGN_MISMATCH")

    # -- reading ----------------------------------------------------------------------------------------------

    def test_filter_the_format_does_not_name(self):
        """§1: a dataset with a filter other than deflate, shuffle, fletcher32 is refused before decoding."""
        for path_ in sf.VOXELMAP_2_0_DATASETS:
            with self.subTest(dataset=path_):
                path = self.bad("lzf_" + sf.split_path(path_)[1],
                                post=lambda f, p=path_: sf.replace_dataset(f, p, chunks=True, compression="lzf"))
                self.assert_rejected(path, "READ_FAILED", path_contains=path_, message_re="filter")

    def test_corrupt_chunk_fletcher32(self):
        """A flipped byte in a fletcher32-protected chunk of /voxelmap/brick_values -> READ_FAILED."""
        path = self.bad("bad_chunk_values", fletcher32=True)
        with h5py.File(path, "r") as f:
            info = f["/voxelmap/brick_values"].id.get_chunk_info(0)
            offset, size = info.byte_offset, info.size
        with open(path, "r+b") as fh:
            fh.seek(offset + size // 2)
            b = fh.read(1)
            fh.seek(offset + size // 2)
            fh.write(bytes([b[0] ^ 0xFF]))
        self.assert_rejected(path, "READ_FAILED")

    def test_one_entry_chunks_over_a_huge_brick_table(self):
        """2^30 brick table entries in 1-entry chunks, none written (8192^3 voxels): refused before HDF5 walks
        2^30 chunks (§1: at most 2^22 chunks per dataset)."""
        def huge(f):
            del f["/voxelmap/bricks"]
            f["/voxelmap"].create_dataset("bricks", shape=(1024, 1024, 1024), dtype="<i4", chunks=(1, 1, 1))
            f["/voxelmap"].attrs.create("dims", np.array([8192, 8192, 8192], dtype="<u4"))
        path = self.bad("tiny_chunks_bricks", post=huge)
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="bricks", message_re="chunks")


@ss.requires_bin
class TestMalformedLegacy(MalformedBase):
    """Legacy 1.x files (§3.4: dense layers and distances), one violation at a time: a 2.0 reader still reads
    them (by the legacy path), so it must still judge them by the 1.x rules."""

    def bad(self, name, **kw):
        return sf.write_legacy_fixture_h5py(os.path.join(self.tmp, name + ".vox.h5"), **kw)

    def test_good_legacy_file_is_valid(self):
        """Control: the unmodified 1.1 file is accepted."""
        path = self.bad("good_1_1")
        proc = ss.run([ss.VOXFMT_BIN, "validate", path, "--json"])
        self.assertEqual(proc.returncode, 0, describe(proc))

    def test_layers_float32(self):
        path = self.bad("layers_f32", dtypes={"/voxelmap/layers": "<f4"})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/voxelmap/layers")

    def test_distances_shape_not_dims(self):
        path = self.bad("dist_shape", values={"/voxelmap/distances": sf.distances_expected()[:, :, :-1]})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="/voxelmap/distances")

    def test_layers_unsigned(self):
        path = self.bad("layers_u16", dtypes={"/voxelmap/layers": "<u2"},
                        values={"/voxelmap/layers": np.abs(sf.layers_expected())})
        self.assert_rejected(path, "WRONG_DTYPE", path_contains="/voxelmap/layers")

    def test_layers_shape_swapped(self):
        lay = np.zeros((sf.DIM, sf.DIM, sf.DIM + 1), dtype=np.int16)
        path = self.bad("layers_shape", values={"/voxelmap/layers": lay})
        self.assert_rejected(path, "WRONG_SHAPE", path_contains="/voxelmap/layers")

    def test_stored_distance_infinite(self):
        d = sf.distances_expected()
        k, j, i = np.argwhere(~np.isnan(d))[0]
        d[k, j, i] = np.inf
        path = self.bad("dist_inf", values={"/voxelmap/distances": d})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="distances")

    def test_layer_distance_mismatch(self):
        """§3.4 (full): where a distance is stored the layer MUST be floor(-d/h + 1/2)."""
        lay = sf.layers_expected()
        k, j, i = np.argwhere(sf.stored_mask() & (lay == 0))[0]
        lay[k, j, i] = 1
        path = self.bad("layer_mismatch", values={"/voxelmap/layers": lay})
        self.assert_rejected(path, "LAYER_DISTANCE_MISMATCH", path_contains="/voxelmap/layers")

    def test_layer_outside_band_too_small(self):
        """§3.4 (full): a layer without a stored distance has |v| >= floor(distance_band + 1/2)."""
        lay = sf.layers_expected()
        k, j, i = np.argwhere(~sf.stored_mask() & (lay == -3))[0]  # outside, just beyond the band
        lay[k, j, i] = -1
        path = self.bad("layer_too_small", values={"/voxelmap/layers": lay})
        self.assert_rejected(path, "LAYER_OUTSIDE_BAND_TOO_SMALL", path_contains="/voxelmap/layers")

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

    def test_voxel_size_infinite_legacy(self):
        """§3.2: voxel_size finite, in a 1.1 file: NON_FINITE_VALUE at the default (full) level too."""
        path = self.bad("h_inf_legacy", values={"/voxelmap/voxel_size": np.float64(np.inf)})
        self.assert_rejected(path, "NON_FINITE_VALUE", path_contains="voxel_size")

    def test_findings_name_only_objects_of_the_file(self):
        """§8: a finding names the HDF5 path it concerns. A 1.1 file with distance_band 0.5 breaks one rule of
        its own attributes; findings about 2.0 objects it does not have (quanta, bricks, lattice: what a reader
        converts it into, §3.4) would blame the file for the reader's conversion."""
        path = self.bad("band_half_legacy", values={"/voxelmap/distance_band": np.float64(0.5)})
        entry = self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="distance_band")
        foreign = ["@" + sf.split_path(p)[1] if p in ("/voxelmap/brick_edge", "/voxelmap/distance_quantum",
                                                        "/voxelmap/estimate_quantum", "/voxelmap/lattice_error")
                   else p for p in sf.VOXELMAP_2_0_PATHS]
        blamed = [(i["code"], i["path"]) for i in entry["issues"] if any(f in i["path"] for f in foreign)]
        self.assertEqual(blamed, [], "findings about objects a 1.1 file does not have")

    def test_stored_distance_beyond_the_band_legacy(self):
        """§3.1: distances are stored only for |d| <= distance_band * h, in 1.x files too. A voxel 2.5-3 voxels out
        storing its exact distance (its layer agrees) was read as the band's edge, its code clamped, and judged
        valid: DISTANCE_OUTSIDE_BAND (full level), as in a 2.x file."""
        h, band = sf.VOXEL_SIZE, sf.DISTANCE_BAND
        d = sf.signed_distance_grid()
        dist = sf.distances_expected()
        i, j, k = voxel_where((d > (band + 0.5) * h) & (d < (band + 1.0) * h) & np.isnan(dist))
        dist[k, j, i] = np.float32(d[k, j, i])
        self.assertEqual(sf.layers_expected()[k, j, i], np.floor(-d[k, j, i] / h + 0.5), "test bug: layer")
        path = self.bad("beyond_band_legacy", values={"/voxelmap/distances": dist})
        self.assert_rejected(path, "DISTANCE_OUTSIDE_BAND", path_contains="/voxelmap/distances")
        self.assert_not_found_at_quick_level(path, "DISTANCE_OUTSIDE_BAND")

    def test_voxel_rules_reported_once_naming_the_files_grids(self):
        """issue-codes.md: each kind of finding once per file; §8: a finding names the file's object. A stored
        distance deep inside with its sign flipped (its layer agrees) breaks the voxel rules, which were checked
        twice (on the 1.x grid, then on its conversion to bricks): DISTANCE_JUMP came twice, the second time
        with SIGN_MISMATCH at /voxelmap/brick_values, an object a 1.1 file does not have."""
        h = sf.VOXEL_SIZE
        dist, lay = sf.distances_expected(), sf.layers_expected()
        k, j, i = np.argwhere(np.isfinite(dist) & (dist < -1.5 * h))[0]
        dist[k, j, i] = -dist[k, j, i]
        lay[k, j, i] = np.floor(-float(dist[k, j, i]) / h + 0.5)
        path = self.bad("sign_flipped_legacy", values={"/voxelmap/distances": dist, "/voxelmap/layers": lay})
        entry = self.assert_rejected(path, ("DISTANCE_JUMP", "SIGN_MISMATCH"))
        codes = [i["code"] for i in entry["issues"]]
        self.assertIn("SIGN_MISMATCH", codes)
        self.assertEqual(len(codes), len(set(codes)), "a kind of finding reported twice: %s" % entry["issues"])
        own = ("/voxelmap/layers", "/voxelmap/distances")
        self.assertEqual([(i["code"], i["path"]) for i in entry["issues"] if i["path"] not in own], [],
                         "findings about objects a 1.1 file does not have")

    def test_voxel_size_1e300_small_legacy(self):
        """§3.2 range of voxel_size, in a 1.1 file: VALUE_OUT_OF_RANGE at the default (full) level too."""
        path = self.bad("h_tiny", values={"/voxelmap/voxel_size": np.float64(1e-300)})
        self.assert_rejected(path, "VALUE_OUT_OF_RANGE", path_contains="voxel_size")


if __name__ == "__main__":
    unittest.main()
