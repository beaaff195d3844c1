"""Ctrl-C (SIGINT) stops a long call that released the GIL, and what it used stays usable. Each call runs in a child
process, so that a KeyboardInterrupt arriving late (after the call, as it did) never reaches pytest itself."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

# The child: a call sized to take about LONG_S seconds (from a short one timed first; its inputs made before),
# SIGINT 0.2 s after it starts, then the same objects queried again. Prints how long the interrupt took to arrive.
_CHILD = r"""
import json, os, signal, sys, threading, time
import numpy as np
import voxfmt

# As at a terminal: a child of a background job (a CI runner) may inherit SIGINT ignored, and Python then installs
# no handler of its own.
signal.signal(signal.SIGINT, signal.default_int_handler)

LONG_S = 20.0
kind, path = sys.argv[1], sys.argv[2]
body = voxfmt.load(path)
tracker = voxfmt.Tracker(body, body)
scene = voxfmt.BatchScene([body], [(0, 0)])


def prepare(n):
    # The call on n poses, its inputs made beforehand.
    poses = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    poses[:, 0, 3] = 0.06  # overlapping spheres: every pose has contacts
    eye = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    if kind == "contacts_batch":
        return lambda: voxfmt.contacts_batch(body, np.eye(4), body, poses, threads=2).count
    if kind == "tracker":
        return lambda: tracker.contacts_batch(eye, poses).count
    eye32, poses32 = eye.astype(np.float32), poses.astype(np.float32)
    return lambda: scene.contacts(eye32, poses32, threads=2).count


small = prepare(2000)
start = time.perf_counter()
expected = small()
n = int(2000 * LONG_S / max(time.perf_counter() - start, 1e-3))
long_call = prepare(n)
threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
start = time.perf_counter()
try:
    long_call()
    outcome = "completed"
except KeyboardInterrupt:
    outcome = "interrupted"
elapsed = time.perf_counter() - start
again = small()
print(json.dumps({"outcome": outcome, "elapsed": elapsed, "usable": bool(np.array_equal(again, expected))}))
"""


@pytest.mark.parametrize("kind", ["contacts_batch", "tracker", "batch_scene"])
def test_sigint_stops_a_long_call(sphere_asset: Path, kind: str) -> None:
    run = subprocess.run([sys.executable, "-c", _CHILD, kind, str(sphere_asset)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["outcome"] == "interrupted"
    # The call takes ~20 s uninterrupted; a look every 20 ms stops it within a chunk of poses (generous for a
    # loaded machine).
    assert result["elapsed"] < 5.0, result
    assert result["usable"], result


# A bake without a progress callable, SIGINT during its voxelmap: it stops at its next stage, writes nothing.
_BAKE_CHILD = r"""
import json, os, signal, sys, threading, time
import voxfmt

# As at a terminal: a child of a background job (a CI runner) may inherit SIGINT ignored, and Python then installs
# no handler of its own.
signal.signal(signal.SIGINT, signal.default_int_handler)

mesh, out = sys.argv[1], sys.argv[2]
threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
start = time.perf_counter()
try:
    voxfmt.bake(mesh, out, resolution=400, points=50000, threads=2)
    outcome = "completed"
except KeyboardInterrupt:
    outcome = "interrupted"
print(json.dumps({"outcome": outcome, "elapsed": time.perf_counter() - start, "written": os.path.exists(out)}))
"""


def interrupted_bake(child: str, mesh: Path, out: Path, *args: str) -> dict[str, object]:
    """Runs a bake child to its end: what it printed, once it checked the bake was interrupted and wrote nothing."""
    run = subprocess.run([sys.executable, "-c", child, str(mesh), str(out), *args], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["outcome"] == "interrupted" and not result["written"], result
    return result


def test_sigint_stops_a_bake_without_progress(sphere_mesh: Path, tmp_path: Path) -> None:
    out = tmp_path / "big.vox.h5"
    interrupted_bake(_BAKE_CHILD, sphere_mesh, out)
    # The same bake still runs afterwards, in this process.
    import voxfmt
    voxfmt.bake(sphere_mesh, out, resolution=32, points=500, threads=1)
    assert voxfmt.load(out).voxel_size > 0


# With a progress callable, SIGINT some seconds into the voxelmap's stage (argv: mesh, out, seconds, resolution,
# points), the callable told the stage's progress about 5 times a second on the bake's own thread.
_VOXELMAP_STAGE_CHILD = r"""
import json, os, signal, sys, threading, time
import voxfmt

