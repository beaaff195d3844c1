"""`voxfmt build` on extreme and degenerate meshes a user brings: a clear coded error, or a valid asset whose inside
is where the mesh's is."""
import json
import os
import subprocess
import unittest

from cli_case import FolderCase

VOXFMT = os.environ.get("VOXFMT_BIN")

# A unit cube's corners and its outward triangles (counter-clockwise seen from outside).
CUBE_CORNERS = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_FACES = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6),
              (0, 6, 4), (1, 5, 7), (1, 7, 3)]


def box(size, centre):
    """A closed box's corners and triangles: `size` along each axis around `centre`."""
    corners = [tuple(c + (v - 0.5) * s for v, s, c in zip(corner, size, centre)) for corner in CUBE_CORNERS]
    return corners, list(CUBE_FACES)


def off_text(*boxes):
    vertices, faces = [], []
    for corners, triangles in boxes:
        faces += [tuple(len(vertices) + i for i in t) for t in triangles]
        vertices += corners
    return ("OFF\n%d %d 0\n" % (len(vertices), len(faces)) + "".join("%.17g %.17g %.17g\n" % v for v in vertices) +
            "".join("3 %d %d %d\n" % f for f in faces))


def accordion(pleats, period, depth, height):
    """An open zigzag sheet: `pleats` folds `period` apart along x, `depth` deep along z, `height` tall along y."""
    vertices, faces = [], []
    for i in range(2 * pleats + 1):
        x, z = i * period / 2, depth * (i % 2)
        vertices += [(x, 0, z), (x, height, z)]
        if i:
            a = 2 * (i - 1)
            faces += [(a, a + 2, a + 3), (a, a + 3, a + 1)]
    return ("OFF\n%d %d 0\n" % (len(vertices), len(faces)) + "".join("%.17g %.17g %.17g\n" % v for v in vertices) +
            "".join("3 %d %d %d\n" % f for f in faces))


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class BuildExtremes(FolderCase):
    def build(self, mesh, *options):
        return subprocess.run([VOXFMT, "build", mesh, "-o", self.out, "--json", *options], capture_output=True,
                              text=True, timeout=120)

    def validate(self):
        r = subprocess.run([VOXFMT, "validate", "--level", "full", "--json", self.out], capture_output=True, text=True,
                           timeout=120)
        self.assertEqual(r.returncode, 0, r.stdout)
        return json.loads(r.stdout)

    def warnings(self, summary):
        return {w["code"]: w["message"] for w in summary["warnings"]}

    def test_a_ply_face_naming_a_missing_vertex_is_an_import_error(self):
        """assimp's PLY reader passes a face's index past the vertices on unchecked: the bake read past the vertex
        array (an asset of whatever memory held there), where the file is corrupt."""
        header = ("ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 12\nproperty list uchar int vertex_indices\nend_header\n")
        faces = CUBE_FACES[:-1] + [(1, 7, 8)]
        text = header + "".join("%d %d %d\n" % c for c in CUBE_CORNERS) + "".join("3 %d %d %d\n" % f for f in faces)
        r = self.build(self.write("bad_index.ply", text), "--resolution", "16", "--points", "100")
        self.assertEqual(r.returncode, 1, r.stderr)
        self.assertEqual(json.loads(r.stdout)["code"], "IMPORT_FAILED")
        self.assertIn("vertex 8", r.stderr)
        self.assertFalse(os.path.exists(self.out))

    def test_an_off_face_naming_a_negative_vertex_is_an_import_error(self):
        """assimp's OFF reader takes "-1" for vertex 0, logs nothing and reads on: the face joined the wrong vertex
        (then dropped as degenerate), and a corrupt file baked. A file of polygons, which assimp reads instead of
        CGAL, still bakes."""
        vertices = "".join("%d %d %d\n" % c for c in CUBE_CORNERS)
        faces = CUBE_FACES[:-1] + [(1, -1, 3)]
        text = "OFF\n# a comment\n8 12 0\n" + vertices + "".join("3 %d %d %d\n" % f for f in faces)
        r = self.build(self.write("negative.off", text), "--resolution", "16", "--points", "100")
        self.assertEqual(r.returncode, 1, r.stderr)
        self.assertEqual(json.loads(r.stdout)["code"], "IMPORT_FAILED")
        self.assertIn("face 11 names vertex -1", r.stderr)
        self.assertFalse(os.path.exists(self.out))
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        text = "OFF 8 6 0\n" + vertices + "".join("4 %d %d %d %d\n" % q for q in quads)
        r = self.build(self.write("quads.off", text), "--resolution", "16", "--points", "100")
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertAlmostEqual(json.loads(r.stdout)["volume"], 1.0, delta=1e-9)

    def test_a_small_part_far_from_a_large_one_encloses_its_volume(self):
        """A 1 m cube and a 1 mm cube 1 km away: the solid's volume is a billionth of its bounding box's, which the
        bake took for a flat, closed sheet, and then for a shell too thin to hold anything (ZERO_VOLUME) at 5 cm
        voxels, where the large cube is 20 voxels across."""
        mesh = self.write("two.off", off_text(box((1, 1, 1), (0, 0, 0)), box((1e-3,) * 3, (1000, 0, 0))))
        r = self.build(mesh, "--voxel-size", "0.05", "--points", "500")
        self.assertEqual(r.returncode, 0, r.stderr)
        summary = json.loads(r.stdout)
        self.assertAlmostEqual(summary["volume"], 1 + 1e-9, delta=1e-9)
        self.assertNotIn("SHELL_MODE", self.warnings(summary))
        self.validate()

    def test_crumpled_surfaces_with_few_points(self):
        """A shell whose every sampled point lies inside it (a few points on a sheet folded tighter than the shell) is
        refused as an option, not written as a file the validator refuses and blamed on the bake; one point on a
        surface of far more area than its box has gets the spec's largest spacing, not an invalid one."""
        sheet = self.write("pleats.off", accordion(40, 0.005, 0.1, 0.1))
        r = self.build(sheet, "--shell-thickness", "0.05", "--resolution", "32", "--points", "2")
        self.assertEqual(r.returncode, 2, r.stderr)
        self.assertEqual(json.loads(r.stdout)["code"], "BAD_OPTION")
        self.assertIn("inside the shell", r.stderr)
        self.assertFalse(os.path.exists(self.out))
        crumpled = self.write("crumpled.off", accordion(1000, 1e-5, 0.01, 0.01))
        for points in ("1", "2"):  # a shell thinner than the folds' gaps: its points survive
            with self.subTest(points=points):
                r = self.build(crumpled, "--resolution", "16", "--points", points, "--shell-thickness", "1e-6")
                self.assertEqual(r.returncode, 0, r.stderr)
                self.assertEqual([i["code"] for i in self.validate().get("issues", [])], [])

    def test_a_closed_part_thinner_than_a_voxel_bakes_as_a_shell(self):
        """A closed 1000:1:1 needle at 31 m voxels: no voxel centre lies inside it, so the asset had no inside at
        all (the needle's axis read 21 m outside, two crossed needles never touched), without a word. Like open
        parts thinner than a voxel, it becomes a 2-voxel shell, and the warning says why."""
        for name, text, options in (
                ("needle.off", off_text(box((1000, 1, 1), (0, 0, 0))), ("--resolution", "32")),
                ("two.off", off_text(box((1, 1, 1), (0, 0, 0)), box((1e-3,) * 3, (1000, 0, 0))),
                 ("--resolution", "32"))):
            with self.subTest(mesh=name):
                r = self.build(self.write(name, text), *options, "--points", "500")
                self.assertEqual(r.returncode, 0, r.stderr)
                summary = json.loads(r.stdout)
                self.assertIn("thinner than a voxel", self.warnings(summary).get("SHELL_MODE", ""), r.stdout)
                report = self.validate()
                self.assertEqual([i["code"] for i in report.get("issues", [])], [], report)


if __name__ == "__main__":
    unittest.main()
