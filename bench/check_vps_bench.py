#!/usr/bin/env python3
"""Runs `vps-bench --quick` and checks its JSON: the documented shape (bench/README.md), every scenario and
method present, and the figures that do not depend on the machine (contacts found, depths against the depths
known by construction). No timing is asserted: times are for people and for the committed results file."""
import json
import os
import subprocess
import sys
import tempfile

binary, cache = sys.argv[1], sys.argv[2]
with tempfile.TemporaryDirectory() as tmp:
    out = os.path.join(tmp, "quick.json")
    run = subprocess.run([binary, "--quick", "--trajectories", "--json", out, "--cache", cache], capture_output=True,
                         text=True)
    if run.returncode != 0:
        sys.exit(f"vps-bench failed ({run.returncode}):\n{run.stderr}")
    report = json.load(open(out))

failures = []
def check(condition, message):
    if not condition:
        failures.append(message)

for key in ("machine", "scenarios", "trajectories", "asset"):
    check(key in report, f"missing top-level key {key}")
check(0 < report["asset"]["runtime_mb"] <= 16, f"runtime memory {report['asset']['runtime_mb']} MB (target <= 16)")
names = [s["name"] for s in report["scenarios"]]
check(names == ["bunny-plane", "bunny-box", "bunny-static-mesh", "bunny-bunny", "tori-stacked", "tori-linked",
                "tori-gap"], f"scenarios {names}")
fields = ("p50_us", "p90_us", "p99_us", "p999_us", "max_us", "cold_p50_us", "contacts_mean", "touching_share",
          "depth_err_max_m", "nodes_visited_mean", "points_tested_mean")
voxel = 0.14 / 306  # the tori's voxel, at resolution 306 over 0.14 m
for scenario in report["scenarios"]:
    methods = {m["name"]: m for m in scenario["methods"]}
    check(set(methods) == {"vps-fine", "vps-fine-scalar", "vps-coarse", "vps-fine-prox", "vps-fine-baked-floor",
                           "gimpact", "hacd", "hull", "fcl"}, f"{scenario['name']}: methods {sorted(methods)}")
    for name, m in methods.items():
        if "unavailable" in m:
            check(name == "hacd" or (name == "vps-fine-baked-floor" and scenario["name"] != "bunny-static-mesh"),
                  f"{scenario['name']}/{name} unavailable: {m['unavailable']}")
            continue
        for field in fields:
            check(field in m, f"{scenario['name']}/{name}: no {field}")
        check(m["p50_us"] > 0 and m["p50_us"] <= m["p99_us"] <= m["max_us"], f"{scenario['name']}/{name}: percentiles")
    fine, coarse = methods["vps-fine"], methods["vps-coarse"]
    # The scalar lower-bound kernel and the SIMD one the runtime picks prune alike: the same work, the same contacts.
    scalar = methods["vps-fine-scalar"]
    for field in ("contacts_mean", "nodes_visited_mean", "points_tested_mean", "touching_share"):
        check(scalar[field] == fine[field], f"{scenario['name']}: vps-fine-scalar {field} {scalar[field]} != {fine[field]}")
    if scenario["name"] in ("tori-stacked", "tori-linked"):
        check(fine["touching_share"] == 1.0, f"{scenario['name']}: vps-fine misses contact on some poses")
        check(fine["depth_err_max_m"] <= 0.1 * voxel,
              f"{scenario['name']}: vps-fine depth error {fine['depth_err_max_m']} m > 0.1 voxel")
    if scenario["name"] == "tori-gap":
        check(fine["touching_share"] == 0.0, "tori-gap: vps-fine reports contact across a 1 mm gap")
    if fine["touching_share"] > 0:
        check(coarse["detects_where_fine_touches"] >= 0.95,
              f"{scenario['name']}: vps-coarse detects {coarse['detects_where_fine_touches']} of fine's contacts")
    if scenario["name"] == "bunny-static-mesh":
        # The floor baked (at 2 mm voxels in a quick run) against its triangles: nearly the same poses touch.
        baked = methods["vps-fine-baked-floor"]
        check(baked.get("detects_where_fine_touches", 0) >= 0.9,
              f"bunny-static-mesh: the baked floor detects {baked.get('detects_where_fine_touches')} of fine's contacts")

# Trajectories: every method on the same consecutive steps. The coherent query must find exactly the contacts
# of the query from scratch, step by step (here: the same mean), with fewer nodes visited.
runs = [(t["scenario"], t["kind"]) for t in report["trajectories"]]
check(runs == [("bunny-plane", "drop"), ("bunny-static-mesh", "drop"), ("bunny-bunny", "drop"),
               ("tori-stacked", "drop"), ("tori-linked", "drop"), ("bunny-bunny", "haptic")], f"trajectories {runs}")
for t in report["trajectories"]:
    where = f"trajectory {t['scenario']}/{t['kind']}"
    methods = {m["name"]: m for m in t["methods"]}
    check(set(methods) == {"vps-fine", "vps-fine-coherent", "vps-fine-baked-floor", "gimpact", "hacd", "hull", "fcl"},
          f"{where}: methods {sorted(methods)}")
    for name, m in methods.items():
        if "unavailable" in m:
            check(name == "hacd" or (name == "vps-fine-baked-floor" and t["scenario"] != "bunny-static-mesh"),
                  f"{where}/{name} unavailable: {m['unavailable']}")
            continue
        for field in ("step_p50_us", "step_p99_us", "step_max_us", "nodes_mean", "contacts_mean", "steps_measured"):
            check(field in m, f"{where}/{name}: no {field}")
        check(0 < m["step_p50_us"] <= m["step_p99_us"] <= m["step_max_us"], f"{where}/{name}: percentiles")
    fine, coherent = methods["vps-fine"], methods["vps-fine-coherent"]
    check(coherent.get("steps_compared_with_vps_fine", 0) >= min(20, t["steps"]), f"{where}: steps compared")
    check(coherent.get("steps_differing_from_vps_fine") == 0,
          f"{where}: {coherent.get('steps_differing_from_vps_fine')} steps where the coherent contacts differ")
    # Over the whole trajectory only: a slow (instrumented) build stops at the time budget, before contact.
    if not fine["budget_hit"] and not coherent["budget_hit"]:
        check(fine["contacts_mean"] > 0, f"{where}: no contact along the trajectory")
        check(coherent["nodes_mean"] < fine["nodes_mean"],
              f"{where}: coherent visits {coherent['nodes_mean']} nodes a step, from scratch {fine['nodes_mean']}")

if failures:
    sys.exit("vps-bench --quick:\n  " + "\n  ".join(failures))
print(f"vps-bench --quick: {len(names)} scenarios and {len(runs)} trajectories checked")
