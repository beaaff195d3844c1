"""`voxfmt export ASSET --nvdb OUT`: the file NanoVDB's own tools accept (nanovdb_validate, nanovdb_print, from
Debian's libnanovdb-tools), its JSON summary, and the refusals: a damaged asset is refused with its code before
anything is written, bad arguments exit 2. (The grids' contents are checked against the runtime with NanoVDB's
reader and sampler in tests/engines/test_layouts.cpp, and with Warp in python/tests/test_warp.py.)"""
import json
import os
import shutil
import struct
import subprocess
import tempfile
import unittest

import h5py
import numpy as np

VOXFMT = os.environ.get("VOXFMT_BIN")
MESHES = os.environ.get("VOXFMT_SAMPLE_MESHES")


class ExportCli(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        cls.dir = cls.tmp.name
        cls.asset = os.path.join(cls.dir, "bunny.vox.h5")
        r = subprocess.run([VOXFMT, "build", os.path.join(MESHES, "bunny00.off"), "-o", cls.asset, "--resolution",
                            "48", "--points", "500", "-q"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def export(self, *args, asset=None):
        return subprocess.run([VOXFMT, "export", asset or self.asset, *args], capture_output=True, text=True,
                              timeout=60)

    def test_json_summary_and_nanovdb_header(self):
        out = os.path.join(self.dir, "bunny.nvdb")
        r = self.export("--nvdb", out, "--json")
        self.assertEqual(r.returncode, 0, r.stderr)
        summary = json.loads(r.stdout)
        self.assertEqual(summary["grids"], ["distance", "coarse"])
        self.assertEqual(summary["bytes"], os.path.getsize(out))
        self.assertTrue(summary["compressed"])
        with h5py.File(self.asset, "r") as f:
            voxelmap = f["voxelmap"]
            h = float(voxelmap.attrs["voxel_size"])
            self.assertAlmostEqual(summary["level_set_width"], (float(voxelmap.attrs["distance_band"]) - 0.5) * h)
            # The level set's leaves are the asset's value bricks.
            self.assertEqual(summary["distance_leaves"], voxelmap["brick_values"].shape[0])
        with open(out, "rb") as f:
            magic, version, grids, codec = struct.unpack("<QIHH", f.read(16))
        self.assertEqual(magic.to_bytes(8, "little"), b"NanoVDB0")  # NanoVDB 32.4 files (Warp reads them too)
        self.assertEqual(version >> 21, 32)  # NanoVDB's major version, the one Warp reads
        self.assertEqual((grids, codec), (2, 1))  # two grids, ZIP

    def test_nanovdb_tools_accept_the_file(self):
        if not shutil.which("nanovdb_validate"):
            self.skipTest("nanovdb_validate not installed (Debian: libnanovdb-tools)")
        for flags in ([], ["--uncompressed"], ["--width", "6"]):
            out = os.path.join(self.dir, "tools.nvdb")
            r = self.export("--nvdb", out, *flags)
            self.assertEqual(r.returncode, 0, r.stderr)
            self.assertIn("NanoVDB grids", r.stdout)
            v = subprocess.run(["nanovdb_validate", "-v", out], capture_output=True, text=True, timeout=60)
            self.assertEqual(v.returncode, 0, v.stdout + v.stderr)
            self.assertIn('Grid named "distance": passed', v.stdout)
            self.assertIn('Grid named "coarse": passed', v.stdout)
            p = subprocess.run(["nanovdb_print", "-l", out], capture_output=True, text=True, timeout=60)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertRegex(p.stdout, r"distance\s+float\s+SDF")

    def test_a_damaged_asset_is_refused_before_anything_is_written(self):
        damaged = os.path.join(self.dir, "damaged.vox.h5")
        shutil.copy(self.asset, damaged)
        with h5py.File(damaged, "r+") as f:
            codes = f["voxelmap/brick_values"][()]
            stored = np.argwhere((codes & 1) == 1)
            row, column = stored[len(stored) // 2]
            codes[row, column] = -codes[row, column]  # a stored distance with the wrong sign
            f["voxelmap/brick_values"][...] = codes
        out = os.path.join(self.dir, "damaged.nvdb")
        r = self.export("--nvdb", out, asset=damaged)
        self.assertEqual(r.returncode, 1, r.stdout + r.stderr)
        self.assertRegex(r.stderr, r"voxfmt export: error: [A-Z_]+: ")
        self.assertFalse(os.path.exists(out))
        self.assertEqual([n for n in os.listdir(self.dir) if n.startswith("damaged.nvdb")], [])

    def test_a_dash_is_refused_not_written_as_a_file_named_dash_and_dot_slash_dash_is_that_file(self):
        r = subprocess.run([VOXFMT, "export", self.asset, "--nvdb", "-"], cwd=self.dir, capture_output=True,
                           text=True, timeout=60)
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
        self.assertIn("BAD_OPTION: --nvdb: '-' (standard output) is not supported", r.stderr)
        self.assertFalse(os.path.exists(os.path.join(self.dir, "-")))
        r = subprocess.run([VOXFMT, "export", self.asset, "--nvdb", "./-"], cwd=self.dir, capture_output=True,
                           text=True, timeout=60)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(os.path.isfile(os.path.join(self.dir, "-")))
        os.remove(os.path.join(self.dir, "-"))

    def test_a_name_as_long_as_the_file_system_allows_is_written(self):
        # Its temporary's name (the name and ".partial-PID-N") would pass 255 bytes: it takes a shortened stem.
        out = os.path.join(self.dir, "n" * 250 + ".nvdb")
        r = self.export("--nvdb", out)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(os.path.isfile(out))
        self.assertEqual([n for n in os.listdir(self.dir) if ".partial-" in n], [])
        os.remove(out)

    def test_temporaries_of_a_killed_export_are_removed_by_the_next(self):
        out = os.path.join(self.dir, "again.nvdb")
        child = subprocess.Popen(["true"])
        child.wait()  # a process number that is gone
        left = out + ".partial-%d-0" % child.pid
        alive = out + ".partial-%d-0" % os.getpid()  # a write still running: not touched
        kept = out + ".partial-%d-0.keep" % child.pid  # not a temporary's name: someone's file
        for path in (left, alive, kept):
            with open(path, "wb") as f:
                f.write(b"x" * 1000)
        folder = out + ".partial-%d-1" % child.pid  # a folder is never a temporary
        os.makedirs(folder)
        r = self.export("--nvdb", out)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertFalse(os.path.exists(left))
        for path in (alive, kept, folder):
            self.assertTrue(os.path.exists(path), path)
        os.remove(alive)
        os.remove(kept)
        os.rmdir(folder)

    def test_a_grid_too_far_from_its_origin_for_float_is_refused(self):
        # Shifted 1e16 m, the asset is valid, but NanoVDB's float transform gave it a voxel of 0.
        far = os.path.join(self.dir, "far.vox.h5")
        shutil.copy(self.asset, far)
        with h5py.File(far, "r+") as f:
            shift = np.array([1e16, 0, 0])
            f["voxelmap"].attrs["origin"] += shift
            f.attrs["bounds_min"] += shift
            f.attrs["bounds_max"] += shift
            f["mass_properties"].attrs["center_of_mass"] += shift
            f["pointshell/points"][...] += shift
            f["pointshell/sphere_centers"][...] += shift
        out = os.path.join(self.dir, "far.nvdb")
        r = self.export("--nvdb", out, asset=far)
        self.assertEqual(r.returncode, 1, r.stdout + r.stderr)
        self.assertIn("VALUE_OUT_OF_RANGE", r.stderr)
        self.assertIn("2^20", r.stderr)
        self.assertFalse(os.path.exists(out))

    def test_bad_arguments_and_missing_files_exit_2(self):
        missing = self.export("--nvdb", os.path.join(self.dir, "x.nvdb"), asset=os.path.join(self.dir, "none.vox.h5"))
        self.assertEqual(missing.returncode, 2)
        self.assertIn("FILE_NOT_FOUND", missing.stderr)
        no_output = self.export()
        self.assertEqual(no_output.returncode, 2)
        self.assertIn("--nvdb", no_output.stderr)
        narrow = self.export("--nvdb", os.path.join(self.dir, "x.nvdb"), "--width", "0.1")
        self.assertEqual(narrow.returncode, 2)
        unwritable = self.export("--nvdb", os.path.join(self.dir, "no-such-folder", "x.nvdb"))
        self.assertEqual(unwritable.returncode, 2)
        self.assertIn("WRITE_FAILED", unwritable.stderr)


if __name__ == "__main__":
    unittest.main()
