"""`voxfmt build` on bad input: a clear error naming the problem, a non-zero exit, and no output file."""
import json
import os
import subprocess
import tempfile
import unittest

VOXFMT = os.environ.get("VOXFMT_BIN")
MESHES = os.environ.get("VOXFMT_SAMPLE_MESHES", "")


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class BuildBadInput(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.out = os.path.join(self.dir.name, "out.vox.h5")

    def tearDown(self):
        self.dir.cleanup()

    def write(self, name, text):
        path = os.path.join(self.dir.name, name)
        with open(path, "w") as f:
            f.write(text)
        return path

    def build(self, *args):
        return subprocess.run([VOXFMT, "build", *args, "-o", self.out, "--json"], capture_output=True, text=True, timeout=120)

    def expect_error(self, mesh, code, *extra):
        r = self.build(mesh, *extra)
        self.assertGreater(r.returncode, 0, r.stdout + r.stderr)  # an error, not a crash (negative = signal)
        self.assertIn(code, r.stderr)
        self.assertEqual(json.loads(r.stdout)["code"], code)
        self.assertFalse(os.path.exists(self.out), "no output file may be left behind")
        self.assertEqual([f for f in os.listdir(self.dir.name) if "partial" in f], [])
        return r

    def test_missing_file(self):
        r = self.expect_error(os.path.join(self.dir.name, "nope.off"), "INPUT_NOT_FOUND")
        self.assertIn("nope.off", r.stderr)

    def test_unsupported_format(self):
        self.expect_error(self.write("mesh.xyzzy", "hello\n"), "UNSUPPORTED_FORMAT")

    def test_garbage_in_a_known_format(self):
        self.expect_error(self.write("broken.obj", "v 0 0 0\nf 1 2 3 4 5\nthis is not obj\n"), "IMPORT_FAILED")

    def test_empty_scene(self):
        self.expect_error(self.write("empty.off", "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n"), "EMPTY_SCENE")

    def test_non_finite_coordinates(self):
        text = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\nnan 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n"
        self.expect_error(self.write("nan.off", text), "NON_FINITE_COORDINATES")

    def test_degenerate_mesh(self):
        r = self.expect_error(self.write("line.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n"), "EMPTY_SCENE")
        self.assertIn("line.off", r.stderr)

    def test_flat_sheet_bakes_as_a_shell(self):
        text = "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n"
        r = self.build(self.write("flat.off", text), "--resolution", "32", "--points", "500")
        self.assertEqual(r.returncode, 0, r.stderr)
        summary = json.loads(r.stdout)
        self.assertIn("SHELL_MODE", [w["code"] for w in summary["warnings"]])
        # A 1 m square, 2 voxels (1/16 m) thick: volume = area x thickness.
        self.assertAlmostEqual(summary["volume"], 1.0 / 16, delta=1e-9)

    def test_bad_option_is_a_usage_error(self):
        tet = self.write("tet.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n")
        r = subprocess.run([VOXFMT, "build", tet, "-o", self.out, "--resolution", "10", "--voxel-size", "0.1"],
                           capture_output=True, text=True)
        self.assertEqual(r.returncode, 2)
        self.assertFalse(os.path.exists(self.out))

    def test_good_input_writes_a_valid_asset(self):
        tet = self.write("tet.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n")
        r = self.build(tet, "--resolution", "16", "--points", "200")
        self.assertEqual(r.returncode, 0, r.stderr)
        summary = json.loads(r.stdout)
        self.assertEqual(summary["status"], "ok")
        self.assertAlmostEqual(summary["volume"], 1 / 6, places=12)
        for stage in ("import", "repair", "voxelmap", "point shell", "sphere tree", "write"):
            self.assertIn(stage, summary["timings_s"])
        v = subprocess.run([VOXFMT, "validate", self.out], capture_output=True, text=True)
        self.assertEqual(v.returncode, 0, v.stdout)


if __name__ == "__main__":
    unittest.main()
