#!/usr/bin/env python3
"""Plot bunny_drop.csv like the DLR seed's Figure 2: per scene, narrow-phase time and linear speed per step,
both on log scales, one line per collision method.

usage: plot_bunny_drop.py BUNNY_DROP_CSV OUT_PNG
"""
import csv
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    series = defaultdict(lambda: {"step": [], "us": [], "speed": []})
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            s = series[(row["scene"], row["method"])]
            s["step"].append(int(row["step"]) * 1e-3)
            s["us"].append(max(float(row["narrow_phase_us"]), 1e-2))
            s["speed"].append(max(float(row["linear_speed"]), 1e-6))
    scenes = sorted({scene for scene, _ in series}, key=lambda s: s != "table")
    fig, axes = plt.subplots(len(scenes), 2, figsize=(12, 4.2 * len(scenes)), squeeze=False)
    for r, scene in enumerate(scenes):
        for (sc, method), s in sorted(series.items()):
            if sc != scene:
                continue
            axes[r][0].plot(s["step"], s["us"], label=method, linewidth=0.8)
            axes[r][1].plot(s["step"], s["speed"], label=method, linewidth=0.8)
        axes[r][0].set_title(f"bunny on {scene}: narrow phase per step")
        axes[r][0].set_ylabel("time [µs]")
        axes[r][1].set_title(f"bunny on {scene}: linear speed")
        axes[r][1].set_ylabel("speed [m/s]")
        for ax in axes[r]:
            ax.set_yscale("log")
            ax.set_xlabel("simulated time [s]")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=110)
    print(f"wrote {sys.argv[2]}")


if __name__ == "__main__":
    main()
