"""`voxfmt report`, `inspect --html` and `batch --report` without a browser: the folder, its data against the
manifest, the 3D view's arrays decoded as the page decodes them, damaged input, and usage errors."""
import base64
import json
import os
import shutil
import tempfile
import unittest
import zlib

import report_fixture as fx


def parsed(text, prefix, suffix):
    """The value of `PREFIX JSON.parse("...") SUFFIX`: a JSON document inside a JSON string."""
    text = text.rstrip()
    assert text.startswith(prefix + "JSON.parse(") and text.endswith(")" + suffix), text[:80]
    return json.loads(json.loads(text[len(prefix + "JSON.parse("):-len(")" + suffix)]))


def load_data(report):
    with open(os.path.join(report, "data.js")) as f:
        return parsed(f.read(), "window.VOXFMT_REPORT = ", ";")


def load_asset(report, row):
    with open(os.path.join(report, row["detail"])) as f:
        return parsed(f.read(), "voxfmtReport.addAsset(%d, " % row["id"], ");")


def png_pixels(path):
    """(width, height, rows of RGB tuples) of an 8-bit RGB PNG, every filter type undone."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, width = 8, b"", 0
    while pos < len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour = int.from_bytes(body[:4], "big"), int.from_bytes(body[4:8], "big"), body[8], body[9]
            assert (depth, colour) == (8, 2), (depth, colour)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw, stride, rows, previous = zlib.decompress(idat), 3 * width, [], bytearray(3 * width)
    for y in range(height):
        kind, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = line[i - 3] if i >= 3 else 0
            b, c = previous[i], previous[i - 3] if i >= 3 else 0
            if kind == 1:
                line[i] = (line[i] + a) & 255
            elif kind == 2:
                line[i] = (line[i] + b) & 255
            elif kind == 3:
                line[i] = (line[i] + (a + b) // 2) & 255
            elif kind == 4:
                p_ = a + b - c
                pa, pb, pc = abs(p_ - a), abs(p_ - b), abs(p_ - c)
                line[i] = (line[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append([tuple(line[3 * x:3 * x + 3]) for x in range(width)])
        previous = line
    return width, height, rows


def box_obj(lo, hi, first):
    """A closed box's OBJ vertices and faces, its vertices numbered from `first`."""
    v = [(x, y, z) for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])]
    faces = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    text = "".join("v %g %g %g\n" % p for p in v)
    for a, b, c, d in faces:
        text += "f %d %d %d\nf %d %d %d\n" % (a + first, b + first, c + first, a + first, c + first, d + first)
    return text


class ReportTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-report-")
        cls.library, cls.other = fx.make_library(cls.tmp)
        cls.report = os.path.join(cls.tmp, "report")
        p = fx.run("report", cls.library, "-o", cls.report, "--against", cls.other, "--json")
        cls.summary = json.loads(p.stdout)
        cls.data = load_data(cls.report)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_counts_match_the_manifest(self):
        records = fx.manifest(self.library)
        statuses = [r["status"] for r in records]
        self.assertEqual(self.summary["meshes"], len(records))
        self.assertEqual(self.summary["built"], statuses.count("ok"))
        self.assertEqual(self.summary["failed"], statuses.count("failed"))
        self.assertEqual(self.summary["failed"], 4)  # two meshes, and the two hostile records
        self.assertEqual(self.summary["unreadable_assets"], 1)
        self.assertEqual(self.summary["skipped_manifest_lines"], 3)  # torn, not an object, nested too deep
        self.assertEqual(len(self.data["rows"]), len(records))
        self.assertEqual(sorted(r["status"] for r in self.data["rows"]), sorted(statuses))

    def test_the_folder_is_self_contained(self):
        for name in ["index.html", "voxfmt-report.js", "voxfmt-report.css", "three.cjs.js", "three-LICENSE.txt"]:
            self.assertTrue(os.path.isfile(os.path.join(self.report, name)), name)
        with open(os.path.join(self.report, "index.html")) as f:
            page = f.read()
        self.assertNotIn("http://", page)
        self.assertNotIn("https://", page)
        with open(os.path.join(self.report, "three-LICENSE.txt")) as f:
            self.assertIn("Permission is hereby granted", f.read())  # three.js's MIT licence, beside it

    def test_built_assets_have_pictures_and_3d_data(self):
        built = [r for r in self.data["rows"] if r["status"] == "ok" and "asset_error" not in r]
        self.assertEqual(len(built), 4)
        for row in built:
            for key in ("views", "slice"):
                with open(os.path.join(self.report, row[key]), "rb") as f:
                    self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n")
            self.assertTrue(row["validation"]["valid"])
            scene = load_asset(self.report, row)["scene"]
            shell = zlib.decompress(base64.b64decode(scene["shell"]["data"]))
            n = scene["shell"]["points"]
            self.assertEqual(len(shell), 9 * n)
            self.assertEqual(scene["shell"]["level_offsets"][-1], n)
            # Decoded as the page decodes it: every point inside the bounds, every normal about unit length.
            lo, hi = scene["bounds"]
            for p in range(n):
                for a in range(3):
                    q = shell[3 * p + a] | (shell[3 * n + 3 * p + a] << 8)
                    self.assertLessEqual(q, 4095)
                nx, ny, nz = (((shell[6 * n + 3 * p + a] + 128) % 256) - 128 for a in range(3))
                self.assertAlmostEqual((nx * nx + ny * ny + nz * nz) ** 0.5 / 127, 1.0, delta=0.02)
            field = zlib.decompress(base64.b64decode(scene["field"]["data"]))
            dims = scene["field"]["dims"]
            self.assertEqual(len(field), dims[0] * dims[1] * dims[2])
            signed = [((b + 128) % 256) - 128 for b in field]
            if row["name"] != "sheet.obj":  # a closed mesh has inside and outside on the grid
                self.assertLess(min(signed), 0)
            self.assertGreater(max(signed), 0)

    def test_failures_and_the_damaged_asset_carry_codes(self):
        rows = {r["name"]: r for r in self.data["rows"]}
        for name in ("not_a_mesh.obj", "points_only.obj"):
            self.assertEqual(rows[name]["status"], "failed")
            self.assertRegex(rows[name]["error"]["code"], r"^[A-Z0-9_]+$")
        damaged = rows["damaged.obj"]
        self.assertEqual(damaged["status"], "ok")
        self.assertRegex(damaged["asset_error"]["code"], r"^[A-Z0-9_]+$")
        self.assertFalse(damaged["validation"]["valid"])
        self.assertNotIn("detail", damaged)
        self.assertIn("OPEN_BORDER", [w["code"] for w in rows["sheet.obj"]["warnings"]])

    def test_against_holds_the_other_bake(self):
        against = self.data["against"]
        self.assertEqual(len(against["rows"]), len(fx.manifest(self.other)))
        self.assertEqual({r["output"] for r in against["rows"]} | {"hostile.vox.h5", "proto.vox.h5"},
                         {r["output_name"] for r in self.data["rows"]})

    def test_same_names_in_subfolders_stay_apart(self):
        names = [r["output_name"] for r in self.data["rows"]]
        self.assertEqual(len(names), len(set(names)))
        self.assertIn("parts/tet.obj.vox.h5", names)
        self.assertIn("tet.obj.vox.h5", names)
        rows = {r["output_name"]: r for r in self.data["rows"]}
        # Each read its own asset (a box and a tetrahedron: different volumes).
        self.assertNotEqual(rows["parts/tet.obj.vox.h5"]["volume"], rows["tet.obj.vox.h5"]["volume"])
        self.assertNotIn("asset_error", rows["parts/tet.obj.vox.h5"])

    def test_failed_meshes_of_one_name_in_two_subfolders_stay_apart(self):
        # No asset was written for either: each is keyed by where the manifest places it below the library, here
        # and in the other bake's rows, so a comparison never takes one for the other.
        library, older = fx.make_edge_library(self.tmp)
        out = os.path.join(self.tmp, "edge-report")
        fx.run("report", library, "-o", out, "--against", older, "--no-pictures")
        data = load_data(out)
        failed = sorted(r["output_name"] for r in data["rows"] if r["status"] == "failed")
        self.assertEqual(failed, ["a/x.obj.vox.h5", "b/x.obj.vox.h5"])
        against = {r["output"]: r for r in data["against"]["rows"]}
        self.assertEqual(sorted(against), sorted(r["output_name"] for r in data["rows"]))
        self.assertEqual((against["a/x.obj.vox.h5"]["status"], against["b/x.obj.vox.h5"]["status"]), ("ok", "failed"))
        # The other bake's asset that is gone is said to be (its assets are not read, only looked for).
        self.assertEqual(against[fx.LONG_NAME + ".vox.h5"]["asset_error"]["code"], "FILE_NOT_FOUND")
        self.assertNotIn("asset_error", against["flat.obj.vox.h5"])

    def test_unreadable_assets_carry_their_real_size_or_none(self):
        rows = {r["output_name"]: r for r in self.data["rows"]}
        damaged = rows["damaged.obj.vox.h5"]
        self.assertEqual(damaged["asset_bytes"], os.path.getsize(os.path.join(self.library, "damaged.obj.vox.h5")))
        self.assertGreater(damaged["file_size_bytes"], damaged["asset_bytes"])  # the manifest's, as recorded at bake
        self.assertNotIn("asset_bytes", rows["tet.obj.vox.h5"])
        # A gone asset has no size at all.
        library = os.path.join(self.tmp, "gone-asset")
        shutil.copytree(self.library, library)
        os.remove(os.path.join(library, "box.obj.vox.h5"))
        out = os.path.join(self.tmp, "gone-asset-report")
        fx.run("report", library, "-o", out, "--no-pictures")
        box = next(r for r in load_data(out)["rows"] if r["output_name"] == "box.obj.vox.h5")
        self.assertEqual(box["asset_error"]["code"], "FILE_NOT_FOUND")
        self.assertNotIn("asset_bytes", box)

    def test_the_3d_view_is_offered_only_with_its_data(self):
        built = [r for r in self.data["rows"] if r["status"] == "ok" and "asset_error" not in r]
        self.assertTrue(all(r.get("has_3d") is True for r in built))
        out = os.path.join(self.tmp, "no-pictures")
        fx.run("report", self.library, "-o", out, "--no-pictures")
        rows = load_data(out)["rows"]
        self.assertTrue([r for r in rows if "detail" in r])  # the card's details still load
        for row in rows:
            self.assertNotIn("has_3d", row)
            if "detail" in row:
                self.assertNotIn("scene", load_asset(out, row))

    def test_only_the_library_and_its_shards_manifests_are_read(self):
        # A backup beside the manifest must not bring back what the library no longer has; a shard's manifest counts.
        library = os.path.join(self.tmp, "with-backup")
        shutil.copytree(self.library, library)
        gone = dict(fx.manifest(library)[0], output=os.path.join(library, "gone.vox.h5"), input="gone.obj")
        gone.pop("output_from_manifest", None)
        for name in ("manifest-backup.jsonl", "manifest.old.jsonl", "manifest.shard-0-of-2.jsonl.bak",
                     "manifest.shard-x-of-2.jsonl"):
            with open(os.path.join(library, name), "w") as f:
                f.write(json.dumps(gone) + "\n")
        shard = dict(gone, output=os.path.join(library, "sharded.vox.h5"), input="sharded.obj", status="failed")
        with open(os.path.join(library, "manifest.shard-1-of-2.jsonl"), "w") as f:
            f.write(json.dumps(shard) + "\n")
        out = os.path.join(self.tmp, "with-backup-report")
        summary = json.loads(fx.run("report", library, "-o", out, "--no-pictures", "--json").stdout)
        self.assertEqual(summary["meshes"], self.summary["meshes"] + 1)
        names = [r["name"] for r in load_data(out)["rows"]]
        self.assertIn("sharded.obj", names)
        self.assertNotIn("gone.obj", names)

    def test_a_hostile_record_cannot_point_the_page_elsewhere(self):
        row = next(r for r in self.data["rows"] if r["output_name"] == "hostile.vox.h5")
        self.assertNotIn("detail", row)
        self.assertNotIn("views", row)
        self.assertEqual(row["status"], "failed")
        # "__proto__" stays an ordinary key: data.js is JSON.parse of a string, not an object literal.
        proto = next(r for r in self.data["rows"] if r["output_name"] == "proto.vox.h5")
        self.assertIn("__proto__", proto)
        with open(os.path.join(self.report, "data.js")) as f:
            self.assertTrue(f.read().startswith('window.VOXFMT_REPORT = JSON.parse("'))

    def test_a_record_too_long_to_be_one_is_skipped_not_read(self):
        # 2 MiB in one line (over the 1 MiB a record may take): counted as skipped, not held nor copied into the page.
        library = os.path.join(self.tmp, "long-record")
        shutil.copytree(self.library, library)
        with open(os.path.join(library, "manifest.jsonl"), "a") as f:
            f.write(json.dumps({"output": "x" * (2 << 20), "status": "built"}) + "\n")
        out = os.path.join(self.tmp, "long-record-report")
        p = fx.run("report", library, "-o", out, "--no-pictures", "--json")
        summary = json.loads(p.stdout)
        self.assertEqual(summary["skipped_manifest_lines"], self.summary["skipped_manifest_lines"] + 1)
        self.assertEqual(summary["meshes"], self.summary["meshes"])
        self.assertLess(os.path.getsize(os.path.join(out, "data.js")), 1 << 20)

    def test_a_record_of_many_path_parts_or_leaving_the_library_is_not_searched_for(self):
        # 64,000 parts in one output (128 KB) once took minutes (every tail looked up); "../" never leaves the library.
        library = os.path.join(self.tmp, "many-parts")
        os.makedirs(library)
        outside = os.path.join(self.tmp, "outside.vox.h5")
        shutil.copy(os.path.join(self.library, "tet.obj.vox.h5"), outside)
        records = [{"output": "a/" * 64000 + "x.vox.h5", "status": "ok"},
                   {"output": "../" * 8 + outside.lstrip("/"), "status": "ok"}]
        with open(os.path.join(library, "manifest.jsonl"), "w") as f:
            f.write("".join(json.dumps(r) + "\n" for r in records))
        p = fx.run("report", library, "--no-pictures", "--json")
        rows = load_data(os.path.join(library, "report"))["rows"]
        self.assertEqual(json.loads(p.stdout)["meshes"], 2)
        self.assertEqual(sorted(r["output_name"] for r in rows), ["outside.vox.h5", "x.vox.h5"])
        for row in rows:  # neither found: the file outside the library was not read into the page
            self.assertNotIn("detail", row)
            self.assertEqual(row["asset_error"]["code"], "FILE_NOT_FOUND")
            self.assertIn(library, row["asset_error"]["message"])

    def test_fields_of_the_wrong_type_are_dropped_not_shown(self):
        # A hand-edited manifest: a number as the status, a string as a time, warnings that are not objects.
        library = os.path.join(self.tmp, "mistyped")
        os.makedirs(library)
        records = [
            {"output": "a.vox.h5", "status": 5, "error": "boom", "timings_s": "abc", "total_s": "x", "volume": [1],
             "warnings": {"a": 1}, "voxelmap": 7, "finished_utc": 9},
            {"output": "b.vox.h5", "status": "failed", "error": {"code": 7, "message": ["m"]}, "input": 12},
            {"output": "c.vox.h5", "status": "ok", "error": None, "warnings": [1, {"code": 3}, "s"],
             "timings_s": {"import": "1"}, "total_s": 2.5},
        ]
        with open(os.path.join(library, "manifest.jsonl"), "w") as f:
            f.write("".join(json.dumps(r) + "\n" for r in records))
        p = fx.run("report", library, "--json")
        summary = json.loads(p.stdout)
        self.assertEqual((summary["meshes"], summary["built"], summary["failed"]), (3, 1, 1))
        rows = {r["output_name"]: r for r in load_data(os.path.join(library, "report"))["rows"]}
        for key in ("status", "error", "timings_s", "total_s", "volume", "warnings", "voxelmap", "finished_utc"):
            self.assertNotIn(key, rows["a.vox.h5"], key)
        self.assertNotIn("error", rows["b.vox.h5"])
        self.assertNotIn("input", rows["b.vox.h5"])
        self.assertEqual(rows["b.vox.h5"]["name"], "b")  # from the output, as for any record without an input
        for key in ("warnings", "timings_s"):
            self.assertNotIn(key, rows["c.vox.h5"], key)
        self.assertEqual(rows["c.vox.h5"]["total_s"], 2.5)

    def test_run_twice_replaces_the_report(self):
        out = os.path.join(self.tmp, "again")
        for target in (out, out + "/", out + "/"):  # a trailing slash names the same folder
            p = fx.run("report", self.library, "-o", target)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertEqual(load_data(out)["kind"], "library")
        self.assertFalse([n for n in os.listdir(self.tmp) if ".partial-" in n or ".old-" in n])
        # A report folder that gained a file of someone's is not a report any more: never replaced.
        with open(os.path.join(out, "notes.txt"), "w") as f:
            f.write("mine")
        p = fx.run("report", self.library, "-o", out, check=False)
        self.assertEqual(p.returncode, 2)
        self.assertIn("BAD_OPTION", p.stderr)
        self.assertTrue(os.path.isfile(os.path.join(out, "notes.txt")))
        # Nor is a folder whose img/ or assets/ holds someone's files (the names alone once passed for a report's).
        for sub, name in (("img", "photo.jpg"), ("assets", "notes.txt"), ("assets", "model.vox.h5")):
            site = os.path.join(self.tmp, "site-" + sub + "-" + name)
            os.makedirs(os.path.join(site, sub))
            with open(os.path.join(site, sub, name), "w") as f:
                f.write("mine")
            p = fx.run("report", self.library, "-o", site, "--no-pictures", check=False)
            self.assertEqual(p.returncode, 2, (sub, name, p.stderr))
            self.assertIn("holds files a report does not write", p.stderr)
            self.assertTrue(os.path.isfile(os.path.join(site, sub, name)))

    def test_a_folder_is_replaced_only_when_it_is_a_report(self):
        # The names a report writes are common ones: a site's index.html or someone's data.js alone is no report.
        cases = {"only-index": {"index.html": "<p>my site</p>"},
                 "only-data": {"data.js": "var mine = 1;\n"},
                 "page-and-data": {"index.html": "<p>x</p>", "data.js": "window.OTHER = 1;\n"}}
        for case, files in cases.items():
            site = os.path.join(self.tmp, "site-" + case)
            os.makedirs(site)
            for name, text in files.items():
                with open(os.path.join(site, name), "w") as f:
                    f.write(text)
            p = fx.run("report", self.library, "-o", site, "--no-pictures", check=False)
            self.assertEqual(p.returncode, 2, (case, p.stderr))
            self.assertIn("holds files a report does not write", p.stderr)
            for name, text in files.items():
                with open(os.path.join(site, name)) as f:
                    self.assertEqual(f.read(), text, case)
        # An empty folder holds nothing to lose; a previous report is replaced (test_run_twice_replaces_the_report).
        empty = os.path.join(self.tmp, "empty-folder")
        os.makedirs(empty)
        p = fx.run("report", self.library, "-o", empty, "--no-pictures", check=False)
        self.assertEqual(p.returncode, 0, p.stderr)

    def test_usage_errors(self):
        p = fx.run("report", os.path.join(self.tmp, "nowhere"), check=False)
        self.assertEqual(p.returncode, 2)
        self.assertIn("FILE_NOT_FOUND", p.stderr)
        self.assertIn("no such folder", p.stderr)  # not "no manifest.jsonl here"
        p = fx.run("report", os.path.join(self.tmp, "nowhere"), "--json", check=False)
        self.assertEqual(json.loads(p.stdout)["code"], "FILE_NOT_FOUND")
        p = fx.run("report", self.library, "--manifest", self.library, check=False)
        self.assertIn("a folder, not a manifest", p.stderr)
        p = fx.run("report", self.library, "--size-threshold", "0.5", check=False)  # meaningless without --against
        self.assertEqual(p.returncode, 2)
        self.assertIn("--against", p.stderr)
        p = fx.run("report", self.library, "--against", os.path.join(self.tmp, "nowhere"), "-o", os.path.join(self.tmp, "x"), check=False)
        self.assertEqual(p.returncode, 2)
        self.assertFalse(os.path.exists(os.path.join(self.tmp, "x")))
        # An output folder that is not a report is never replaced.
        precious = os.path.join(self.tmp, "precious")
        os.makedirs(precious)
        with open(os.path.join(precious, "thesis.tex"), "w") as f:
            f.write("x")
        p = fx.run("report", self.library, "-o", precious, check=False)
        self.assertEqual(p.returncode, 2)
        self.assertIn("BAD_OPTION", p.stderr)
        self.assertTrue(os.path.isfile(os.path.join(precious, "thesis.tex")))

    def test_a_folder_of_assets_without_a_manifest(self):
        # Assets baked one by one, or copied from elsewhere: each *.vox.h5 below the folder gets its card, from the
        # file alone; a damaged one carries its code; other files are not assets.
        folder = os.path.join(self.tmp, "loose")
        os.makedirs(os.path.join(folder, "sub", "deeper"))
        shutil.copy(os.path.join(self.library, "tet.obj.vox.h5"), os.path.join(folder, "tet.vox.h5"))
        shutil.copy(os.path.join(self.library, "tet.obj.vox.h5"), os.path.join(folder, "sub", "deeper", "tet.vox.h5"))
        shutil.copy(os.path.join(self.library, "damaged.obj.vox.h5"), os.path.join(folder, "sub", "damaged.vox.h5"))
        with open(os.path.join(folder, "notes.txt"), "w") as f:
            f.write("not an asset")
        p = fx.run("report", folder, "--json")
        summary = json.loads(p.stdout)
        self.assertEqual((summary["meshes"], summary["built"], summary["failed"]), (3, 3, 0))
        self.assertEqual(summary["unreadable_assets"], 1)
        rows = {r["output_name"]: r for r in load_data(os.path.join(folder, "report"))["rows"]}
        self.assertEqual(sorted(rows), ["sub/damaged.vox.h5", "sub/deeper/tet.vox.h5", "tet.vox.h5"])
        for name in ("tet.vox.h5", "sub/deeper/tet.vox.h5"):
            self.assertTrue(rows[name]["validation"]["valid"], name)
            self.assertGreater(rows[name]["volume"], 0)
            self.assertEqual(rows[name]["file_size_bytes"], os.path.getsize(os.path.join(folder, name)))
        self.assertIn("asset_error", rows["sub/damaged.vox.h5"])
        # Compared with a copy of itself: no change, though the damaged asset is read only on this side.
        copy = os.path.join(self.tmp, "loose-copy")
        shutil.copytree(folder, copy, ignore=shutil.ignore_patterns("report"))
        p = fx.run("report", folder, "--against", copy, "-o", os.path.join(self.tmp, "loose-vs-copy"))
        data = load_data(os.path.join(self.tmp, "loose-vs-copy"))
        self.assertEqual(len(data["against"]["rows"]), 3)
        self.assertTrue(all(r.get("unread") for r in data["against"]["rows"]))
        self.assertNotIn("unread", json.dumps(data["rows"]))
        # A folder with neither a manifest nor an asset says so.
        empty = os.path.join(self.tmp, "no-assets")
        os.makedirs(empty)
        p = fx.run("report", empty, check=False)
        self.assertEqual(p.returncode, 2)
        self.assertIn("no manifest.jsonl and no *.vox.h5 asset here", p.stderr)

    def test_inspect_html(self):
        asset = os.path.join(self.library, "tet.obj.vox.h5")
        out = os.path.join(self.tmp, "card")
        p = fx.run("inspect", asset, "--html", out)
        self.assertEqual(p.returncode, 0, p.stderr)
        data = load_data(out)
        self.assertEqual(data["kind"], "asset")
        self.assertEqual(len(data["rows"]), 1)
        self.assertTrue(data["rows"][0]["validation"]["valid"])
        # No manifest record: the grid, points and volume come from the asset.
        self.assertEqual(len(data["rows"][0]["voxelmap"]["dims"]), 3)
        self.assertGreater(data["rows"][0]["pointshell"]["points_per_level"][-1], 0)
        self.assertGreater(data["rows"][0]["volume"], 0)
        self.assertIn("scene", load_asset(out, data["rows"][0]))
        self.assertTrue(data["rows"][0]["has_3d"])
        # The bake's warnings and settings, from the asset's provenance, as plain `inspect` prints them.
        p = fx.run("inspect", os.path.join(self.library, "sheet.obj.vox.h5"), "--html", os.path.join(self.tmp, "sheet"))
        self.assertEqual(p.returncode, 0, p.stderr)
        sheet = load_data(os.path.join(self.tmp, "sheet"))["rows"][0]
        self.assertIn("OPEN_BORDER", [w["code"] for w in sheet["warnings"]])
        self.assertEqual(sheet["build_parameters"]["resolution"], 24)
        # Bare relative names, run from the asset's own folder (its parent path is empty).
        here = os.path.join(self.tmp, "here")
        os.makedirs(here, exist_ok=True)
        shutil.copy(asset, os.path.join(here, "tet.vox.h5"))
        p = fx.run("inspect", "tet.vox.h5", "--html", "card", cwd=here, check=False)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertEqual(load_data(os.path.join(here, "card"))["library"], os.path.abspath(here))
        p = fx.run("inspect", os.path.join(self.library, "damaged.obj.vox.h5"), "--html", os.path.join(self.tmp, "bad"),
                   check=False)
        self.assertNotEqual(p.returncode, 0)
        self.assertRegex(p.stderr, r"error: [A-Z0-9_]+:")
        self.assertFalse(os.path.exists(os.path.join(self.tmp, "bad")))

    def test_batch_report(self):
        meshes = os.path.join(self.tmp, "meshes")
        out = os.path.join(self.tmp, "batched")
        p = fx.run("batch", meshes, "-o", out, "--resolution", "16", "--points", "200", "-q", "--report")
        self.assertIn("report: ", p.stdout)
        self.assertEqual(len(load_data(os.path.join(out, "report"))["rows"]), fx.MESH_COUNT)
        # With its own manifest file, the report reads that one.
        other = os.path.join(self.tmp, "batched2")
        p = fx.run("batch", meshes, "-o", other, "--resolution", "16", "--points", "200", "-q", "--report",
                   "--manifest", os.path.join(self.tmp, "custom.jsonl"))
        self.assertIn("report: ", p.stdout)
        self.assertEqual(len(load_data(os.path.join(other, "report"))["rows"]), fx.MESH_COUNT)


