#!/usr/bin/env python3
"""Plot vps-sim's per-step series: one PNG per scenario with the fastest body point's speed (log scale) and the
scene's energy (kinetic + potential, the constant forces' potential included) against time, a line per method.

usage: plot_vps_sim.py VPS_SIM_SERIES_CSV OUT_DIR   (writes OUT_DIR/vps-sim-SCENARIO.png)
"""
import csv
import os
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    series = defaultdict(lambda: {"t": [], "speed": [], "energy": []})
    with open(sys.argv[1], newline="") as f:
        for row in csv.DictReader(f):
            s = series[(row["scenario"], row["method"])]
            s["t"].append(float(row["t"]))
            s["speed"].append(max(float(row["speed"]), 1e-7))
            s["energy"].append(float(row["energy"]))
    written = []
    for scenario in sorted({sc for sc, _ in series}):
        fig, (speed, energy) = plt.subplots(1, 2, figsize=(13, 4.2))
        for (sc, method), s in sorted(series.items()):
            if sc != scenario or not s["t"]:
                continue
            speed.plot(s["t"], s["speed"], label=method, lw=1)
            start = s["energy"][0]
            energy.plot(s["t"], [e - start for e in s["energy"]], label=method, lw=1)
        speed.set_yscale("log")
        speed.axhline(1e-4, color="grey", ls=":", lw=0.8)
        speed.set(xlabel="time (s)", ylabel="fastest point of any body (m/s)", title=f"{scenario}: speed")
        energy.set(xlabel="time (s)", ylabel="energy - initial energy (J)", title=f"{scenario}: energy")
        speed.legend(fontsize=8)
        energy.legend(fontsize=8)
        fig.tight_layout()
        path = os.path.join(sys.argv[2], f"vps-sim-{scenario}.png")
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    print("plots: " + ", ".join(written))


if __name__ == "__main__":
    main()
