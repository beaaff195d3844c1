#!/usr/bin/env python3
"""Runs `vps-sim --quick` and checks its JSON: the documented shape (bench/README.md) and the outcomes that do not
depend on the machine's speed (the simulations are deterministic; vps-budget's cuts depend on the clock, so only
its shape is checked). No timing is asserted: times are for people and for the committed results file.

usage: check_vps_sim.py VPS_SIM_BINARY CACHE_DIR"""
import json
import os
import subprocess
import sys
import tempfile

binary, cache = sys.argv[1], sys.argv[2]
with tempfile.TemporaryDirectory() as tmp:
    out = os.path.join(tmp, "quick.json")
    run = subprocess.run([binary, "--quick", "--no-plots", "--json", out, "--cache", cache, "-o", tmp],
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"vps-sim failed ({run.returncode}):\n{run.stderr}")
    report = json.load(open(out))
    print(run.stdout)

failures = []


def check(condition, message):
    if not condition:
        failures.append(message)


KEYS = ("scenario", "method", "rest_time_s", "residual_speed_mps", "energy_gain_rel", "max_penetration_mm",
        "escaped", "step_ms_p50", "step_ms_p99", "narrow_phase_ms_p50", "outcome")
runs = {(r["scenario"], r["method"]): r for r in report["runs"]}
for scenario in ("drop", "pile", "chain", "peg-in-hole-0.5mm"):
    for method in ("vps-fine", "vps-coarse", "vps-budget", "hull"):
        r = runs.get((scenario, method))
        check(r is not None, f"no run {scenario} / {method}")
        if r is None or r["skipped"]:
            continue
        for key in KEYS:
            check(key in r, f"{scenario} / {method}: no key {key}")
        # A slow (instrumented) build may stop at the wall-clock budget: the figures then cover what it simulated.
        check(r["simulated_s"] == 1.5 or r["stopped_early"], f"{scenario} / {method}: simulated {r['simulated_s']} s")
        check(r["energy_gain_rel"] >= 0 and r["max_penetration_mm"] >= 0, f"{scenario} / {method}: figures")
    check(runs.get((scenario, "hacd"), {}).get("skipped", True) or "outcome" in runs[(scenario, "hacd")],
          f"{scenario} / hacd: neither run nor skipped")

fine = {s: runs[(s, "vps-fine")] for s in ("drop", "pile", "chain", "peg-in-hole-0.5mm")}


def whole(r):
    """The outcome of a run that simulated its whole time (a slow build may stop a run early)."""
    return not r["stopped_early"]


if whole(fine["drop"]):
    check(fine["drop"]["residual_speed_mps"] < 1e-3, f"drop: vps-fine still moves at {fine['drop']['residual_speed_mps']} m/s")
check(fine["drop"]["max_penetration_voxels"] < 0.5, f"drop: vps-fine {fine['drop']['max_penetration_voxels']} voxel")
check(fine["pile"]["escaped"] == 0, f"pile: {fine['pile']['escaped']} bodies escaped the bin with vps-fine")
if whole(fine["chain"]):
    check(fine["chain"]["outcome"]["linked"] is True, "chain: came apart with vps-fine")
check(runs[("chain", "hull")]["outcome"]["linked"] is False, "chain: hulls cannot stay linked, yet did")
if whole(fine["peg-in-hole-0.5mm"]):
    check(fine["peg-in-hole-0.5mm"]["outcome"]["inserted"] is True,
          f"peg 0.5 mm: vps-fine not inserted ({fine['peg-in-hole-0.5mm']['outcome']})")
check(runs[("peg-in-hole-0.5mm", "hull")]["outcome"]["inserted"] is False, "peg 0.5 mm: a hull went into the hole")
# A coarse shell refines its cut where it touches (refine_cut_contacts): it comes to rest on the table (on its
# coarse points alone it rocked, 1.4e-2 m/s) and the peg goes into the hole (it fell through the block).
coarse = {s: runs[(s, "vps-coarse")] for s in ("drop", "peg-in-hole-0.5mm")}
if whole(coarse["drop"]):
    check(coarse["drop"]["residual_speed_mps"] < 1e-3,
          f"drop: vps-coarse still moves at {coarse['drop']['residual_speed_mps']} m/s")
if whole(coarse["peg-in-hole-0.5mm"]):
    check(coarse["peg-in-hole-0.5mm"]["outcome"]["inserted"] is True,
          f"peg 0.5 mm: vps-coarse not inserted ({coarse['peg-in-hole-0.5mm']['outcome']})")
for scenario in ("drop", "chain"):
    for method in ("vps-fine", "vps-coarse"):
        gain = runs[(scenario, method)]["energy_gain_rel"]
        check(gain < 0.05, f"{scenario} / {method}: energy gain {gain} of the released energy")

if failures:
    sys.exit("vps-sim --quick:\n  " + "\n  ".join(failures))
print("vps-sim --quick: shape and outcomes as expected")
