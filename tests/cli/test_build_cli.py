"""`voxfmt build` on bad input: a clear error naming the problem, a non-zero exit, and no output file."""
import json
import os
import stat
import subprocess
import tempfile
import time
import unittest

from cli_case import FolderCase

VOXFMT = os.environ.get("VOXFMT_BIN")
MESHES = os.environ.get("VOXFMT_SAMPLE_MESHES", "")


def as_nobody():
    """preexec_fn: the child runs as the user nobody where the test runs as root (permissions do not stop root)."""
    if os.geteuid() == 0:
        os.setgroups([])
        os.setgid(65534)
        os.setuid(65534)


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class CommandLine(unittest.TestCase):
    def test_no_command_prints_the_overview_and_an_unknown_one_is_named(self):
        r = subprocess.run([VOXFMT], capture_output=True, text=True, timeout=30)
        self.assertEqual(r.returncode, 2)
        self.assertIn("Usage: voxfmt [OPTIONS] SUBCOMMAND", r.stderr)
        self.assertIn("build", r.stderr)
        r = subprocess.run([VOXFMT, "biuld", "x.obj"], capture_output=True, text=True, timeout=30)
        self.assertEqual(r.returncode, 2)
        self.assertIn("unknown command 'biuld'", r.stderr)
        self.assertIn("build batch inspect", r.stderr)


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class BuildBadInput(FolderCase):
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

    @unittest.skipUnless(os.geteuid() == 0, "needs root to run the bake as another user")
    def test_a_mesh_the_user_cannot_read_is_input_not_found(self):
        # Its permissions, not its content: it was IMPORT_FAILED (the importer's "Unable to open file").
        mesh = self.write("locked.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n")
        os.chmod(mesh, 0)
        os.chmod(self.dir.name, 0o777)
        r = subprocess.run([VOXFMT, "build", mesh, "-o", self.out, "--json"], capture_output=True, text=True,
                           timeout=120, preexec_fn=as_nobody)
        self.assertEqual(json.loads(r.stdout)["code"], "INPUT_NOT_FOUND", r.stderr)
        self.assertIn("Permission denied", r.stderr)
        self.assertFalse(os.path.exists(self.out))

    def test_a_folder_or_a_pipe_is_not_a_mesh(self):
        pipe = os.path.join(self.dir.name, "pipe.obj")
        os.mkfifo(pipe)
        folder = os.path.join(self.dir.name, "folder.obj")
        os.mkdir(folder)
        for path in (pipe, folder):
            r = self.expect_error(path, "INPUT_NOT_FOUND")
            self.assertIn("not a regular file", r.stderr)

    def test_unsupported_format(self):
        self.expect_error(self.write("mesh.xyzzy", "hello\n"), "UNSUPPORTED_FORMAT")

    def test_garbage_in_a_known_format(self):
        self.expect_error(self.write("broken.obj", "v 0 0 0\nf 1 2 3 4 5\nthis is not obj\n"), "IMPORT_FAILED")

    def test_a_face_naming_a_missing_vertex_is_an_import_error(self):
        """assimp reads an OFF face whose index is past the vertices as the last vertex, and only logs it: the
        file is corrupt, and refused, not baked into a shape nobody drew."""
        text = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 7\n3 0 2 3\n3 1 2 3\n"
        r = self.expect_error(self.write("bad_index.off", text), "IMPORT_FAILED")
        self.assertIn("out of range", r.stderr)
        # The same tetrahedron with every index in range bakes.
        good = self.build(self.write("good.off", text.replace("3 0 1 7", "3 0 1 3")), "--resolution", "16")
        self.assertEqual(good.returncode, 0, good.stderr)

    def test_a_crashing_importer_is_an_import_error(self):
        # Debian's assimp aborts in an assertion on an OFF file that announces more vertices than it holds; the
        # import runs in a child process, so that is IMPORT_FAILED, not the end of voxfmt. (The comment's bytes let
        # the header's promise pass the size check, so that the importer itself meets the file.)
        text = "OFF\n# " + "padding " * 40 + "\n100 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
        r = self.expect_error(self.write("short.off", text), "IMPORT_FAILED")
        self.assertIn("short.off", r.stderr)
        self.assertNotIn("its header declares", r.stderr)

    def test_a_header_that_declares_more_than_the_file_holds_is_refused_before_any_reader(self):
        # Readers believe a header: they reserved ~1 GB a second for these, and beyond ~1e9 vertices CGAL's OFF
        # reader overflows an int. Each count is checked against the bytes that could hold it.
        ply = ("ply\nformat ascii 1.0\nelement vertex 2000000000\nproperty float x\nproperty float y\n"
               "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
               "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
        binary_ply = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                      + "\0" * 40)
        cases = {"huge.ply": ply, "huge.off": "OFF\n4000000000 1 0\n0 0 0\n1 0 0\n",
                 "counts_on_the_first_line.off": "OFF 50 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                 "short_binary.ply": binary_ply}
        for name, text in cases.items():
            started = time.monotonic()
            r = self.expect_error(self.write(name, text), "IMPORT_FAILED")
            self.assertIn("its header declares", r.stderr, name)
            self.assertLess(time.monotonic() - started, 10, name)
        # A lying header the check does not read (longer than the 64 KiB it reads) meets the reader, whose memory
        # the import's watchdog stops in proportion to the file (it used to run on to the 30 s time limit).
        long_header = ply.replace("format ascii 1.0\n", "format ascii 1.0\n" + ("comment " + "x" * 70 + "\n") * 1000)
        started = time.monotonic()
        r = self.expect_error(self.write("long_header.ply", long_header), "IMPORT_FAILED")
        self.assertIn("the importer needed more than", r.stderr)
        self.assertLess(time.monotonic() - started, 25, "stopped by the time limit, not the memory limit")
        # The same headers declaring what they hold pass, and the lone triangle bakes (as a shell).
        honest = {"tri.off": "OFF\n# comment\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                  "tri.ply": ply.replace("2000000000", "3")}
        for name, text in honest.items():
            r = self.build(self.write(name, text))
            self.assertEqual(r.returncode, 0, name + ": " + r.stderr)

    def test_a_grid_a_few_voxels_across_is_baked_with_a_warning(self):
        # A closed tetrahedron: at --resolution 2 its shape is lost (COARSE_GRID); at 8 and beyond nothing is said.
        tetra = self.write("tetra.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n")
        for resolution, warned in (("2", True), ("8", False)):
            r = self.build(tetra, "--resolution", resolution)
            self.assertEqual(r.returncode, 0, r.stderr)
            codes = [w["code"] for w in json.loads(r.stdout)["warnings"]]
            self.assertEqual("COARSE_GRID" in codes, warned, resolution)
            os.remove(self.out)

    def test_empty_scene(self):
        self.expect_error(self.write("empty.off", "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n"), "EMPTY_SCENE")

    def test_non_finite_coordinates(self):
        text = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\nnan 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n"
        self.expect_error(self.write("nan.off", text), "NON_FINITE_COORDINATES")

    def test_an_extent_that_overflows_is_out_of_scale_not_coincident(self):
        huge = self.write("huge.off", "OFF\n4 4 0\n-1.7e308 0 0\n1.7e308 0 0\n0 1.7e308 0\n0 0 1.7e308\n"
                                      "3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n")
        r = self.expect_error(huge, "SCALE_OUT_OF_RANGE")
        self.assertIn("overflows", r.stderr)

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

    def test_a_point_shell_beyond_the_memory_limit_is_refused_up_front(self):
        tet = self.write("tet.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n")
        r = self.expect_error(tet, "OUT_OF_MEMORY", "--resolution", "16", "--points", "50000000", "--max-memory", "64")
        self.assertIn("point shell (50000000 points)", r.stderr)
        # A sheet that turns out to be a shell takes a spacing's points twice (one set on each sheet): checked again
        # then (it was let through, 24,000 points under a limit for 20,000).
        flat = self.write("flat.off", "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n")
        r = self.expect_error(flat, "OUT_OF_MEMORY", "--resolution", "16", "--point-spacing", "0.007",
                              "--max-memory", "12")
        self.assertIn("point shell", r.stderr)

    @unittest.skipUnless(MESHES, "VOXFMT_SAMPLE_MESHES not set")
    def test_a_wide_band_beyond_the_memory_limit_is_refused_up_front(self):
        # Each triangle is binned to every brick within the band: at 64 voxels the bunny at 96^3 took 1.3 GB in 17 s
        # under --max-memory 150; the default band fits.
        bunny = os.path.join(MESHES, "bunny00.off")
        r = self.expect_error(bunny, "OUT_OF_MEMORY", "--resolution", "96", "--points", "500", "--band", "64",
                              "--max-memory", "150")
        self.assertIn("a narrower band", r.stderr)
        self.assertEqual(self.build(bunny, "--resolution", "96", "--points", "500", "--max-memory", "150").returncode, 0)

    def test_an_upper_case_extension_keeps_double_precision(self):
        # PART.OFF went to assimp's 32-bit floats: a 0.1 m cube 100 km from its origin lost 5 % of its volume.
        quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
        corners = [(1e5 + 0.1 * x, 0.1 * y, 0.1 * z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]
        text = "OFF\n8 12 0\n" + "".join("%.17g %.17g %.17g\n" % c for c in corners) + "".join(
            "3 %d %d %d\n3 %d %d %d\n" % (a, b, c, a, c, d) for a, b, c, d in quads)  # triangles: CGAL's reader
        volumes = []
        for name in ("far.off", "FAR.OFF"):
            r = self.build(self.write(name, text), "--resolution", "32", "--points", "200")
            self.assertEqual(r.returncode, 0, r.stderr)
            volumes.append(json.loads(r.stdout)["volume"])
        self.assertAlmostEqual(volumes[0], 1e-3, delta=1e-9)
        self.assertEqual(volumes[1], volumes[0])

    def test_bad_option_is_a_usage_error(self):
        tet = self.write("tet.off", "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 1 2 3\n3 2 0 3\n")
        for bad in (["--resolution", "10", "--voxel-size", "0.1"], ["--seed", "-1"],  # -1 wrapped to 2^64 - 1
                    ["--threads", "4294967295"], ["--voxel-size", "0"], ["--unit-scale", "nan"],
                    ["--shell-thickness", "inf"], ["--band", "nan"]):
            r = subprocess.run([VOXFMT, "build", tet, "-o", self.out, *bad], capture_output=True, text=True)
            self.assertEqual(r.returncode, 2, bad)
            self.assertIn("BAD_OPTION", r.stderr, bad)
            self.assertFalse(os.path.exists(self.out))
        # The message says what is wanted (CLI11's own named a range up to 1.8e308 that seemed to hold 0).
        r = subprocess.run([VOXFMT, "build", tet, "-o", self.out, "--voxel-size", "0"], capture_output=True, text=True)
        self.assertIn("must be a finite number > 0", r.stderr)
        # A count in another notation is refused as such, not as out of range ("1e3") or read its own way ("0x2").
        for option, value in (("--resolution", "1e3"), ("--points", "1e4"), ("--threads", "0x2"), ("--margin", "2.5"),
                              ("--max-memory", "1e3")):
            r = subprocess.run([VOXFMT, "build", tet, "-o", self.out, option, value], capture_output=True, text=True)
            self.assertEqual(r.returncode, 2, option)
            self.assertIn("must be a whole number in decimal digits, not '%s'" % value, r.stderr)
            self.assertFalse(os.path.exists(self.out))
        r = subprocess.run([VOXFMT, "build", tet, "-o", self.out, "--seed", "99999999999999999999"],
                           capture_output=True, text=True)
        self.assertIn("must be at most 18446744073709551615", r.stderr)  # not clamped to it
        # Leading zeros are decimal (CLI11 alone read "010" as octal 8, and called "09" out of range).
        dims = []
        for resolution in ("10", "010", "09"):
            r = subprocess.run([VOXFMT, "build", tet, "-o", self.out, "--resolution", resolution, "--json"],
                               capture_output=True, text=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            dims.append(json.loads(r.stdout)["voxelmap"]["dims"])
        self.assertEqual(dims[0], dims[1])
        self.assertEqual(max(dims[2]) + 1, max(dims[0]))

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



@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class BuildBadOutput(unittest.TestCase):
    """Outputs that cannot be written: WRITE_FAILED naming the problem, no partial file, an earlier asset untouched."""

    TET = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.mesh = os.path.join(self.dir.name, "tet.obj")
        with open(self.mesh, "w") as f:
            f.write(self.TET)

    def tearDown(self):
        self.dir.cleanup()

    def build(self, out, resolution="24", preexec_fn=None):
        return subprocess.run([VOXFMT, "build", self.mesh, "-o", out, "--resolution", resolution, "--points", "300",
                               "--json"], capture_output=True, text=True, timeout=120, preexec_fn=preexec_fn)

    def expect_write_failed(self, r, words):
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)  # an error, not a crash
        self.assertIn("WRITE_FAILED", r.stderr)
        self.assertEqual(json.loads(r.stdout)["code"], "WRITE_FAILED")
        self.assertIn(words, r.stderr)

    def skip_unless_nobody_can_run_voxfmt(self):
        try:
            subprocess.run([VOXFMT, "--version"], preexec_fn=as_nobody, capture_output=True, check=True)
        except (OSError, subprocess.CalledProcessError):
            self.skipTest("the user nobody cannot run voxfmt from this checkout (a parent folder is private)")

    def partials(self, folder):
        return [f for f in os.listdir(folder) if ".partial-" in f]

    def test_folder_that_does_not_exist(self):
        out = os.path.join(self.dir.name, "missing", "out.vox.h5")
        self.expect_write_failed(self.build(out), "does not exist")
        self.assertFalse(os.path.exists(os.path.dirname(out)))

    def test_a_pipe_the_mesh_itself_or_a_link_are_not_replaced(self):
        pipe = os.path.join(self.dir.name, "pipe.vox.h5")
        os.mkfifo(pipe)
        self.expect_write_failed(self.build(pipe), "not a regular file")
        self.assertTrue(stat.S_ISFIFO(os.stat(pipe).st_mode))
        r = self.build(self.mesh)  # -o the mesh itself
        self.assertEqual(r.returncode, 2, r.stderr)
        self.assertIn("BAD_OPTION", r.stderr)
        with open(self.mesh) as f:
            self.assertEqual(f.read(), self.TET)
        # Through a link the file it names is written; the link stays.
        target = os.path.join(self.dir.name, "target.vox.h5")
        link = os.path.join(self.dir.name, "link.vox.h5")
        os.symlink("target.vox.h5", link)
        self.assertEqual(self.build(link).returncode, 0)
        self.assertTrue(os.path.islink(link))
        with open(target, "rb") as f:
            self.assertEqual(f.read(8), b"\x89HDF\r\n\x1a\n")

    def test_a_dash_or_an_empty_path_is_a_usage_error_and_a_long_name_is_written(self):
        for out, words in (("-", "--output: '-' (standard output) is not supported"), ("", "--output: an empty path")):
            r = subprocess.run([VOXFMT, "build", self.mesh, "-o", out, "--resolution", "24"], cwd=self.dir.name,
                               capture_output=True, text=True, timeout=120)
            self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
            self.assertIn(words, r.stderr)
        self.assertEqual(sorted(os.listdir(self.dir.name)), [os.path.basename(self.mesh)])
        long_name = os.path.join(self.dir.name, "a" * 248 + ".vox.h5")  # 255 bytes: the file system's limit
        self.assertEqual(self.build(long_name).returncode, 0)
        with open(long_name, "rb") as f:
            self.assertEqual(f.read(8), b"\x89HDF\r\n\x1a\n")
        self.assertEqual(self.partials(self.dir.name), [])
        # One byte more is refused before the bake, not by the write at its end.
        too_long = os.path.join(self.dir.name, "a" * 249 + ".vox.h5")
        self.expect_write_failed(self.build(too_long),
                                 "the file's name (256 bytes) is longer than its folder's file system allows")

    def test_empty_path_is_a_usage_error(self):
        r = self.build("")
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
        self.assertIn("--output: an empty path", r.stderr)
        self.assertEqual(self.partials(self.dir.name), [])

    def test_path_that_is_a_folder(self):
        out = os.path.join(self.dir.name, "folder.vox.h5")
        os.mkdir(out)
        self.expect_write_failed(self.build(out), "is a folder")
        self.assertTrue(os.path.isdir(out))

    def test_folder_where_nothing_can_be_created(self):
        # /proc refuses new files to everyone, root included (a chmod'ed folder would not stop root).
        self.expect_write_failed(self.build("/proc/voxfmt-test.vox.h5"), "cannot create file")

    def test_read_only_folder_keeps_the_earlier_asset(self):
        """A folder without write permission (as root, the build runs as `nobody`, since permissions do not stop
        root): WRITE_FAILED, the earlier asset untouched, no temporary."""
        folder = os.path.join(self.dir.name, "assets")
        os.mkdir(folder)
        out = os.path.join(folder, "out.vox.h5")
        self.assertEqual(self.build(out).returncode, 0)
        with open(out, "rb") as f:
            before = f.read()
        os.chmod(self.dir.name, 0o755)
        os.chmod(self.mesh, 0o644)
        os.chmod(folder, 0o555)
        self.skip_unless_nobody_can_run_voxfmt()
        try:
            self.expect_write_failed(self.build(out, preexec_fn=as_nobody), "Permission denied")
        finally:
            os.chmod(folder, 0o755)
        with open(out, "rb") as f:
            self.assertEqual(f.read(), before, "the earlier asset changed")
        self.assertEqual(self.partials(folder), [])

    def test_a_read_only_asset_of_ones_own_is_replaced_and_stays_read_only(self):
        """As a user who is not root (nobody, in a folder of theirs): an asset made read-only is replaced (the folder
        allows it) and keeps its mode; the temporary was only ever its owner's."""
        folder = os.path.join(self.dir.name, "mine")
        os.mkdir(folder)
        os.chmod(self.dir.name, 0o755)
        os.chmod(self.mesh, 0o644)
        if os.geteuid() == 0:
            os.chown(folder, 65534, 65534)
        self.skip_unless_nobody_can_run_voxfmt()
        out = os.path.join(folder, "out.vox.h5")
        self.assertEqual(self.build(out, preexec_fn=as_nobody).returncode, 0)
        os.chmod(out, 0o440)
        r = self.build(out, resolution="28", preexec_fn=as_nobody)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(json.loads(r.stdout)["status"], "ok")
        self.assertEqual(stat.S_IMODE(os.stat(out).st_mode), 0o440)
        self.assertEqual(self.partials(folder), [])

    def test_full_disk_keeps_the_earlier_asset(self):
        """A 64 KiB file-size limit (ulimit -f) stands for a full disk: the kernel refuses the write (EFBIG) and,
        by default, sends SIGXFSZ, which voxfmt must not die of (reset here: Python starts children ignoring it)."""
        import resource
        import signal
        out = os.path.join(self.dir.name, "out.vox.h5")
        self.assertEqual(self.build(out).returncode, 0)
        with open(out, "rb") as f:
            before = f.read()

        def limit_file_size():
            signal.signal(signal.SIGXFSZ, signal.SIG_DFL)
            resource.setrlimit(resource.RLIMIT_FSIZE, (64 << 10, 64 << 10))

        r = self.build(out, resolution="96", preexec_fn=limit_file_size)
        self.expect_write_failed(r, "File too large")
        with open(out, "rb") as f:
            self.assertEqual(f.read(), before, "the earlier asset changed")
        self.assertEqual(self.partials(self.dir.name), [])


def cube_obj(edge):
    """A closed cube of the given edge (metres) with a corner at the origin, as OBJ text."""
    corners = [(x, y, z) for z in (0, edge) for y in (0, edge) for x in (0, edge)]
    quads = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    lines = ["v %r %r %r" % c for c in corners]
    lines += ["f %d %d %d\nf %d %d %d" % (a, b, c, a, c, d) for a, b, c, d in quads]
    return "\n".join(lines) + "\n"


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class BuildAtAnyScale(unittest.TestCase):
    """A micrometre part and a kilometre structure bake into valid assets with the right mass properties; a mesh
    whose voxels would leave the format's range (1e-9..1e6 m) is SCALE_OUT_OF_RANGE before the bake starts."""

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.out = os.path.join(self.dir.name, "out.vox.h5")

    def tearDown(self):
        self.dir.cleanup()

    def build(self, edge, *extra):
        mesh = os.path.join(self.dir.name, "cube.obj")
        with open(mesh, "w") as f:
            f.write(cube_obj(edge))
        grid = [] if "--voxel-size" in extra else ["--resolution", "24"]
        return subprocess.run([VOXFMT, "build", mesh, "-o", self.out, *grid, "--points", "400", "--json", *extra],
                              capture_output=True, text=True, timeout=120)

    def test_tiny_and_huge_meshes_bake_into_valid_assets(self):
        for edge in (1e-6, 3e-8, 1e6, 1e7):
            with self.subTest(edge=edge):
                r = self.build(edge)
                self.assertEqual(r.returncode, 0, r.stderr)
                summary = json.loads(r.stdout)
                self.assertAlmostEqual(summary["volume"] / edge**3, 1.0, places=9)
                v = subprocess.run([VOXFMT, "validate", "--level", "full", "--json", self.out],
                                   capture_output=True, text=True)
                self.assertEqual(v.returncode, 0, v.stdout)
                info = json.loads(subprocess.run([VOXFMT, "inspect", "--json", self.out], capture_output=True,
                                                 text=True, check=True).stdout)
                self.assertAlmostEqual(info["voxelmap"]["voxel_size"] / (edge / 24), 1.0, places=9)

    def test_voxels_outside_the_formats_range_are_refused_before_the_bake(self):
        for edge, words in ((1e-8, "use fewer voxels"), (1e9, "use more voxels")):
            with self.subTest(edge=edge):
                r = self.build(edge)
                self.assertEqual(r.returncode, 1, r.stderr)
                self.assertIn("SCALE_OUT_OF_RANGE", r.stderr)
                self.assertIn("cube.obj", r.stderr)
                self.assertIn(words, r.stderr)
                self.assertEqual(json.loads(r.stdout)["code"], "SCALE_OUT_OF_RANGE")
                self.assertEqual(os.listdir(self.dir.name), ["cube.obj"])
        # A millimetre file read as metres and scaled by 1e-6 by mistake: the unit is the likely cause.
        r = self.build(1.0, "--unit-scale", "1e-9")
        self.assertIn("SCALE_OUT_OF_RANGE", r.stderr)
        self.assertIn("unit scale", r.stderr)
        r = self.build(1.0, "--voxel-size", "1e-10")
        self.assertEqual(r.returncode, 2, r.stderr)
        self.assertIn("BAD_OPTION", r.stderr)


if __name__ == "__main__":
    unittest.main()
