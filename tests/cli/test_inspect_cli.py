"""`voxfmt inspect --slice ... --png`, `--ply [--level L]` and `--vdb` on a small baked asset, and their usage
errors. (The VDB grids' contents are checked with OpenVDB itself in test_vdb_export.cpp.) The asset (format 2.0)
is read with the spec's own decoder, tests/spec/spec_support.py (bricks, codes and lattice to dense arrays)."""
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import unittest

from terminal import run_on_terminal
import zlib

import h5py
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "spec"))
import spec_support  # noqa: E402  (the spec's voxelmap decoder)

VOXFMT = os.environ.get("VOXFMT_BIN")

# A torus-like closed box with a hole is overkill: a tetrahedron has inside, outside and a surface in most slices.
TET_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"


def read_png(path):
    """Minimal PNG reader (8-bit RGB, no interlace): returns (width, height, pixels[h, w, 3])."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG signature"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        assert zlib.crc32(kind + body) & 0xFFFFFFFF == crc, "bad CRC in chunk %r" % kind
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            break
        pos += 12 + length
    width, height, depth, colour, _, _, interlace = header
    assert (depth, colour, interlace) == (8, 2, 0)
    raw = zlib.decompress(idat)
    stride = width * 3
    out = np.zeros((height, stride), dtype=np.int32)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(height):
        kind = raw[y * (stride + 1)]
        line = np.frombuffer(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)], dtype=np.uint8).astype(np.int32)
        cur = np.zeros(stride, dtype=np.int32)
        for x in range(stride):
            a = cur[x - 3] if x >= 3 else 0
            b = prev[x]
            c = prev[x - 3] if x >= 3 else 0
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            cur[x] = (line[x] + pred) & 0xFF
        out[y] = cur
        prev = cur
    return width, height, out.reshape(height, width, 3)


def read_ply(path):
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[0] == "ply" and header[1] == "format binary_little_endian 1.0", header[:2]
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    props = [line.split()[2] for line in header if line.startswith("property")]
    assert props == ["x", "y", "z", "nx", "ny", "nz"], props
    assert all(line.split()[1] == "float" for line in header if line.startswith("property"))
    body = np.frombuffer(data[end:], dtype="<f4")
    assert body.size == count * 6, "body has %d floats for %d vertices" % (body.size, count)
    return body.reshape(count, 6)


def read_terminal(command):
    """What `command` writes on stderr when stderr is a terminal (a pseudo-terminal here), decoded strictly."""
    return run_on_terminal(command, stdout=subprocess.DEVNULL, timeout=60)[1].decode("utf-8")


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class InspectExports(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        cls.dir = cls.tmp.name
        mesh = os.path.join(cls.dir, "tet.obj")
        with open(mesh, "w") as f:
            f.write(TET_OBJ)
        cls.asset = os.path.join(cls.dir, "tet.vox.h5")
        r = subprocess.run([VOXFMT, "build", mesh, "-o", cls.asset, "--resolution", "20", "--points", "400", "-q"],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        with h5py.File(cls.asset, "r") as f:
            assert f.attrs["format_version"].tolist() == [2, 2], f.attrs["format_version"]
            cls.voxelmap = spec_support.decode_voxelmap(f)
            cls.dims = list(cls.voxelmap.dims)
            cls.layers = cls.voxelmap.layers  # floor(-value/h + 1/2) of every voxel, [D, H, W]
            cls.offsets = f["pointshell/level_offsets"][()]
            cls.points = f["pointshell/points"][()]
            cls.normals = f["pointshell/normals"][()]

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def inspect(self, *args):
        return subprocess.run([VOXFMT, "inspect", self.asset, *args], capture_output=True, text=True, timeout=60)

    def summary(self):
        r = self.inspect("--json")
        self.assertEqual(r.returncode, 0, r.stderr)
        return json.loads(r.stdout)

    def test_summary_agrees_with_the_spec_decoder(self):
        """inspect --json's voxelmap figures are the decoded file's: stored distances, the layers of the values,
        the brick table's counts, lattice_error."""
        vm = self.summary()["voxelmap"]
        v = self.voxelmap
        self.assertEqual(vm["dims"], list(v.dims))
        self.assertEqual(vm["stored_distances"], v.stored_count)
        self.assertEqual((vm["layer_min"], vm["layer_max"]), (int(self.layers.min()), int(self.layers.max())))
        self.assertEqual((vm["bricks"], vm["value_bricks"], vm["coarse_bricks"]),
                         (v.brick_count, v.value_brick_count, v.coarse_brick_count))
        np.testing.assert_allclose(vm["lattice_error"], v.lattice_error, rtol=1e-12)
        self.assertEqual(vm["estimates"], "settled")  # a bake writes format 2.2's rule (spec 3.1)
        self.assertLess(self.layers.min(), 0)  # the tetrahedron's grid has outside...
        self.assertGreater(self.layers.max(), 0)  # ...and inside voxels

    def test_strings_from_the_file_cannot_drive_the_terminal(self):
        """A hostile provenance string (escape sequences, a bell, a carriage return, a forged line) is printed with
        its control characters escaped; --json escapes them by JSON's own rules."""
        hostile = os.path.join(self.dir, "hostile.vox.h5")
        with open(self.asset, "rb") as src, open(hostile, "wb") as dst:
            dst.write(src.read())
        text = "\x1b[31mRED\x1b[2J\x1b]0;title\x07\nFAKE: valid\r\u0085"
        with h5py.File(hostile, "r+") as f:
            f["provenance"].attrs["source_file"] = text
        r = subprocess.run([VOXFMT, "inspect", hostile], capture_output=True, text=True, timeout=60)
        self.assertEqual(r.returncode, 0, r.stderr)
        for control in ("\x1b", "\x07", "\r", "\u0085", "\nFAKE"):
            self.assertNotIn(control, r.stdout)
        self.assertIn("\\x1B[31mRED\\x1B[2J\\x1B]0;title\\x07\\x0AFAKE: valid\\x0D\\xC2\\x85", r.stdout)
        r = subprocess.run([VOXFMT, "inspect", hostile, "--json"], capture_output=True, text=True, timeout=60)
        self.assertEqual(json.loads(r.stdout)["provenance"]["source_file"], text)

    def test_ply_of_every_level(self):
        levels = len(self.offsets) - 1
        for level in range(levels):
            out = os.path.join(self.dir, "level%d.ply" % level)
            r = self.inspect("--ply", out, "--level", str(level))
            self.assertEqual(r.returncode, 0, r.stderr)
            cloud = read_ply(out)
            self.assertEqual(len(cloud), self.offsets[level + 1])  # the breadth-first prefix
            np.testing.assert_allclose(cloud[:, :3], self.points[:len(cloud)], atol=1e-6)
            np.testing.assert_allclose(cloud[:, 3:], -self.normals[:len(cloud)], atol=1e-7)  # outward
        full = os.path.join(self.dir, "all.ply")
        r = self.inspect("--ply", full, "--inward-normals", "--json")
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(json.loads(r.stdout)["exports"][0]["points"], len(self.points))
        cloud = read_ply(full)
        self.assertEqual(len(cloud), len(self.points))
        np.testing.assert_allclose(cloud[:, 3:], self.normals, atol=1e-7)
        np.testing.assert_allclose(np.linalg.norm(cloud[:, 3:], axis=1), 1, atol=1e-3)

    def test_vdb_file_and_summary(self):
        out = os.path.join(self.dir, "tet.vdb")
        r = self.inspect("--vdb", out, "--json")
        self.assertEqual(r.returncode, 0, r.stderr)
        export = json.loads(r.stdout)["exports"][0]
        self.assertEqual(export["kind"], "vdb")
        # "layers": the whole voxelmap (value-brick voxels one by one, a coarse brick one 8^3 tile);
        # "distance": a level set of the stored distances only.
        self.assertEqual(export["layer_voxels"], int(np.prod(self.dims)))
        self.assertEqual(export["distance_voxels"], self.voxelmap.stored_count)
        self.assertEqual(export["distance_voxels"], self.summary()["voxelmap"]["stored_distances"])
        with open(out, "rb") as f:
            header = f.read(21)
        self.assertEqual(header[:4], b" BDV", "OpenVDB's magic number 0x56444220, little-endian")
        self.assertEqual(header[20], 1, "grid offsets (readers load grids lazily), as openvdb::io::File writes")

    def test_a_vdb_cut_short_by_a_file_size_limit_is_write_failed_and_no_file(self):
        import resource
        out = os.path.join(self.dir, "limited.vdb")

        def limit_file_size():
            resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

        r = subprocess.run([VOXFMT, "inspect", self.asset, "--vdb", out], capture_output=True, text=True, timeout=60,
                           preexec_fn=limit_file_size)
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
        self.assertIn("WRITE_FAILED", r.stderr)
        self.assertEqual([n for n in os.listdir(self.dir) if n.startswith("limited.vdb")], [])

    def test_the_card_goes_with_the_other_outputs_and_json(self):
        card, ply = os.path.join(self.dir, "card"), os.path.join(self.dir, "with-card.ply")
        r = self.inspect("--html", card, "--ply", ply, "--json")
        self.assertEqual(r.returncode, 0, r.stderr)
        exports = json.loads(r.stdout)["exports"]
        self.assertEqual([e["kind"] for e in exports], ["html", "point_shell"])
        self.assertEqual(exports[0]["file"], os.path.join(card, "index.html"))
        self.assertGreater(exports[0]["bytes"], 0)
        self.assertTrue(os.path.isfile(ply) and os.path.isfile(os.path.join(card, "index.html")))
        for clash, words in ((card, "is a folder"), (os.path.join(card, "shell.ply"), "is --html's folder or in it")):
            r = self.inspect("--html", card, "--ply", clash)  # refused before anything is written
            self.assertEqual(r.returncode, 2, r.stderr)
            self.assertIn(words, r.stderr)
        self.assertFalse(os.path.exists(os.path.join(card, "shell.ply")))
        # What a killed inspect left beside an output (a dead process's temporary) goes with the next write.
        ended = subprocess.Popen(["true"])
        ended.wait()
        left = ply + ".partial-%d-0" % ended.pid
        with open(left, "w") as f:
            f.write("torn")
        self.assertEqual(self.inspect("--ply", ply).returncode, 0)
        self.assertFalse(os.path.exists(left))

    def test_output_that_cannot_reach_stdout_is_a_failure(self):
        # `--json > report.json` on a full disk: exit 2 and a message, never exit 0 with an empty report.
        for command in (["inspect", self.asset, "--json"], ["validate", self.asset, "--json"]):
            with open("/dev/full", "w") as full:
                r = subprocess.run([VOXFMT, *command], stdout=full, stderr=subprocess.PIPE, text=True, timeout=60)
            self.assertEqual(r.returncode, 2, r.stderr)
            self.assertIn("WRITE_FAILED: standard output", r.stderr)

    def test_slice_png_size_colours_and_contour(self):
        W, H, D = self.dims
        for axis, index, cols, rows in (("z", D // 3, W, H), ("y", H // 3, W, D), ("x", W // 3, H, D)):
            for field in ("layers", "distances"):
                out = os.path.join(self.dir, "slice-%s-%s.png" % (axis, field))
                r = self.inspect("--slice", "%s=%d" % (axis, index), "--png", out, "--zoom", "5", "--field", field, "--json")
                self.assertEqual(r.returncode, 0, r.stderr)
                info = json.loads(r.stdout)["exports"][0]
                width, height, pixels = read_png(out)
                # The documented layout: P * columns + 200 by max(P * rows, 240) + 42 pixels.
                self.assertEqual((width, height), (5 * cols + 200, max(5 * rows, 240) + 42))
                self.assertEqual((info["width"], info["height"], info["columns"], info["rows"]), (width, height, cols, rows))
                self.assertTrue(info["surface_in_slice"])
                top = 10 + 14 + 8  # margin + title + gap
                area = pixels[top:top + 5 * rows, 10:10 + 5 * cols]
                red = (area[:, :, 0] > 150) & (area[:, :, 2] < 120)
                blue = (area[:, :, 2] > 150) & (area[:, :, 0] < 120)
                black = area.sum(axis=2) == 0
                self.assertTrue(red.any() and blue.any() and black.any(), "inside, outside and the contour appear")
        # The first row of map pixels is the top row of voxels (rows go up): z slice, j = H - 1 is outside.
        r = self.inspect("--slice", "z=%d" % (D // 3), "--png", os.path.join(self.dir, "z.png"), "--zoom", "1")
        self.assertEqual(r.returncode, 0, r.stderr)
        width, height, pixels = read_png(os.path.join(self.dir, "z.png"))
        self.assertLess(self.layers[D // 3, H - 1, 0], 0)
        corner = pixels[10 + 14 + 8, 10]
        self.assertGreater(corner[2], corner[0], "top-left voxel (outside) is blue")

    def test_estimates_rule_follows_the_file_version(self):
        """inspect names each file's estimate rule (spec 3.1): a 2.1 file's are interpolated, the same file upgraded
        to 2.2 holds settled ones; text and JSON agree."""
        import spec_fixture  # tests/spec: writes files from the spec alone

        old = spec_fixture.write_fixture_h5py(os.path.join(self.dir, "sphere21.vox.h5"), format_version=[2, 1])
        new = os.path.join(self.dir, "sphere22.vox.h5")
        r = subprocess.run([VOXFMT, "upgrade", old, "-o", new], capture_output=True, text=True, timeout=60)
        self.assertEqual(r.returncode, 0, r.stderr)
        for path, rule, version in ((old, "interpolated", [2, 1]), (new, "settled", [2, 2])):
            r = subprocess.run([VOXFMT, "inspect", path, "--json"], capture_output=True, text=True, timeout=60)
            self.assertEqual(r.returncode, 0, r.stderr)
            summary = json.loads(r.stdout)
            self.assertEqual((summary["format_version"], summary["voxelmap"]["estimates"]), (version, rule))
            r = subprocess.run([VOXFMT, "inspect", path], capture_output=True, text=True, timeout=60)
            line = next(line for line in r.stdout.splitlines() if line.strip().startswith("estimates"))
            self.assertIn(rule, line)

    def test_bad_arguments_exit_2_with_a_message(self):
        png = os.path.join(self.dir, "bad.png")
        cases = [
            (["--slice", "z=99999", "--png", png], "0..%d" % (self.dims[2] - 1)),
            (["--slice", "w=3", "--png", png], "AXIS"),
            (["--slice", "z=-1", "--png", png], "index"),
            (["--slice", "z", "--png", png], "AXIS=INDEX"),
            (["--slice", "z=3"], "--png"),
            (["--png", png], "--slice"),
            (["--ply", os.path.join(self.dir, "bad.ply"), "--level", "99"], "levels 0.."),
            (["--level", "1"], "--ply"),
            (["--slice", "x=1", "--png", os.path.join(self.dir, "no-such-dir", "x.png")], "no-such-dir"),
            (["--vdb", os.path.join(self.dir, "no-such-dir", "x.vdb")], "no-such-dir"),
            # An empty path given explicitly is refused, not read as "not asked for" (which printed the summary).
            (["--ply", self.asset], "would replace it"),
            (["--ply", os.path.join(self.dir, "same"), "--vdb", os.path.join(self.dir, "same")], "the same file"),
            (["--html", ""], "empty path"),
            (["--ply", ""], "empty path"),
            (["--vdb", ""], "empty path"),
        ]
        for args, message in cases:
            r = self.inspect(*args)
            self.assertEqual(r.returncode, 2, (args, r.stdout, r.stderr))
            self.assertIn(message, r.stderr, args)
        self.assertFalse(os.path.exists(png))
        self.assertEqual([f for f in os.listdir(self.dir) if "partial" in f], [])
        # --html naming a file: said so (not "holds files a report does not write").
        r = self.inspect("--html", self.asset)
        self.assertEqual(r.returncode, 2, r.stderr)
        self.assertIn("is a file, not a folder", r.stderr)

    def test_a_usage_error_writes_no_output(self):
        """A slice index or --level the asset does not have is refused before anything is written: not the picture,
        the card or another file asked for with it (the PNG and the card were written before --level was checked)."""
        png, ply, card, vdb = (os.path.join(self.dir, "usage-" + n) for n in ("p.png", "s.ply", "card", "v.vdb"))
        for args in (["--slice", "z=5", "--png", png, "--ply", ply, "--level", "99"],
                     ["--html", card, "--ply", ply, "--level", "99"],
                     ["--html", card, "--vdb", vdb, "--slice", "z=99999", "--png", png],
                     ["--html", card, "--slice", "z=99999", "--png", png, "--json"]):
            r = self.inspect(*args)
            self.assertEqual(r.returncode, 2, (args, r.stdout, r.stderr))
            self.assertIn("BAD_OPTION", r.stderr, args)
            for path in (png, ply, card, vdb):
                self.assertFalse(os.path.exists(path), (args, path))
        self.assertLess(5, self.dims[2])  # z=5 itself is a slice the asset has

    def test_file_names_cannot_drive_the_terminal(self):
        """A file name is printed with its control characters escaped, as strings from the file are: inspect's
        summary and export lines, validate's verdict, upgrade's progress on a terminal, an unknown command's name.
        --json keeps the name exact (JSON escapes it its own way)."""
        folder = os.path.join(self.dir, "names")
        os.makedirs(folder)
        hostile = os.path.join(folder, "t\x1b]0;title\x07\x1b[2J.vox.h5")
        shutil.copy(self.asset, hostile)
        shutil.copy(self.asset, os.path.join(folder, "plain.vox.h5"))
        shown = "t\\x1B]0;title\\x07\\x1B[2J.vox.h5"
        ply = os.path.join(self.dir, "s\x1b[2J.ply")
        for command, where, expected in (
                (["inspect", hostile], "stdout", shown),
                (["inspect", hostile, "--ply", ply], "stdout", "s\\x1B[2J.ply"),
                (["validate", hostile], "stdout", shown),
                (["\x1b[2Jbogus"], "stderr", "\\x1B[2Jbogus")):
            r = subprocess.run([VOXFMT, *command], capture_output=True, text=True, timeout=60)
            for control in ("\x1b", "\x07"):
                self.assertNotIn(control, r.stdout + r.stderr, command)
            self.assertIn(expected, getattr(r, where), command)
        r = subprocess.run([VOXFMT, "inspect", hostile, "--json"], capture_output=True, text=True, timeout=60)
        self.assertEqual(json.loads(r.stdout)["file"], hostile)
        # upgrade's progress line, drawn on a terminal only (its own "\r\x1b[K" aside).
        terminal = read_terminal([VOXFMT, "upgrade", folder, "-o", os.path.join(self.dir, "names-upgraded")])
        self.assertIn(shown, terminal)
        for control in ("\x1b]", "\x1b[2J", "\x07"):
            self.assertNotIn(control, terminal)

    def test_json_errors_are_json_on_stdout_too(self):
        truncated = os.path.join(self.dir, "truncated.vox.h5")
        with open(self.asset, "rb") as src, open(truncated, "wb") as dst:
            dst.write(src.read(1000))
        r = subprocess.run([VOXFMT, "inspect", truncated, "--json"], capture_output=True, text=True, timeout=60)
        self.assertEqual(r.returncode, 1, r.stderr)
        error = json.loads(r.stdout)
        self.assertEqual((error["status"], error["input"]), ("error", truncated))
        self.assertIn(error["code"], r.stderr)

    def test_an_option_error_is_json_when_json_is_asked_for_in_any_spelling(self):
        # CLI11 refuses the line before any command runs; the error is still JSON on stdout for --json=true.
        for spelling, wants_json in (("--json", True), ("--json=true", True), ("--json=ON", True),
                                     ("--json=2", True), ("--json=false", False), ("--json=0", False),
                                     ("--json=-1", False)):
            r = subprocess.run([VOXFMT, "inspect", self.asset, spelling, "--no-such-option"], capture_output=True,
                               text=True, timeout=60)
            self.assertEqual(r.returncode, 2, (spelling, r.stderr))
            self.assertIn("BAD_OPTION", r.stderr, spelling)
            if wants_json:
                self.assertEqual(json.loads(r.stdout)["code"], "BAD_OPTION", spelling)
            else:
                self.assertEqual(r.stdout, "", spelling)


if __name__ == "__main__":
    unittest.main()