signal.signal(signal.SIGINT, signal.default_int_handler)

mesh, out = sys.argv[1], sys.argv[2]
delay, resolution, points = float(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
sent = []
shares = []


def progress(stage, fraction):
    shares.append(fraction)
    if stage == "voxelmap + point shell" and not sent:
        sent.append(time.perf_counter() + delay)
        threading.Timer(delay, lambda: os.kill(os.getpid(), signal.SIGINT)).start()


try:
    voxfmt.bake(mesh, out, resolution=resolution, points=points, threads=2, progress=progress)
    outcome = "completed"
except KeyboardInterrupt:
    outcome = "interrupted"
print(json.dumps({"outcome": outcome, "latency": time.perf_counter() - sent[0], "last_share": shares[-1],
                  "written": os.path.exists(out)}))
"""


# SIGINT 0.3 s in, while the band runs: the interrupt lands there (it waited for the stage's end: 4 s of this 1000^3
# bake on 2 cores).
def test_sigint_stops_a_bake_within_its_voxelmap(sphere_mesh: Path, tmp_path: Path) -> None:
    result = interrupted_bake(_VOXELMAP_STAGE_CHILD, sphere_mesh, tmp_path / "band.vox.h5", "0.3", "1000", "50000")
    assert result["last_share"] < 0.72, result  # before "assemble": within the voxelmap's stage
    assert result["latency"] < 1.5, result


# SIGINT at the write's second report, within its work (the grids compressed, the value bricks checked): the bake stops
# there and the file is not written (the write was one report, and ran to its end: 1.1 s of this 800^3 bake on 2
# cores).
_WRITE_CHILD = r"""
import json, os, signal, sys, time
import voxfmt

signal.signal(signal.SIGINT, signal.default_int_handler)

mesh, out = sys.argv[1], sys.argv[2]
sent = []
shares = []
writes = []


def progress(stage, fraction):
    shares.append(fraction)
    writes.append(stage == "write")
    if sum(writes) == 2 and not sent:
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)


try:
    voxfmt.bake(mesh, out, resolution=800, points=50000, threads=2, progress=progress)
    outcome = "completed"
except KeyboardInterrupt:
    outcome = "interrupted"
print(json.dumps({"outcome": outcome, "latency": time.perf_counter() - sent[0] if sent else None,
                  "last_share": shares[-1], "written": os.path.exists(out),
                  "left": sorted(os.listdir(os.path.dirname(out)))}))
"""


def test_sigint_stops_a_bake_within_its_write(sphere_mesh: Path, tmp_path: Path) -> None:
    result = interrupted_bake(_WRITE_CHILD, sphere_mesh, tmp_path / "write.vox.h5")
    assert 0.74 < result["last_share"] < 1, result  # within the write's work
    assert result["latency"] < 0.5, result
    assert result["left"] == [], result  # no temporary either


# SIGINT 1.5 s in, while a point shell of a million points is sampled after the voxelmap is done: the bake is told on
# and stops the sampling (it waited for it: 23 s of this bake on 2 cores).
def test_sigint_stops_a_bake_within_its_point_shell(sphere_mesh: Path, tmp_path: Path) -> None:
    result = interrupted_bake(_VOXELMAP_STAGE_CHILD, sphere_mesh, tmp_path / "shell.vox.h5", "1.5", "32", "1000000")
    assert result["latency"] < 1.0, result
