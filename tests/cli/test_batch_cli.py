"""`voxfmt batch`: naming, failures, up-to-date skipping, --force, shards, SIGKILL and resume."""
import json
import os
import signal
import subprocess
import tempfile
import time
import unittest

from terminal import run_on_terminal

VOXFMT = os.environ.get("VOXFMT_BIN")
SMALL = ["--resolution", "12", "--points", "100"]

TET_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"


def cube_off(size, offset=0.0):
    v = [(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    lines = ["OFF", "8 6 0"]
    lines += ["%g %g %g" % (offset + size * x, size * y, size * z) for x, y, z in v]
    lines += ["4 %d %d %d %d" % q for q in quads]
    return "\n".join(lines) + "\n"


# Only a degenerate (collinear) triangle: nothing is left after repair, the bake fails with EMPTY_SCENE. (A flat
# sheet bakes: as a shell.)
FLAT_OFF = "OFF\n3 1 0\n0 0 0\n1 0 0\n2 0 0\n3 0 1 2\n"


@unittest.skipUnless(VOXFMT, "VOXFMT_BIN not set")
class Batch(unittest.TestCase):
    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory()
        self.root = self.tmp.name
        self.lib = os.path.join(self.root, "lib")
        self.out = os.path.join(self.root, "out")
        self.write("lib/a/model.obj", TET_OBJ)
        self.write("lib/b/model.obj", TET_OBJ.replace("v 0 0 1", "v 0 0 2"))
        self.write("lib/b/cube.off", cube_off(2.0))
        self.write("lib/broken/flat.off", FLAT_OFF)
        self.write("lib/notes.md", "not a mesh\n")  # not an extension assimp reads: ignored by the scan

    def tearDown(self):
        self.tmp.cleanup()

    def write(self, relative, text):
        path = os.path.join(self.root, relative)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write(text)
        return path

    def batch(self, *args, out=None, expect=None):
        r = subprocess.run([VOXFMT, "batch", *args, "-o", out or self.out, "--json", "-j", "2", *SMALL],
                           capture_output=True, text=True, timeout=120)
        if expect is not None:
            self.assertEqual(r.returncode, expect, r.stdout + r.stderr)
        return r, (json.loads(r.stdout) if r.stdout.strip() else None)

    def test_threads_follow_the_cpus_the_task_may_use(self):
        """Under Slurm (--cpus-per-task), taskset or a cpuset, a bake's default thread count is what the process
        may run on, not the machine's core count."""
        r = subprocess.run(["taskset", "-c", "0", VOXFMT, "batch", self.lib, "-o", self.out, "-j", "1", *SMALL],
                           capture_output=True, text=True, timeout=120)
        self.assertIn("-j 1 (1 thread(s) each)", r.stdout + r.stderr)

    def manifest(self, path=None):
        with open(path or os.path.join(self.out, "manifest.jsonl")) as f:
            return [json.loads(line) for line in f]

    def last_records(self, path=None):
        return {rec["output"]: rec for rec in self.manifest(path)}

    def assets(self, directory=None):
        found = []
        for dirpath, _, files in os.walk(directory or self.out):
            found += [os.path.relpath(os.path.join(dirpath, f), directory or self.out) for f in files if f.endswith(".vox.h5")]
        return sorted(found)

    def assert_valid(self, directory=None):
        files = [os.path.join(directory or self.out, a) for a in self.assets(directory)]
        v = subprocess.run([VOXFMT, "validate", *files], capture_output=True, text=True)
        self.assertEqual(v.returncode, 0, v.stdout)

    def test_names_failures_and_manifest(self):
        r, summary = self.batch(self.lib, expect=1)  # one mesh failed
        self.assertEqual((summary["built"], summary["up_to_date"], summary["failed"]), (3, 0, 1), r.stderr)
        # Same-named meshes in different folders: distinct outputs mirroring the folders.
        self.assertEqual(self.assets(), ["a/model.obj.vox.h5", "b/cube.off.vox.h5", "b/model.obj.vox.h5"])
        self.assert_valid()
        records = self.last_records()
        self.assertEqual(len(self.manifest()), 4)
        failed = records[os.path.join(self.out, "broken/flat.off.vox.h5")]
        self.assertEqual(failed["status"], "failed")
        self.assertEqual(failed["error"]["code"], "EMPTY_SCENE")
        self.assertIn("flat.off", failed["error"]["message"])
        self.assertIn("build", failed["command"])
        ok = records[os.path.join(self.out, "b/cube.off.vox.h5")]
        self.assertEqual(ok["status"], "ok")
        self.assertIsNone(ok["error"])
        for key in ("input", "timings_s", "file_size_bytes", "input_bytes", "warnings", "source_sha256", "build_parameters"):
            self.assertIn(key, ok)
        self.assertEqual(ok["file_size_bytes"], os.path.getsize(ok["output"]))
        self.assertEqual(summary["failures"][0]["code"], "EMPTY_SCENE")
        self.assertFalse([f for f in os.listdir(os.path.join(self.out, "broken"))] if os.path.isdir(os.path.join(self.out, "broken")) else [])

    def test_prune_removes_the_assets_of_meshes_no_longer_among_the_inputs(self):
        """A mesh deleted from the library is said (not_in_inputs) and its asset kept, until --prune removes the
        asset and its record: the next run and the report no longer know it."""
        self.batch(self.lib, expect=1)
        os.remove(os.path.join(self.lib, "b/cube.off"))
        # A record edited to name a file outside OUTDIR: counted, never deleted.
        elsewhere = self.write("precious.vox.h5", "not ours\n")
        with open(os.path.join(self.out, "manifest.jsonl"), "a") as f:
            f.write(json.dumps({"output": elsewhere, "status": "ok"}) + "\n")
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual((summary["not_in_inputs"], summary["pruned"]), (2, 0))
        self.assertIn("b/cube.off.vox.h5", self.assets())
        r, summary = self.batch(self.lib, "--prune", expect=1)
        self.assertEqual((summary["not_in_inputs"], summary["pruned"]), (2, 1))
        self.assertEqual(self.assets(), ["a/model.obj.vox.h5", "b/model.obj.vox.h5"])
        self.assertTrue(os.path.exists(elsewhere))
        report = subprocess.run([VOXFMT, "report", self.out, "-o", os.path.join(self.root, "rep"), "--json"],
                                capture_output=True, text=True, timeout=120)
        # Two built, the failed one and the edited record; not the pruned one.
        self.assertEqual(json.loads(report.stdout)["meshes"], 4, report.stderr)
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual(summary["not_in_inputs"], 1)  # the record naming a file elsewhere stays
        self.assertFalse([rec for rec in self.manifest() if "cube" in rec["output"]])

    def test_the_output_folder_spelled_another_way_keeps_one_record_a_mesh(self):
        """"./out/" or a link to the folder name the same outputs as the path the first batch was given: their
        records are found (the failed mesh is not retried) and compaction keeps one record a mesh."""
        self.batch(self.lib, expect=1)
        os.symlink(self.out, os.path.join(self.root, "link"))
        # A record of the same asset written with another spelling (as an older version would have left it).
        first = [rec for rec in self.manifest() if rec["output"].endswith("a/model.obj.vox.h5")][0]
        with open(os.path.join(self.out, "manifest.jsonl"), "a") as f:
            f.write(json.dumps(dict(first, output="./out/a/model.obj.vox.h5")) + "\n")
        report = subprocess.run([VOXFMT, "report", "out", "-o", "rep", "--json"], cwd=self.root, capture_output=True,
                                text=True, timeout=120)
        self.assertEqual(json.loads(report.stdout)["meshes"], 4, report.stderr)  # not 5
        for spelling in ("./out/", "link"):
            r = subprocess.run([VOXFMT, "batch", "lib", "-o", spelling, "--json", "-j", "2", *SMALL], cwd=self.root,
                               capture_output=True, text=True, timeout=120)
            self.assertEqual(r.returncode, 1, r.stdout + r.stderr)
            summary = json.loads(r.stdout)
            self.assertEqual((summary["built"], summary["up_to_date"], summary["failed_not_retried"]), (0, 3, 1))
        # Each run found every record (nothing to append); compaction kept one record a mesh.
        self.assertEqual(len(self.manifest()), 4)
        self.assertEqual(len({os.path.realpath(os.path.join(self.root, rec["output"])) for rec in self.manifest()}), 4)

    def test_a_library_is_the_same_from_any_working_directory_and_after_it_moves(self):
        """Records say where their asset is from the manifest's folder too: a batch run again from inside the
        library (Slurm and cron start elsewhere) finds every record, and a library moved elsewhere keeps its
        report and its up-to-date assets. (Records kept only the path from the batch's working directory: the rerun
        found none, baked the failure again, and the report counted every mesh twice.)"""
        first = subprocess.run([VOXFMT, "batch", "lib", "-o", "out", "--json", "-j", "2", *SMALL], cwd=self.root,
                               capture_output=True, text=True, timeout=120)
        self.assertEqual(first.returncode, 1, first.stdout + first.stderr)

        def batch_in(cwd, library, out):
            r = subprocess.run([VOXFMT, "batch", library, "-o", out, "--json", "-j", "2", *SMALL], cwd=cwd,
                               capture_output=True, text=True, timeout=120)
            self.assertEqual(r.returncode, 1, r.stdout + r.stderr)
            return json.loads(r.stdout)

        inside = batch_in(self.out, "../lib", ".")
        self.assertEqual((inside["built"], inside["up_to_date"], inside["failed_not_retried"],
                          inside["not_in_inputs"]), (0, 3, 1, 0))
        self.assertEqual(len(self.manifest()), 4)
        moved = os.path.join(self.root, "elsewhere", "library")
        os.makedirs(os.path.dirname(moved))
        os.rename(self.out, moved)
        report = subprocess.run([VOXFMT, "report", moved, "-o", os.path.join(self.root, "rep"), "--json"],
                                capture_output=True, text=True, timeout=120)
        summary = json.loads(report.stdout)
        self.assertEqual((summary["meshes"], summary["failed"], summary["unreadable_assets"]), (4, 1, 0), report.stderr)
        again = batch_in(self.root, "lib", "elsewhere/library")
        self.assertEqual((again["built"], again["up_to_date"], again["failed_not_retried"], again["not_in_inputs"]),
                         (0, 3, 1, 0))
        # A manifest in a linked folder, its assets reached by "..": located from the folder the link resolves to.
        os.makedirs(os.path.join(self.root, "real", "a", "b", "logs"))
        os.symlink(os.path.join("real", "a", "b", "logs"), os.path.join(self.root, "logs"))
        for _ in range(2):
            linked = subprocess.run([VOXFMT, "batch", "lib", "-o", "elsewhere/library", "--manifest", "logs/m.jsonl",
                                     "--json", "-j", "2", *SMALL], cwd=self.root, capture_output=True, text=True,
                                    timeout=120)
            self.assertEqual(json.loads(linked.stdout)["not_in_inputs"], 0, linked.stdout + linked.stderr)

    def test_rerun_skips_force_rebuilds_and_option_change_rebuilds(self):
        self.batch(self.lib, expect=1)
        before = {a: os.stat(os.path.join(self.out, a)).st_mtime_ns for a in self.assets()}
        # Everything up to date; the deterministic failure is not retried but still counts.
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual((summary["built"], summary["up_to_date"], summary["failed"], summary["failed_not_retried"]), (0, 3, 1, 1))
        self.assertEqual(before, {a: os.stat(os.path.join(self.out, a)).st_mtime_ns for a in self.assets()})
        self.assertEqual(len(self.manifest()), 4, "a rerun with nothing to do keeps one record per mesh")
        # Touched assets are up to date by their provenance and keep their bake's figures (the report shows them).
        for asset in self.assets():
            os.utime(os.path.join(self.out, asset))
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual((summary["built"], summary["up_to_date"]), (0, 3))
        kept = [rec for rec in self.last_records().values() if rec["status"] == "up_to_date"]
        self.assertEqual(len(kept), 3)
        self.assertTrue(all(rec.get("total_s", 0) > 0 and rec.get("input_triangles") for rec in kept), kept)
        # Without the manifest the assets' provenance proves them up to date.
        os.remove(os.path.join(self.out, "manifest.jsonl"))
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual((summary["built"], summary["up_to_date"]), (0, 3))
        self.assertEqual({rec["status"] for rec in self.manifest()}, {"up_to_date", "failed"})
        # An asset damaged past its provenance (its compressed bricks overwritten, the same size) is not up to date.
        import h5py  # the spec tests' interpreter has it
        damaged = os.path.join(self.out, "b", "cube.off.vox.h5")
        with h5py.File(damaged, "r") as f:
            chunk = f["voxelmap/brick_values"].id.get_chunk_info(0)
        with open(damaged, "r+b") as f:
            f.seek(chunk.byte_offset)
            f.write(b"\xff" * chunk.size)
        self.assertNotEqual(subprocess.run([VOXFMT, "validate", damaged], capture_output=True).returncode, 0)
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual((summary["built"], summary["up_to_date"]), (1, 2), r.stderr)
        self.assertEqual(subprocess.run([VOXFMT, "validate", damaged], capture_output=True).returncode, 0)
        # --force rebuilds (and retries the failure).
        r, summary = self.batch(self.lib, "--force", expect=1)
        self.assertEqual((summary["built"], summary["up_to_date"], summary["failed_not_retried"]), (3, 0, 0))
        # A changed build option rebuilds; so does a changed source.
        r, summary = self.batch(self.lib, "--seed", "7", expect=1)
        self.assertEqual(summary["built"], 3)
        self.write("lib/a/model.obj", TET_OBJ.replace("v 1 0 0", "v 3 0 0"))
        r, summary = self.batch(self.lib, "--seed", "7", expect=1)
        self.assertEqual((summary["built"], summary["up_to_date"]), (1, 2))
        # A fixed mesh is retried (its source hash changed) and succeeds.
        self.write("lib/broken/flat.off", cube_off(1.0, offset=5))
        r, summary = self.batch(self.lib, "--seed", "7", expect=0)
        self.assertEqual((summary["built"], summary["failed"]), (1, 0))
        self.assert_valid()

    def test_a_file_name_that_is_not_utf8_is_kept_exactly(self):
        # JSON holds UTF-8 only: the name used to reach the manifest as U+FFFD, so no record matched its asset, and
        # the asset itself was invalid (its provenance named the file in raw bytes).
        lib = os.path.join(self.root.encode(), b"odd")
        os.makedirs(lib)
        with open(os.path.join(lib, b"m\xff.obj"), "w") as f:
            f.write(TET_OBJ)
        out = os.path.join(self.root, "odd-out")
        r, summary = self.batch(lib.decode("utf-8", "surrogateescape"), out=out, expect=0)
        self.assertEqual(summary["built"], 1)
        asset = os.path.join(out.encode(), b"m\xff.obj.vox.h5")
        v = subprocess.run([VOXFMT.encode(), b"validate", asset], capture_output=True, timeout=60)
        self.assertEqual(v.returncode, 0, v.stdout)
        with open(os.path.join(out, "manifest.jsonl")) as f:
            record = json.loads(f.readline())
        self.assertTrue(record["output"].endswith("m\\xFF.obj.vox.h5"), record["output"])
        self.assertEqual(bytes.fromhex(record["output_hex"]), os.path.join(out.encode(), b"m\xff.obj.vox.h5"))
        r, summary = self.batch(lib.decode("utf-8", "surrogateescape"), out=out, expect=0)
        self.assertEqual((summary["built"], summary["up_to_date"]), (0, 1))
        with open(os.path.join(out, "manifest.jsonl")) as f:
            self.assertEqual(len(f.readlines()), 1, "the manifest's record matched: nothing was appended")
        report = subprocess.run([VOXFMT, "report", out, "--json"], capture_output=True, text=True, timeout=120)
        self.assertEqual(report.returncode, 0, report.stderr)
        self.assertEqual(json.loads(report.stdout)["unreadable_assets"], 0)

    def test_a_failed_mesh_whose_name_is_not_utf8_is_named_exactly_in_the_summary(self):
        # The summary's failures showed such a name as U+FFFD (its bytes lost); now as the manifest does.
        lib = os.path.join(self.root.encode(), b"odd-broken")
        os.makedirs(lib)
        with open(os.path.join(lib, b"m\xff.obj"), "w") as f:
            f.write("this is not a mesh\n")
        out = os.path.join(self.root, "odd-broken-out")
        for retried in (True, False):  # baked and failed, then unchanged since it failed
            r, summary = self.batch(lib.decode("utf-8", "surrogateescape"), out=out, expect=1)
            [failure] = summary["failures"]
            self.assertEqual(failure["retried"], retried)
            self.assertNotIn("\ufffd", failure["input"])
            self.assertTrue(failure["input"].endswith("m\\xFF.obj"), failure["input"])
            self.assertEqual(bytes.fromhex(failure["input_hex"]), os.path.join(lib, b"m\xff.obj"))
            self.assertEqual(bytes.fromhex(failure["output_hex"]), os.path.join(out.encode(), b"m\xff.obj.vox.h5"))

    def test_a_report_folder_that_would_hold_assets_is_refused_before_the_bake(self):
        self.write("lib/report/model.obj", TET_OBJ)
        r, _ = self.batch(self.lib, "--report", expect=2)
        self.assertIn("report/model.obj would be baked into", r.stderr)
        self.assertEqual(self.assets(), [], "refused before any bake")
        notes = os.path.join(self.root, "notes")  # a folder of someone's: never replaced, and said before the bakes
        self.write("notes/thesis.tex", "x")
        r, _ = self.batch(self.lib, "--report-dir", notes, expect=2)
        self.assertIn("holds files a report does not write", r.stderr)
        self.assertIn("--report-dir", r.stderr)
        self.assertEqual(self.assets(), [], "refused before any bake")
        html = os.path.join(self.root, "html")
        r, summary = self.batch(self.lib, "--report-dir", html, expect=1)  # flat.off fails, as ever
        self.assertEqual(summary["built"], 4)
        self.assertTrue(os.path.isfile(os.path.join(html, "index.html")))
        # One JSON document on stdout, the report's summary in it as `voxfmt report --json` prints it.
        self.assertEqual(summary["report"]["index_html"], os.path.join(html, "index.html"))
        self.assertEqual((summary["report"]["meshes"], summary["report"]["failed"]), (5, 1), summary["report"])
        # "0/01" is one shard as the batch reads it: its report is written too.
        one = os.path.join(self.root, "one-shard")
        r, summary = self.batch(self.lib, "--shard", "0/01", "--report-dir", one, expect=1)
        self.assertTrue(os.path.isfile(os.path.join(one, "index.html")), r.stderr)
        self.assertEqual(summary["report"]["meshes"], 5)
        # A shard of several writes none (`voxfmt report` reads every shard's manifest once all are done).
        r, summary = self.batch(self.lib, "--shard", "0/2", "--report", expect=None)
        self.assertIsNone(summary["report"], r.stderr)
        self.assertIn("once every shard is done", r.stderr)

    def test_shards_cover_the_library_disjointly(self):
        for i in range(8):  # enough meshes that both shards get some
            self.write("lib/many/tet%d.obj" % i, TET_OBJ.replace("v 0 0 1", "v 0 0 %d" % (i + 1)))
        outputs = []
        for shard in ("0/2", "1/2"):
            r, summary = self.batch(self.lib, "--shard", shard, out=self.out)
            name = "manifest.shard-%s-of-2.jsonl" % shard[0]
            outputs.append({rec["output"] for rec in self.manifest(os.path.join(self.out, name))})
            self.assertEqual(summary["meshes"], len(outputs[-1]))
            self.assertEqual(summary["meshes_all_shards"], 12)
            self.assertGreater(len(outputs[-1]), 0)
        self.assertEqual(outputs[0] & outputs[1], set())
        self.assertEqual(len(outputs[0] | outputs[1]), 12)
        self.assertEqual(len(self.assets()), 11)  # all but the flat one
        # The same split again (deterministic), and every shard's work is now up to date.
        r, summary = self.batch(self.lib, "--shard", "1/2")
        self.assertEqual(summary["built"], 0)

    def test_sigkill_then_rerun_completes(self):
        for i in range(10):
            self.write("lib/many/cube%d.off" % i, cube_off(1.0 + 0.1 * i))
        args = [VOXFMT, "batch", self.lib, "-o", self.out, "-j", "2", "--resolution", "40", "--points", "2000", "-q"]
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        manifest = os.path.join(self.out, "manifest.jsonl")
        deadline = time.time() + 60
        while time.time() < deadline:  # wait until some but not all meshes are done
            if os.path.exists(manifest):
                with open(manifest) as f:
                    if len(f.read().splitlines()) >= 3:
                        break
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        done_before = len(self.manifest())
        self.assertLess(done_before, 14, "the batch finished before it could be killed; make the work larger")
        # The bakes die with the batch: no orphan keeps writing into the library.
        time.sleep(0.3)
        orphans = []
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                with open("/proc/%s/cmdline" % pid, "rb") as f:
                    if self.out.encode() in f.read():
                        orphans.append(pid)
            except OSError:
                pass
        self.assertEqual(orphans, [])
        # A temporary of a bake killed mid-write, and a manifest line torn by a crash.
        self.write("out/many/cube0.off.vox.h5.partial-999999-0", "torn")
        with open(manifest, "a") as f:  # a record with the wrong types (hand-edited), then a torn line
            f.write('{"output": %s, "status": 5, "source_sha256": null, "error": "x"}\n' %
                    json.dumps(os.path.join(self.out, "many/cube1.off.vox.h5")))
            f.write('{"input": "x", "outp')
        r = subprocess.run(args[:-1] + ["--json"], capture_output=True, text=True, timeout=120)
        self.assertEqual(r.returncode, 1, r.stderr)  # only the flat mesh fails
        summary = json.loads(r.stdout)
        self.assertEqual(summary["built"] + summary["up_to_date"], 13)
        self.assertGreater(summary["up_to_date"], 0, "finished assets were kept")
        leftovers = [f for _, _, files in os.walk(self.out) for f in files if ".partial-" in f]
        self.assertEqual(leftovers, [])
        self.assertEqual(len(self.assets()), 13)
        self.assert_valid()
        records = self.last_records()
        self.assertEqual(len(records), 14)
        self.assertEqual(sum(rec["status"] != "failed" for rec in records.values()), 13)

    def test_a_mesh_named_like_an_option_bakes_and_only_dead_bakes_temporaries_go(self):
        # "-dash.obj" once reached the bake as an option (BAD_OPTION, never retried). A temporary of a live process
        # (another batch or build writing into the library) is kept; a dead one's removed.
        self.write("lib/c/-dash.obj", TET_OBJ)
        live = self.write("out/c/-dash.obj.vox.h5.partial-%d-0" % os.getpid(), "a live bake's")
        ended = subprocess.Popen(["true"])
        ended.wait()
        dead = self.write("out/a/model.obj.vox.h5.partial-%d-0" % ended.pid, "a killed bake's")
        r, summary = self.batch(self.lib, expect=1)  # only the flat mesh fails
        self.assertNotIn("c/-dash.obj", [f["input"].split("lib/")[-1] for f in summary["failures"]], r.stderr)
        self.assertTrue(os.path.exists(os.path.join(self.out, "c", "-dash.obj.vox.h5")), r.stderr)
        self.assertTrue(os.path.exists(live), "a live process's temporary was removed")
        self.assertFalse(os.path.exists(dead), "a dead process's temporary was kept")
        # What a scan leaves out that a user may miss is said: a link to a folder, a mesh's name linking to nothing.
        os.symlink(os.path.join(self.lib, "a"), os.path.join(self.lib, "c", "linked"))
        os.symlink("gone.obj", os.path.join(self.lib, "c", "dangling.obj"))
        r, summary = self.batch(self.lib, expect=1)
        self.assertEqual(sorted(s.split(os.sep + "c" + os.sep)[-1] for s in summary["skipped_inputs"]),
                         ["dangling.obj: a link to nothing", "linked: a link to a folder, not followed"])
        r = subprocess.run([VOXFMT, "batch", self.lib, "-o", self.out, *SMALL], capture_output=True, text=True,
                           timeout=120)
        self.assertIn("warning: " + os.path.join(self.lib, "c", "dangling.obj") + ": a link to nothing", r.stderr)

    def test_a_mesh_whose_asset_name_is_as_long_as_allowed_bakes_and_its_dead_temporaries_go(self):
        # The asset's name is 255 bytes, the file system's limit: its temporary takes a shortened stem
        # (atomic_file.h's temporary_stem: the first 208 bytes, "~" and the FNV-1a hash of the whole name).
        name = "m" * 244 + ".obj"
        self.write("lib/long/" + name, TET_OBJ)
        asset = name + ".vox.h5"
        self.assertEqual(len(asset), 255)
        digest = 14695981039346656037
        for byte in asset.encode():
            digest = ((digest ^ byte) * 1099511628211) % 2**64
        ended = subprocess.Popen(["true"])
        ended.wait()
        dead = self.write("out/long/%s~%016x.partial-%d-0" % (asset[:208], digest, ended.pid), "a killed bake's")
        live = self.write("out/long/%s~%016x.partial-%d-0" % (asset[:208], digest, os.getpid()), "a live bake's")
        self.batch(self.lib, expect=1)  # only the flat mesh fails
        self.assertIn(os.path.join("long", asset), self.assets())
        self.assertFalse(os.path.exists(dead), "a dead process's temporary was kept")
        self.assertTrue(os.path.exists(live), "a live process's temporary was removed")

    def test_list_file_and_single_files(self):
        self.write("more/x/box.off", cube_off(1.0))
        self.write("lists/local/chair.obj", TET_OBJ)
        self.write("lists/meshes.txt", "# my library\n../lib/a/model.obj\n\n  ../more  \nlocal/chair.obj\n")
        r, summary = self.batch(os.path.join(self.root, "lists/meshes.txt"), expect=0)
        # A ../ entry: its file name; a listed directory: scanned; a relative entry keeps its path.
        self.assertEqual(self.assets(), ["local/chair.obj.vox.h5", "model.obj.vox.h5", "x/box.off.vox.h5"])
        # The same list with @ and a directory whose model.obj would take the same name: refused.
        self.write("lists/more.lst", "../lib/a/model.obj\n../lib/b\n")
        r, _ = self.batch("@" + os.path.join(self.root, "lists/more.lst"), expect=2)
        self.assertIn("same asset 'model.obj.vox.h5'", r.stderr)

    def test_a_list_read_from_a_pipe_is_relative_to_the_working_directory(self):
        """`find ... | voxfmt batch @/dev/stdin` and `voxfmt batch @<(find ...)`: a pipe has no folder of its own
        (its path's folder is /dev or /dev/fd), so its entries are relative to the working directory, and each
        asset is named by its entry's path as for a list file."""
        listing = "lib/a/model.obj\n./lib/b/cube.off\n"
        r = subprocess.run([VOXFMT, "batch", "@/dev/stdin", "-o", "out", "--json", *SMALL], input=listing,
                           cwd=self.root, capture_output=True, text=True, timeout=120)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(self.assets(), ["lib/a/model.obj.vox.h5", "lib/b/cube.off.vox.h5"])
        read, write = os.pipe()  # what bash's <(...) passes: /dev/fd/N
        os.write(write, listing.encode())
        os.close(write)
        try:
            r = subprocess.run([VOXFMT, "batch", "@/dev/fd/%d" % read, "-o", "fd-out", "--json", *SMALL],
                               cwd=self.root, pass_fds=(read,), capture_output=True, text=True, timeout=120)
        finally:
            os.close(read)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(self.assets(os.path.join(self.root, "fd-out")), self.assets())

    def test_a_manifest_that_cannot_be_written_is_write_failed(self):
        """A full disk or `ulimit -f` under a manifest append: WRITE_FAILED naming the manifest and the system's
        reason (exit 2, as for any output that cannot be written), not an unexpected error; bakes in flight are
        stopped and leave no temporaries."""
        import resource

        def small_files():
            resource.setrlimit(resource.RLIMIT_FSIZE, (100, 100))  # an empty compacted manifest fits, a record not
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # so that write() returns EFBIG

        def limited_batch():
            return subprocess.run([VOXFMT, "batch", self.lib, "-o", self.out, "--json", "-j", "2", *SMALL],
                                  capture_output=True, text=True, timeout=120, preexec_fn=small_files)

        manifest = os.path.join(self.out, "manifest.jsonl")
        # The bakes' own assets are over the limit too: their failures' records are the appends that fail.
        r = limited_batch()
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
        self.assertIn("WRITE_FAILED: " + manifest + ": cannot write: File too large", r.stderr)
        self.assertEqual(json.loads(r.stdout)["code"], "WRITE_FAILED")
        self.assertEqual([f for _, _, files in os.walk(self.out) for f in files if ".partial-" in f], [])
        self.assertEqual(self.children_of_this_test(), [])
        # An asset found up to date by its provenance (its record lost): that record's append fails alike.
        self.batch(self.lib, expect=1)
        os.remove(manifest)
        r = limited_batch()
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
        self.assertIn("WRITE_FAILED: " + manifest + ": cannot write: File too large", r.stderr)

    def test_a_report_that_cannot_be_written_says_why(self):
        """batch --report under a full disk or `ulimit -f`: WRITE_FAILED with the system's reason, not a bare
        "cannot write"."""
        import resource

        self.batch(self.lib, expect=1)
        limit = os.path.getsize(os.path.join(self.out, "manifest.jsonl")) + 64  # its compaction fits, the report not

        def small_files():
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

        r = subprocess.run([VOXFMT, "batch", self.lib, "-o", self.out, "--report", "-q", *SMALL], capture_output=True,
                           text=True, timeout=120, preexec_fn=small_files)
        self.assertEqual(r.returncode, 2, r.stdout + r.stderr)
        self.assertRegex(r.stderr, r"WRITE_FAILED: \S+: cannot write: File too large")

    def test_the_manifest_is_neither_an_asset_nor_an_empty_path(self):
        """--manifest naming an asset of the batch (however spelled, through a link): the asset's rename would
        replace the manifest; refused before anything is made. An empty path is refused, not read as the default."""
        mesh = os.path.join(self.lib, "b/cube.off")
        asset = os.path.join(self.out, "cube.off.vox.h5")
        link = os.path.join(self.root, "link.jsonl")
        os.symlink(asset, link)  # dangling until the asset is baked
        for manifest in (asset, os.path.join(self.out, ".", "cube.off.vox.h5"), link):
            r, _ = self.batch(mesh, "--manifest", manifest, expect=2)
            self.assertIn("BAD_OPTION", r.stderr, manifest)
            self.assertIn("is the asset of", r.stderr, manifest)
            self.assertFalse(os.path.exists(self.out), manifest)
        r, _ = self.batch(mesh, "--manifest", "", expect=2)
        self.assertIn("BAD_OPTION", r.stderr)
        self.assertIn("empty path", r.stderr)
        self.assertFalse(os.path.exists(self.out))

    def test_names_cannot_drive_the_terminal(self):
        """A mesh's name in the progress bar, an output folder's in the note of --report with --shard: control
        characters escaped. The bar is cut to the terminal's width at a character, never inside one's UTF-8."""
        name = "a\x1b[2J" + "\u00e9" * 20 + ".obj"
        mesh = self.write(name, TET_OBJ)
        r, data = run_on_terminal([VOXFMT, "batch", mesh, "-o", self.out, "-j", "1", *SMALL], stdout=subprocess.PIPE,
                                  timeout=120)  # the bar is drawn on a terminal only
        self.assertEqual(r.returncode, 0, data)
        terminal = data.decode("utf-8", errors="replace")
        self.assertNotIn("\ufffd", terminal, "a character cut inside its bytes")
        self.assertNotIn("\x1b[2J", terminal)
        bars = [part for part in terminal.split("\r\x1b[K") if part.startswith("[")]
        self.assertTrue(bars, terminal)
        self.assertIn("  a\\x1B[2J\u00e9", bars[0])
        self.assertTrue(all(len(bar.rstrip("\r\n")) <= 79 for bar in bars), bars)
        out = os.path.join(self.root, "out\x1b[2J")
        r, _ = self.batch(mesh, "--shard", "0/2", "--report", out=out, expect=None)
        self.assertIn("run `voxfmt report " + os.path.join(self.root, "out\\x1B[2J`"), r.stderr)
        self.assertNotIn("\x1b", r.stdout + r.stderr)

    def test_usage_errors(self):
        r, _ = self.batch(os.path.join(self.lib, "a/model.obj"), os.path.join(self.lib, "b/model.obj"), expect=2)
        self.assertIn("same asset", r.stderr)
        self.assertIn("model.obj", r.stderr)
        r, _ = self.batch(self.lib, "--shard", "2/2", expect=2)
        self.assertIn("--shard", r.stderr)
        r, _ = self.batch(os.path.join(self.root, "nope"), expect=2)
        self.assertIn("FILE_NOT_FOUND", r.stderr)
        self.assertIn("nope", r.stderr)
        os.makedirs(os.path.join(self.root, "empty"))
        r, _ = self.batch(os.path.join(self.root, "empty"), expect=2)
        self.assertIn("BAD_OPTION", r.stderr)
        self.assertIn("no meshes", r.stderr)
        self.assertFalse(self.assets())
        # Refused before anything is made: no empty output folder left behind.
        self.assertFalse(os.path.exists(self.out))
        # Option values that cannot be meant: coded, exit 2, nothing baked.
        for bad in (["--timeout", "nan"], ["--threads", "4294967295"], ["--max-memory", "120"],
                    ["--max-memory", "1e3"], ["--voxel-size", "0"], ["--band", "inf"]):
            r, _ = self.batch(self.lib, *bad, expect=2)
            self.assertIn("BAD_OPTION", r.stderr, bad)
            self.assertIn(bad[0], r.stderr, bad)
            self.assertFalse(os.path.exists(self.out), bad)
        # A size written as "1e3" is 1000 to a reader: the message says what is wrong with it, not "not in range".
        r, _ = self.batch(self.lib, "--max-memory", "1e3", expect=2)
        self.assertIn("whole number", r.stderr)

    def test_nothing_that_is_not_a_manifest_or_a_mesh_is_overwritten_or_waited_for(self):
        # --manifest naming a mesh or notes: refused, the file untouched (compaction used to rewrite it).
        mesh = os.path.join(self.lib, "a/model.obj")
        notes = self.write("notes.txt", "my notes\n")
        minified = self.write("other-tool.json", '{"a": "' + "x" * (2 << 20) + '"}')  # one line over 1 MiB
        for path, before in ((mesh, TET_OBJ), (notes, "my notes\n"), (minified, None)):
            before = before if before is not None else open(path).read()
            r, _ = self.batch(mesh, "--manifest", path, expect=2)
            self.assertIn("not a manifest, not overwritten", r.stderr)
            with open(path) as f:
                self.assertEqual(f.read(), before)
        # A record torn by a crash is still a manifest: the run goes on. Through a link, the link stays one.
        torn = self.write("torn.jsonl", '{"output": "x.vox')
        link = os.path.join(self.root, "link.jsonl")
        os.symlink("torn.jsonl", link)
        self.batch(mesh, "--manifest", link, expect=0)
        self.assertTrue(os.path.islink(link))
        with open(torn) as f:
            self.assertIn("model.obj.vox.h5", f.read())
        # A FIFO given as a mesh (explicitly or in a list) or as the manifest is refused at once, not waited for.
        fifo = os.path.join(self.root, "pipe.obj")
        os.mkfifo(fifo)
        listed = self.write("pipes.txt", "pipe.obj\n")
        for args in ([fifo, mesh], ["@" + listed], [mesh, "--manifest", fifo]):
            r, _ = self.batch(*args, expect=2)
            self.assertIn("not a regular file", r.stderr)
        os.makedirs(os.path.join(self.root, "folder.txt"))
        r, _ = self.batch("@" + os.path.join(self.root, "folder.txt"), mesh, expect=2)
        self.assertIn("is a folder, not a list file", r.stderr)

    def children_of_this_test(self):
        found = []
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                with open("/proc/%s/cmdline" % pid, "rb") as f:
                    args = f.read().split(b"\0")
            except OSError:
                continue
            if b"build" in args and any(self.out.encode() in a for a in args):
                found.append(int(pid))
        return found

    def slow_batch_and_its_bake(self, mesh):
        """A batch of one slow bake, and the bake's process id once it runs."""
        proc = subprocess.Popen([VOXFMT, "batch", mesh, "-o", self.out, "--resolution", "300", "--points", "20000",
                                 "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 30
        children = []
        while not children and time.time() < deadline:
            children = self.children_of_this_test()
            time.sleep(0.01)
        self.assertTrue(children, "the bake child was not seen")
        return proc, children[0]

    def test_a_crashing_bake_is_recorded_and_retried(self):
        # A bake that dies of a signal (here SIGSEGV sent by the test, as a broken library would) costs one
        # recorded failure; the batch goes on, and the next run retries it.
        mesh = os.path.join(self.lib, "b/cube.off")
        proc, bake = self.slow_batch_and_its_bake(mesh)
        os.kill(bake, signal.SIGSEGV)
        out, _ = proc.communicate(timeout=60)
        self.assertEqual(proc.returncode, 1)
        failure = json.loads(out)["failures"][0]
        self.assertEqual(failure["code"], "CRASHED")
        self.assertIn("signal %d" % signal.SIGSEGV, failure["message"])
        self.assertEqual(self.assets(), [])
        r, summary = self.batch(mesh, expect=0)
        self.assertEqual(summary["built"], 1)

    def test_a_bake_stopped_just_before_its_batch_is_not_a_failure(self):
        # scancel (or systemd) signals the batch and its bakes; the bake may be first. Its death is not recorded as a
        # crash (which the report would count): the batch stops, records nothing, and the next run bakes the mesh.
        mesh = os.path.join(self.lib, "b/cube.off")
        proc, bake = self.slow_batch_and_its_bake(mesh)
        os.kill(bake, signal.SIGTERM)
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        self.assertEqual(proc.returncode, 128 + signal.SIGTERM, err)
        self.assertEqual([rec for rec in self.manifest() if rec.get("status") == "failed"], [], err)
        self.assertEqual(self.assets(), [])
        r, summary = self.batch(mesh, expect=0)
        self.assertEqual((summary["built"], summary["failed"]), (1, 0))
        # Stopped alone (the batch goes on), the bake is recorded as crashed, after the moment's wait.
        os.remove(os.path.join(self.out, "cube.off.vox.h5"))
        proc, bake = self.slow_batch_and_its_bake(mesh)
        os.kill(bake, signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        self.assertEqual(proc.returncode, 1, err)
        self.assertEqual(json.loads(out)["failures"][0]["code"], "CRASHED")

    def test_timeout_is_a_recorded_failure(self):
        r, summary = self.batch(os.path.join(self.lib, "b/cube.off"), "--timeout", "0.001", expect=1)
        self.assertEqual(summary["failures"][0]["code"], "TIMEOUT")
        self.assertEqual(self.assets(), [])
        self.assertEqual([f for f in os.listdir(self.out) if ".partial-" in f], [])
        # A timeout is not the mesh's fault: the next run retries it.
        r, summary = self.batch(os.path.join(self.lib, "b/cube.off"), expect=0)
        self.assertEqual(summary["built"], 1)

    def test_ctrl_z_stops_the_bakes_with_the_batch(self):
        """SIGTSTP (Ctrl-Z) stops the running bakes too (each is in a process group of its own, which the terminal
        does not reach: they went on at full speed while the job looked suspended), and SIGCONT continues them; the
        time stopped counts toward no --timeout."""
        mesh = self.write("big/cube.off", cube_off(2.0))

        def children(pid):
            try:
                with open(f"/proc/{pid}/task/{pid}/children") as f:
                    return [int(c) for c in f.read().split()]
            except FileNotFoundError:
                return []

        def state(pid):
            with open(f"/proc/{pid}/stat") as f:
                return f.read().rsplit(")", 1)[1].split()[0]

        # A group of its own under this process: a stop signal to an orphaned group (a CI's setsid) is discarded.
        # A bake of about 0.3 s (3 s under AddressSanitizer), well inside --timeout, stopped longer than it.
        p = subprocess.Popen([VOXFMT, "batch", mesh, "-o", self.out, "--json", "-j", "1", "--resolution", "200",
                              "--points", "5000", "--timeout", "12"], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, preexec_fn=os.setpgrp)
        try:
            deadline = time.time() + 30
            while not children(p.pid) and time.time() < deadline:
                time.sleep(0.01)
            bakes = children(p.pid)
            self.assertTrue(bakes)
            os.kill(p.pid, signal.SIGTSTP)
            deadline = time.time() + 10
            while time.time() < deadline and not (state(p.pid) == "T" and all(state(b) == "T" for b in bakes)):
                time.sleep(0.01)
            self.assertEqual((state(p.pid), [state(b) for b in bakes]), ("T", ["T"] * len(bakes)))
            time.sleep(12.5)  # stopped longer than --timeout: not a TIMEOUT
            os.kill(p.pid, signal.SIGCONT)
            out, err = p.communicate(timeout=120)
        finally:
            if p.poll() is None:
                p.kill()
                p.wait()
        self.assertEqual(p.returncode, 0, out + err)
        self.assertEqual(json.loads(out)["built"], 1)


if __name__ == "__main__":
    unittest.main()