class UpAxisViewsTest(unittest.TestCase):
    """The pictures stand the asset the right way up for each of the six up axes (a negative one drew it upside
    down, and an X axis as if Y were up)."""

    def test_the_up_axis_points_up_in_the_pictures(self):
        tmp = tempfile.mkdtemp(prefix="voxfmt-report-up-")
        self.addCleanup(shutil.rmtree, tmp, True)
        for axis in ("+X", "-X", "+Y", "-Y", "+Z", "-Z"):
            # A mushroom along the up axis: a thin stem, then a wide cap further up.
            index, sign = "XYZ".index(axis[1]), 1 if axis[0] == "+" else -1
            def box(low, high, width):
                lo, hi = [-width] * 3, [width] * 3
                lo[index], hi[index] = (low, high) if sign > 0 else (-high, -low)
                return lo, hi
            meshes = os.path.join(tmp, "meshes" + axis)
            os.makedirs(meshes)
            with open(os.path.join(meshes, "mushroom.obj"), "w") as f:
                f.write(box_obj(*box(0, 2, 0.2), 0) + box_obj(*box(2, 2.6, 1.0), 8))
            library, report = os.path.join(tmp, "library" + axis), os.path.join(tmp, "report" + axis)
            fx.run("batch", meshes, "-o", library, "--resolution", "48", "--points", "3000", "--up-axis=" + axis, "-q")
            fx.run("report", library, "-o", report)
            [row] = [r for r in load_data(report)["rows"] if r["status"] == "ok"]
            self.assertEqual(load_asset(report, row)["scene"]["view"]["up"], [index, sign])
            for picture, panels in ((row["views"], 3), (row["slice"], 1)):
                width, height, rows = png_pixels(os.path.join(report, picture))
                for panel in range(panels - (panels == 3)):  # the top view looks down the axis
                    columns = range(panel * width // panels, (panel + 1) * width // panels)
                    # The shell's points in a view, the inside (red) in the slice: the wider cap shows as more.
                    shown = (lambda p: p != (255, 255, 255)) if panels == 3 else (lambda p: p[0] > p[2] + 20)
                    drawn = [y for y in range(height) for x in columns if shown(rows[y][x])]
                    top = sum(1 for y in drawn if y < height / 2)
                    self.assertGreater(top, len(drawn) - top, "%s: %s panel %d is upside down" % (axis, picture, panel))


if __name__ == "__main__":
    unittest.main()
