#!/usr/bin/env python3
"""Runs examples/mixed_scene for 1.5 simulated seconds (VOXFMT_EXAMPLE_SECONDS: sanitizer builds, 50-100x slower,
run 0.2 s, enough for every body to reach its partner) and checks its JSON: one entry per partner kind, each
with contacts, no penetration beyond a voxel, and a picture written. Then twice for 0.2 s with friction anchors, the
second with every drop moved by --drop-offset: the bunny on the ground plane must end moved by that offset."""
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
    moved = []
    for offset in ("0,0", "0.015,-0.01"):
        run = subprocess.run([binary, "--seconds", "0.2", "--json", out, "--png", png, "--cache", tmp,
                              "--friction-anchors", f"--drop-offset={offset}"], capture_output=True, text=True)
        if run.returncode != 0:
            sys.exit(f"mixed_scene --drop-offset={offset} failed ({run.returncode}):\n{run.stderr}")
        moved.append(json.load(open(out)))
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
# On a plane a drop moved sideways lands moved as much, within about a millimetre (rounding picks other contacts,
# and it bounces differently).
still, shifted = ({p["partner"]: p for p in r["pairs"]} for r in moved)
echoed = [(r["friction_anchors"], r["drop_offset_m"]) for r in moved]
if echoed != [(True, [0, 0]), (True, [0.015, -0.01])]:
    failures.append(f"options echoed as {echoed}")
shift = [b - a for a, b in zip(still["plane"]["final_position_m"], shifted["plane"]["final_position_m"])]
if max(abs(shift[0] - 0.015), abs(shift[1]), abs(shift[2] + 0.01)) > 3e-3:
    failures.append(f"the plane's bunny moved by {shift} for a drop offset of (0.015, 0, -0.01) m")
if failures:
    sys.exit("mixed_scene: " + "; ".join(failures))
print(f"mixed_scene: {len(pairs)} partner kinds in contact, none deeper than a voxel; a moved drop lands moved")
