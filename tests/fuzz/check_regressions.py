#!/usr/bin/env python3
"""Every input a fuzzer once crashed or hung on (tests/fuzz/regressions/) goes through `voxfmt validate --level full`
and `voxfmt inspect`: each must end with an exit code (0 valid, 1 invalid, 2 unreadable), never a signal or a hang."""
import os
import subprocess
import sys

voxfmt, folder = sys.argv[1], sys.argv[2]
inputs = sorted(os.path.join(folder, f) for f in os.listdir(folder))
failures = []
for path in inputs:
    for args in (["validate", "--level", "full", path], ["inspect", path]):
        try:
            run = subprocess.run([voxfmt, *args], capture_output=True, text=True, timeout=120)
        except subprocess.TimeoutExpired:
            failures.append(f"{args[0]} {os.path.basename(path)}: hung")
            continue
        if run.returncode not in (0, 1, 2):
            failures.append(f"{args[0]} {os.path.basename(path)}: exit {run.returncode}\n{run.stderr[-2000:]}")
if not inputs:
    failures.append("no regression inputs found")
if failures:
    sys.exit("\n".join(failures))
print(f"fuzz regressions: {len(inputs)} inputs, no crash")
