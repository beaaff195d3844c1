#!/usr/bin/env python3
"""Runs examples/mixed_scene for 1.5 simulated seconds (VOXFMT_EXAMPLE_SECONDS: sanitizer builds, 50-100x slower,
run 0.2 s, enough for every body to reach its partner) and checks its JSON: one entry per partner kind, each
with contacts, no penetration beyond a voxel, and a picture written."""
import json
import os
import subprocess
import sys
import tempfile

binary = sys.argv[1]
with tempfile.TemporaryDirectory() as tmp:
    out, png = os.path.join(tmp, "scene.json"), os.path.join(tmp, "scene.png")
    seconds = os.environ.get("VOXFMT_EXAMPLE_SECONDS", "1.5")
    run = subprocess.run([binary, "--seconds", seconds, "--json", out, "--png", png, "--cache", tmp],
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"mixed_scene failed ({run.returncode}):\n{run.stderr}")
    report = json.load(open(out))
    if not os.path.getsize(png) > 1000:
        sys.exit("mixed_scene wrote no picture")
kinds = ["vps", "plane", "box", "sphere", "capsule", "cylinder", "cone", "convex-hull", "compound", "static-mesh",
         "heightfield"]
pairs = {p["partner"]: p for p in report["pairs"]}
failures = []
if sorted(pairs) != sorted(kinds):
    failures.append(f"partner kinds {sorted(pairs)}")
for kind, p in pairs.items():
    for key in ("contacts_mean", "max_penetration_voxels", "residual_speed_mps", "narrow_us_p50"):
        if key not in p:
            failures.append(f"{kind}: no {key}")
    if p.get("contacts_mean", 0) <= 0:
        failures.append(f"{kind}: no contacts")
    if p.get("max_penetration_voxels", 9) > 1.0:
        failures.append(f"{kind}: penetration {p['max_penetration_voxels']} voxels")
if failures:
    sys.exit("mixed_scene: " + "; ".join(failures))
print(f"mixed_scene: {len(pairs)} partner kinds in contact, none deeper than a voxel")
