"""The CPU batch: voxfmt.BatchScene (runtime::BatchScene) against contacts_batch on the same poses, in one run.

    PYTHONPATH=build/python .venv/bin/python bench/cpu_batch.py \\
        --json bench/results/cpu-batch-polyglot-2core.json --markdown bench/results/cpu-batch-polyglot-2core.md

CGAL's bunny at the seed's settings (0.15 m, resolution 306, 35,000 points), B approaching A until they touch, then
0.5 mm short to 1.5 mm in (python_peers.bunny_poses, the poses of bench/gpu_batch.py). Both calls get the same
float32 poses (contacts_batch as float64 copies of them), the same stiffness, 1 and 2 threads; the two are
alternated for `--rounds` rounds and the median time of each is reported, with their agreement (counts equal,
largest force difference relative to the largest force).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=40_000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--bunny", default="build/cgal-data/data/meshes/bunny00.off")
    parser.add_argument("--work", default="out/cpu-batch", help="where the baked bunny is kept")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()

    import python_peers as peers

    import voxfmt

    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    bunny = peers.baked("bunny00-0.15m", Path(args.bunny), 0.15, work)
    pa, pb = peers.bunny_poses(bunny.body, args.poses, np.random.default_rng(7))
    pa32, pb32 = pa.astype(np.float32), pb.astype(np.float32)
    pa64, pb64 = pa32.astype(np.float64), pb32.astype(np.float64)
    stiffness = 2e4
    scene = voxfmt.BatchScene([bunny.body])
    load = list(os.getloadavg())
    rows = []
    for threads in args.threads:
        times: dict[str, list[float]] = {"BatchScene": [], "contacts_batch": []}
        for _ in range(args.rounds):
            start = time.perf_counter()
            got = scene.contacts(pa32, pb32, stiffness=stiffness, threads=threads)
            times["BatchScene"].append(time.perf_counter() - start)
            start = time.perf_counter()
            ref = voxfmt.contacts_batch(bunny.body, pa64, bunny.body, pb64, stiffness=stiffness, threads=threads)
            times["contacts_batch"].append(time.perf_counter() - start)
        force = np.asarray(ref.force)
        agree = {"counts_equal": bool(np.array_equal(got.count, np.asarray(ref.count))),
                 "force_difference_relative": float(np.abs(got.force - force).max() / np.abs(force).max())}
        for method, seconds in times.items():
            median = statistics.median(seconds)
            rows.append({"method": method, "threads": threads, "poses": args.poses, "median_s": median,
                         "poses_per_s": args.poses / median, "rounds": args.rounds, **agree})
    touching = int((got.count > 0).sum())
    result = {"bench": "cpu_batch", "machine": f"{platform.machine()}, {os.cpu_count()} cores",
              "python": platform.python_version(), "load_average_at_start": load, "touching": touching,
              "asset": "bunny00 0.15 m, resolution 306, 35,000 points", "rows": rows}
    lines = [f"# The CPU batch: BatchScene against contacts_batch ({result['machine']})", "",
             "Command: `PYTHONPATH=build/python .venv/bin/python bench/cpu_batch.py --json "
             "bench/results/cpu-batch-polyglot-2core.json --markdown bench/results/cpu-batch-polyglot-2core.md`", "",
             f"{args.poses:,} bunny-on-bunny poses, {touching:,} touching; median of {args.rounds} alternated rounds; "
             f"load average at the start {load[0]:.2f}.", "",
             "| method | threads | s | poses/s | vs contacts_batch | counts equal | force difference |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        ref_row = next(r for r in rows if r["method"] == "contacts_batch" and r["threads"] == row["threads"])
        lines.append(f"| {row['method']} | {row['threads']} | {row['median_s']:.3f} | {row['poses_per_s']:,.0f} | "
                     f"{ref_row['median_s'] / row['median_s']:.2f}x | {row['counts_equal']} | "
                     f"{row['force_difference_relative']:.1e} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
