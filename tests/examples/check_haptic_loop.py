#!/usr/bin/env python3
"""Runs examples/haptic_loop for 1 s per run and checks its JSON: the four (pairs, rate) runs with every cycle
run, the tool touching and pushed back (a force; less penetration than the device's 2 mm press when the full
tree ran every cycle), and the CSV and PNG written. Timing figures are not asserted (CI machines are shared); the benchmark reports them."""
import json
import os
import subprocess
import sys
import tempfile

binary = sys.argv[1]
with tempfile.TemporaryDirectory() as tmp:
    report_path = os.path.join(tmp, "haptic.json")
    run = subprocess.run([binary, "--seconds", "1", "--json", report_path, "--cache", tmp, "--out", tmp],
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"haptic_loop failed ({run.returncode}):\n{run.stderr}")
    report = json.load(open(report_path))
    failures = []
    runs = {(r["pairs"], int(r["rate_hz"])): r for r in report["runs"]}
    if sorted(runs) != [(1, 1000), (1, 5000), (10, 1000), (10, 5000)]:
        failures.append(f"runs {sorted(runs)}")
    for key, r in runs.items():
        for field in ("points_per_tool", "cycles", "cycle_us", "overruns", "levels_completed_min",
                      "max_force_jump_n", "max_penetration_m", "realtime_priority", "memory_locked", "cpu"):
            if field not in r:
                failures.append(f"{key}: no {field}")
        if set(r.get("cycle_us", {})) != {"p50", "p99", "p999", "max"}:
            failures.append(f"{key}: cycle_us keys {sorted(r.get('cycle_us', {}))}")
        if r.get("cycles") != key[1]:
            failures.append(f"{key}: {r.get('cycles')} cycles in 1 s")
        if r.get("points_per_tool", 0) < 30000:
            failures.append(f"{key}: {r.get('points_per_tool')} points per tool")
        # With the full tree every cycle the tool sinks less than the device's 2 mm press. On a loaded machine the
        # time budget cuts the tree (a timing matter, reported, not asserted) and the weighted cut estimate may
        # let it sink further.
        full_tree = r.get("levels_completed_min") == r.get("tree_levels", 0) - 1
        limit = 0.002 if full_tree else 0.01
        if not 0 < r.get("max_penetration_m", 0) < limit:
            failures.append(f"{key}: max penetration {r.get('max_penetration_m')} m (the device presses 2 mm; "
                            f"levels completed {r.get('levels_completed_min')})")
        if not r.get("max_force_n", 0) > 0.1:
            failures.append(f"{key}: max force {r.get('max_force_n')} N")
        csv = r.get("csv", "")
        if not (os.path.exists(csv) and os.path.getsize(csv) > 1000 and os.path.getsize(csv[:-4] + ".png") > 1000):
            failures.append(f"{key}: CSV or PNG missing")
if failures:
    sys.exit("haptic_loop: " + "; ".join(failures))
print("haptic_loop: 4 runs checked")
