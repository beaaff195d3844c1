#!/usr/bin/env python3
"""The main job's library step timed: `voxfmt batch MESHES -o FRESH -j 2` (CGAL's sample library by default), each
run into a new folder, and what the manifest says of each bake (its own `total_s` against the batch's `wall_s` for
it: the difference is the batch's overhead per mesh, a process start and the wait for its end).

    PYTHONPATH= python3 bench/library_step.py --runs 3 --json out.json --markdown out.md
    python3 bench/library_step.py --compare /tmp/voxfmt-before     # that binary and build/bin/voxfmt, alternated

Prints a table; --json and --markdown write the figures. Python standard library only.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def one_run(voxfmt: str, meshes: str, jobs: int) -> dict:
    out = tempfile.mkdtemp(prefix="voxfmt-library-step-")
    try:
        start = time.perf_counter()
        r = subprocess.run([voxfmt, "batch", meshes, "-o", os.path.join(out, "library"), "-j", str(jobs), "--json"],
                           capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if r.returncode not in (0, 1):
            sys.exit(f"library_step: {voxfmt} batch failed ({r.returncode}): {r.stderr[-2000:]}")
        summary = json.loads(r.stdout)
        records = [json.loads(line) for line in open(os.path.join(out, "library", "manifest.jsonl"))]
    finally:
        shutil.rmtree(out, ignore_errors=True)
    overhead = [r["wall_s"] - r["total_s"] for r in records if "wall_s" in r and "total_s" in r]
    return {"seconds": round(seconds, 3), "built": summary["built"], "failed": summary["failed"],
            "bake_overhead_s_median": round(statistics.median(overhead), 4) if overhead else None,
            "bake_overhead_s_max": round(max(overhead), 4) if overhead else None,
            "bakes_over_0_2_s_overhead": sum(o > 0.2 for o in overhead)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--voxfmt", default=str(ROOT / "build/bin/voxfmt"))
    ap.add_argument("--compare", help="another voxfmt binary, run alternately with --voxfmt (e.g. a build before)")
    ap.add_argument("--meshes", default=str(ROOT / "build/cgal-data/data/meshes"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--json")
    ap.add_argument("--markdown")
    args = ap.parse_args()
    binaries = [("compared", args.compare)] if args.compare else []
    binaries.append(("voxfmt", args.voxfmt))
    rows = []
    for run in range(args.runs):
        for name, binary in binaries:
            row = {"binary": name, "path": binary, "run": run, **one_run(binary, args.meshes, args.jobs)}
            rows.append(row)
            print(f"{name:9} run {run}: {row['seconds']:6.2f} s, {row['built']} built, {row['failed']} failed, "
                  f"overhead per bake median {row['bake_overhead_s_median']} s, max {row['bake_overhead_s_max']} s, "
                  f"{row['bakes_over_0_2_s_overhead']} over 0.2 s", flush=True)
    command = "python3 " + " ".join(sys.argv)
    head = ("| binary | run | s | built | failed | overhead per bake, median (s) | max (s) | bakes over 0.2 s |\n"
            "|---|---|---|---|---|---|---|---|\n")
    table = head + "".join(f"| {r['binary']} | {r['run']} | {r['seconds']:.2f} | {r['built']} | {r['failed']} | "
                           f"{r['bake_overhead_s_median']} | {r['bake_overhead_s_max']} | "
                           f"{r['bakes_over_0_2_s_overhead']} |\n" for r in rows)
    print(table)
    if args.json:
        Path(args.json).write_text(json.dumps({"command": command, "meshes": args.meshes, "jobs": args.jobs,
                                               "cpus": os.cpu_count(), "rows": rows}, indent=1) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(f"# The main job's library step\n\n`{command}` on {os.cpu_count()} CPUs.\n\n"
                                       + table)


if __name__ == "__main__":
    main()
