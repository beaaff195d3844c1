#!/usr/bin/env python3
"""Which resting bunnies of mixed_scene stay at rest when they land elsewhere: the scene run over a grid of drop
offsets (every station's bunny moved by the same x, z), once per variant of mixed_scene's options, each bunny's
residual speed (its mean speed over the last 0.1 s) counted against a threshold.

    python3 bench/rest_grid.py --json out/rest-grid.json --markdown out/rest-grid.md
    python3 bench/rest_grid.py --variant plain= --variant anchors=--friction-anchors --seconds 5

One scene's bunnies land where chaos puts them (docs/bullet.md, "mixed_scene"): a setting is judged over the grid,
not by one drop. Exit 1 if mixed_scene fails.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def offsets(spread_mm: float) -> list[tuple[float, float]]:
    """5 x 3 drop offsets in metres: x at -1, -1/2, 0, 1/2, 1 spread, z at -1, 0, 1 spread."""
    s = spread_mm / 1000
    return [(fx * s, fz * s) for fx in (-1, -0.5, 0, 0.5, 1) for fz in (-1, 0, 1)]


def run_scene(binary: str, cache: str, seconds: float, offset: tuple[float, float], extra: list[str],
              folder: Path) -> list[dict]:
    out = folder / "scene.json"
    command = [binary, "--cache", cache, "--seconds", str(seconds), "--json", str(out), "--png",
               str(folder / "scene.png"), f"--drop-offset={offset[0]:g},{offset[1]:g}", *extra]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"rest_grid: {' '.join(command)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return json.loads(out.read_text())["pairs"]


def summary(runs: list[dict], threshold: float) -> dict:
    speeds = sorted(p["residual_speed_mps"] for r in runs for p in r["pairs"])
    moving = [{"offset_m": r["offset_m"], "partner": p["partner"], "residual_speed_mps": p["residual_speed_mps"]}
              for r in runs for p in r["pairs"] if p["residual_speed_mps"] > threshold]
    return {"bunnies": len(speeds), "moving": len(moving), "median_mps": statistics.median(speeds),
            "p90_mps": statistics.quantiles(speeds, n=10, method="inclusive")[-1], "max_mps": speeds[-1],
            "moving_list": moving}


def markdown(result: dict) -> str:
    lines = [f"Drops over a grid of {len(result['offsets_m'])} offsets (±{result['spread_mm']:g} mm in x and z), "
             f"{result['seconds']:g} simulated seconds, a bunny moving if its residual speed is over "
             f"{result['threshold_mps']:g} m/s.", "",
             "| variant | options | bunnies | moving | median m/s | p90 m/s | max m/s | moving ones |",
             "|---|---|--:|--:|--:|--:|--:|---|"]
    for v in result["variants"]:
        s = v["summary"]
        moving = ", ".join(f"{m['partner']} {m['residual_speed_mps']:.1e}" for m in s["moving_list"]) or "—"
        lines.append(f"| {v['name']} | `{' '.join(v['options']) or '(none)'}` | {s['bunnies']} | {s['moving']} | "
                     f"{s['median_mps']:.1e} | {s['p90_mps']:.1e} | {s['max_mps']:.1e} | {moving} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--binary", default=str(ROOT / "build/bin/mixed_scene"))
    parser.add_argument("--cache", default=str(ROOT / "out/mixed_scene"), help="mixed_scene's asset folder")
    parser.add_argument("--variant", action="append", metavar="NAME=OPTIONS",
                        help="a name and mixed_scene options (space-separated; default: plain= and "
                             "anchors=--friction-anchors)")
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--spread-mm", type=float, default=6.0, help="largest offset in x and z")
    parser.add_argument("--threshold", type=float, default=1e-4, help="residual speed counted as moving (m/s)")
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    args = parser.parse_args()
    variants = []
    for text in args.variant or ["plain=", "anchors=--friction-anchors"]:
        name, _, options = text.partition("=")
        variants.append((name, options.split()))
    if not Path(args.binary).exists():
        sys.exit(f"rest_grid: {args.binary} not found (bash scripts/build.sh)")
    grid = offsets(args.spread_mm)
    result = {"seconds": args.seconds, "spread_mm": args.spread_mm, "threshold_mps": args.threshold,
              "offsets_m": grid, "variants": []}
    with tempfile.TemporaryDirectory() as folder:
        for name, options in variants:
            runs = []
            for k, offset in enumerate(grid):
                print(f"\r{name}: drop {k + 1} of {len(grid)}", end="", file=sys.stderr, flush=True)
                pairs = run_scene(args.binary, args.cache, args.seconds, offset, options, Path(folder))
                runs.append({"offset_m": offset, "pairs": pairs})
            print(file=sys.stderr)
            result["variants"].append({"name": name, "options": options, "runs": runs,
                                       "summary": summary(runs, args.threshold)})
    table = markdown(result)
    print(table, end="")
    for path, text in ((args.json, json.dumps(result, indent=1) + "\n"), (args.markdown, table)):
        if path:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            Path(path).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
