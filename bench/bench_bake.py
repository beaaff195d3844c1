#!/usr/bin/env python3
"""Bake benchmark: runs `voxfmt build --json` several times on one mesh and reports median per-stage timings,
peak memory and file size, as JSON (--json) or a table. Default: the seed's setting, CGAL's bunny at
--resolution 306 with --points 35000.

  python3 bench/bench_bake.py [--runs 5] [--mesh build/cgal-data/data/meshes/bunny00.off] [--json] [-- build options]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--voxfmt", default=os.path.join(ROOT, "build", "bin", "voxfmt"))
    parser.add_argument("--mesh", default=os.path.join(ROOT, "build", "cgal-data", "data", "meshes", "bunny00.off"))
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.add_argument("build_options", nargs="*", default=["--resolution", "306", "--points", "35000"])
    args = parser.parse_args()
    if not os.path.exists(args.voxfmt):
        sys.exit(f"bench_bake: {args.voxfmt} not found; build first (bash scripts/build.sh)")

    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "bench.vox.h5")
        for _ in range(args.runs):
            r = subprocess.run([args.voxfmt, "build", args.mesh, "-o", out, "--json", *args.build_options],
                               capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(f"bench_bake: build failed: {r.stderr.strip()}")
            runs.append(json.loads(r.stdout))

    stages = list(runs[0]["timings_s"].keys())
    result = {
        "mesh": os.path.basename(args.mesh),
        "options": args.build_options,
        "runs": args.runs,
        "cores": os.cpu_count(),
        "total_s_median": statistics.median(r["total_s"] for r in runs),
        "total_s_min": min(r["total_s"] for r in runs),
        "stage_s_median": {s: statistics.median(r["timings_s"][s] for r in runs) for s in stages},
        "peak_memory_mib": max(r["peak_memory_bytes"] for r in runs) / 2**20,
        "file_size_mib": runs[0]["file_size_bytes"] / 2**20,
        "dims": runs[0]["voxelmap"]["dims"],
        "points": runs[0]["pointshell"]["points"],
        "points_per_level": runs[0]["pointshell"]["points_per_level"],
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"voxfmt build {result['mesh']} {' '.join(args.build_options)}  ({args.runs} runs, {result['cores']} cores)")
    print(f"{'stage':<24}{'median s':>10}")
    for s, t in result["stage_s_median"].items():
        print(f"{s:<24}{t:>10.3f}")
    print(f"{'total':<24}{result['total_s_median']:>10.3f}   (min {result['total_s_min']:.3f})")
    print(f"peak memory {result['peak_memory_mib']:.0f} MiB, file {result['file_size_mib']:.1f} MiB, "
          f"grid {'x'.join(map(str, result['dims']))}, {result['points']} points, levels {result['points_per_level']}")


if __name__ == "__main__":
    main()
