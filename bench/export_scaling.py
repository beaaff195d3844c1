#!/usr/bin/env python3
"""How the engine exports cost as the resolution grows: CGAL's bunny baked at each resolution, then `voxfmt export
--nvdb` (the CLI: read and validate the asset, build both grids, ZIP, write), and the texture SDF of voxfmt.newton
built from the loaded asset (the layout only, no Warp upload) — time (best of --repeat), bytes against the asset's.

    PYTHONPATH=build/python .venv/bin/python bench/export_scaling.py --json F.json --markdown F.md \\
        [--resolutions 306,1024] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
import voxfmt  # noqa: E402
from voxfmt import _voxfmt  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json")
    ap.add_argument("--markdown")
    ap.add_argument("--resolutions", default="306,1024")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cache", default=str(ROOT / "out/export-scaling"))
    ap.add_argument("--voxfmt", default=str(ROOT / "build/bin/voxfmt"))
    args = ap.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for resolution in (int(r) for r in args.resolutions.split(",")):
        asset = cache / f"bunny-{resolution}.vox.h5"
        if not asset.exists():
            voxfmt.bake(ROOT / "build/cgal-data/data/meshes/bunny00.off", asset, resolution=resolution, points=35000)
        out = cache / f"bunny-{resolution}.nvdb"
        runs = []
        for _ in range(args.repeat):
            r = subprocess.run([args.voxfmt, "export", str(asset), "--nvdb", str(out), "--json"], capture_output=True,
                               text=True, check=True)
            runs.append(json.loads(r.stdout))
        best = min(runs, key=lambda x: x["timings_s"]["read"] + x["timings_s"]["export"])
        body = voxfmt.load(asset)
        layouts = []
        for _ in range(args.repeat):
            start = time.perf_counter()
            layout = _voxfmt._texture_sdf(body, "uint16", -1.0)
            layouts.append(time.perf_counter() - start)
        texture_bytes = sum(layout[k].nbytes for k in ("coarse", "slots", "texels"))
        rows.append({
            "resolution": resolution,
            "dims": list(body.dims),
            "asset_bytes": asset.stat().st_size,
            "runtime_bytes": body.memory_bytes,
            "nvdb_bytes": best["bytes"],
            "nvdb_uncompressed_bytes": best["uncompressed_bytes"],
            "nvdb_over_asset": best["bytes"] / asset.stat().st_size,
            "export_read_s": best["timings_s"]["read"],
            "export_grids_s": best["timings_s"]["export"],
            "export_total_s": best["timings_s"]["read"] + best["timings_s"]["export"],
            "texture_layout_s": min(layouts),
            "texture_bytes": texture_bytes,
            "texture_value_bricks": layout["value_bricks"],
            "texture_coarse_stored": layout["coarse_stored"],
        })
        print(json.dumps(rows[-1]), flush=True)
    cpu = "unknown CPU"
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    report = {"voxfmt": voxfmt.__version__, "machine": f"{cpu} ({os.cpu_count()} cores)",
              "platform": platform.platform(), "rows": rows}
    lines = [f"CGAL's bunny, voxfmt {report['voxfmt']} on {report['machine']}; best of {args.repeat}.", "",
             "| resolution | asset (MB) | .nvdb (MB) | .nvdb / asset | export: read + grids (s) | texture SDF layout (s) "
             "| texture (MB) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['resolution']} | {r['asset_bytes'] / 1e6:.1f} | {r['nvdb_bytes'] / 1e6:.1f} | "
                     f"{r['nvdb_over_asset']:.2f} | {r['export_read_s']:.2f} + {r['export_grids_s']:.2f} | "
                     f"{r['texture_layout_s']:.2f} | {r['texture_bytes'] / 1e6:.1f} |")
    table = "\n".join(lines) + "\n"
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(table)
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
