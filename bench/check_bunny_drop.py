#!/usr/bin/env python3
"""bunny_drop's HACD cache (ctest bench.bunny_drop_hacd_cache): a decomposition is written with its key (the mesh's
hash and HACD's parameters) and reused only under that key; a file with another key is recomputed; a shipped
decomposition is used (and copied into the cache) when its key matches; and the repository's shipped bunny
decomposition matches CGAL's bunny, so the main job never spends HACD's minutes on it.

Usage: check_bunny_drop.py BUNNY_DROP VOXFMT MESHES_DIR"""
import json
import os
import shutil
import subprocess
import sys
import tempfile

bunny_drop, voxfmt, meshes = sys.argv[1:4]
failures = []


def drop(asset, mesh, out, shipped, timeout=300):
    run = subprocess.run([bunny_drop, "--asset", asset, "--mesh", mesh, "-o", out, "--methods", "hacd",
                          "--seconds", "0.02", "--hacd-shipped", shipped], capture_output=True, text=True,
                         timeout=timeout)
    if run.returncode != 0:
        sys.exit(f"bunny_drop failed ({run.returncode}):\n{run.stderr}")
    decomposed = "HACD: decomposing" in run.stderr
    with open(os.path.join(out, "bunny_drop.json")) as f:
        precompute = json.load(f)["runs"][0]["precompute_s"]
    return decomposed, precompute


def bake(mesh, asset):
    subprocess.run([voxfmt, "build", mesh, "-o", asset, "--resolution", "24", "--points", "500"], check=True,
                   capture_output=True)


with tempfile.TemporaryDirectory() as tmp:
    mesh = os.path.join(meshes, "sphere.off")  # 968 triangles: HACD takes a moment
    asset = os.path.join(tmp, "sphere.vox.h5")
    bake(mesh, asset)
    out = os.path.join(tmp, "out")
    cache = os.path.join(out, "bunny00.hacd.txt")
    none = os.path.join(tmp, "no-such-file.txt")

    decomposed, _ = drop(asset, mesh, out, none)
    key = open(cache).readline().rstrip("\n")
    if not decomposed or not key.startswith("voxfmt-hacd-cache 1 mesh=") or "concavity=100" not in key:
        failures.append(f"first run: decomposed {decomposed}, cache key {key!r}")
    decomposed, precompute = drop(asset, mesh, out, none)
    if decomposed or precompute != 0:
        failures.append(f"second run did not use the cache (decomposed {decomposed}, precompute {precompute} s)")

    with open(cache) as f:
        text = f.read()
    with open(cache, "w") as f:  # another HACD parameter: the file is not this run's
        f.write(text.replace("concavity=100", "concavity=99", 1))
    decomposed, _ = drop(asset, mesh, out, none)
    if not decomposed or open(cache).readline().rstrip("\n") != key:
        failures.append(f"a cache with another key was used (decomposed {decomposed})")

    shipped = os.path.join(tmp, "shipped.txt")
    shutil.copy(cache, shipped)
    fresh = os.path.join(tmp, "fresh")
    decomposed, precompute = drop(asset, mesh, fresh, shipped)
    if decomposed or precompute != 0 or open(os.path.join(fresh, "bunny00.hacd.txt")).read() != open(shipped).read():
        failures.append(f"the shipped decomposition was not used and copied (decomposed {decomposed})")

    # The repository's decomposition of CGAL's bunny (bunny_drop's default --hacd-shipped). If its key did not
    # match, HACD would run for minutes: stop it after 2 minutes and say so.
    bunny = os.path.join(meshes, "bunny00.off")
    bunny_asset = os.path.join(tmp, "bunny.vox.h5")
    bake(bunny, bunny_asset)
    run = subprocess.run([bunny_drop, "--asset", bunny_asset, "--mesh", bunny, "-o", os.path.join(tmp, "bunny"),
                          "--methods", "hacd", "--seconds", "0.02"], capture_output=True, text=True, timeout=120)
    if run.returncode != 0 or "HACD: decomposing" in run.stderr:
        failures.append("bench/data/bunny00.hacd.txt does not match CGAL's bunny and HACD's parameters: "
                        + run.stderr[-500:])

if failures:
    sys.exit("bunny_drop HACD cache: " + "; ".join(failures))
print("bunny_drop HACD cache: written with its key, reused, recomputed under another key, shipped copy used")
