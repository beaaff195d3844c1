#!/usr/bin/env python3
"""Every input a fuzzer once crashed or hung on (tests/fuzz/regressions/) must end with an exit code, never a signal or
a hang: an asset (*.vox.h5) goes through `voxfmt validate --level full` and `voxfmt inspect` (0 valid, 1 invalid,
2 unreadable), a mesh through `voxfmt build` at the fuzzers' resolution (0 baked, 1 refused with a code other than
INVALID_ASSET, which means the bake broke the spec)."""
import os
import subprocess
import sys
import tempfile

voxfmt, folder = sys.argv[1], sys.argv[2]
inputs = sorted(os.path.join(folder, f) for f in os.listdir(folder))
failures = []
work = tempfile.mkdtemp(prefix="voxfmt-fuzz-regressions-")
for path in inputs:
    if path.endswith(".vox.h5"):
        commands = (["validate", "--level", "full", path], ["inspect", path])
    else:
        commands = (["build", path, "-o", os.path.join(work, os.path.basename(path) + ".vox.h5"), "--resolution", "24", "--points", "300"],)
    for args in commands:
        try:
            run = subprocess.run([voxfmt, *args], capture_output=True, text=True, timeout=120)
        except subprocess.TimeoutExpired:
            failures.append(f"{args[0]} {os.path.basename(path)}: hung")
            continue
        if run.returncode not in (0, 1, 2):
            failures.append(f"{args[0]} {os.path.basename(path)}: exit {run.returncode}\n{run.stderr[-2000:]}")
        elif args[0] == "build" and "INVALID_ASSET" in run.stderr:
            # The bake refused its own output: a bake bug, as the fuzz targets judge it.
            failures.append(f"build {os.path.basename(path)}: the bake made an invalid asset\n{run.stderr[-2000:]}")
if not inputs:
    failures.append("no regression inputs found")
if failures:
    sys.exit("\n".join(failures))
print(f"fuzz regressions: {len(inputs)} inputs, no crash")
