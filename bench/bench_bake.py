#!/usr/bin/env python3
"""Bake benchmark.

Default: runs `voxfmt build --json` several times on one mesh and reports median per-stage timings, peak memory and
file size, as JSON (--json) or a table. Default mesh and options: the seed's setting, CGAL's bunny at
--resolution 306 with --points 35000.

  python3 bench/bench_bake.py [--runs 5] [--mesh MESH] [--json] [-- build options]

--scaling: how the cost grows with the resolution. For each resolution (128 ... 4096; --quick: up to 512; or
--resolutions), one bake of the mesh with /usr/bin/time (wall time, peak RSS), the asset's size, `voxfmt validate
--level full` (time, verdict), the runtime's load time and memory and the voxelmap's accuracy against the exact
mesh (build/bin/asset-check), and in the same run the floor: OpenVDB's meshToLevelSet of the same mesh at the same
voxel size and band, alone in its own process (build/bin/bake-floor). A table, `--json FILE` ({"runs": [...]}) and
`--png FILE` (log-log: time and peak memory against the resolution, bake and floor).

  python3 bench/bench_bake.py --scaling [--quick] [--json F] [--png F] [--resolutions 128,256,...]

--broken: broken meshes against clean ones. bench/make_shelf.py writes the same bookshelf twice, about 10,000
triangles each: broken (open borders, ~150 components, ~14,000 self-intersecting face pairs, non-manifold: the bake
decides its inside by the winding number) and clean (closed and apart: the pseudonormal sign). For each resolution
(128 ... 1024, or --resolutions) and mesh, one bake with /usr/bin/time (wall time, peak RSS) and its stages, the
band's time per stored distance, and the floor: OpenVDB's meshToLevelSet of the same mesh alone (build/bin/bake-floor).
OpenVDB's signs are wrong on the open mesh (its flood fill leaks through the holes); its time is still the floor for
the distances. `--extra-mesh M` (repeatable) adds a mesh, e.g. one of CGAL's broken samples in
build/cgal-data/data/meshes (elk.off, mech-holes-shark.off, polygon_mesh.off, mask_cone.off, three_peaks.off,
b9_mesh.off, mpi.off).

  python3 bench/bench_bake.py --broken [--resolutions 128,256] [--json F] [--extra-mesh M ...] [--bin DIR]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")
FULL = [128, 256, 512, 1024, 2048, 4096]
QUICK = [128, 256, 512]


def timed(command):
    """Runs `command` under /usr/bin/time: (CompletedProcess, wall seconds, peak RSS MB)."""
    with tempfile.NamedTemporaryFile("r", suffix=".time") as t:
        r = subprocess.run(["/usr/bin/time", "-f", "%e %M", "-o", t.name, *command], capture_output=True, text=True)
        wall, kb = t.read().split()[-2:]
    return r, float(wall), float(kb) / 1024


def add_floor(args, mesh, resolution, run):
    """OpenVDB's narrow band on the same mesh and grid (bake-floor): its time, active voxels and peak memory."""
    r, _, run["floor_peak_rss_mb"] = timed([os.path.join(args.bin, "bake-floor"), mesh, "--resolution",
                                            str(resolution), "--band", "3"])
    if r.returncode == 0:
        floor = json.loads(r.stdout)
        run["floor_s"] = floor["seconds"]
        run["floor_active_voxels"] = floor["active_voxels"]


def stages_bench(args):
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "bench.vox.h5")
        for _ in range(args.runs):
            r = subprocess.run([args.voxfmt, "build", args.mesh, "-o", out, "--json", *args.build_options],
                               capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(f"bench_bake: build failed: {r.stderr.strip()}")
            runs.append(json.loads(r.stdout))
    stages = list(runs[0]["timings_s"].keys())
    result = {
        "mesh": os.path.basename(args.mesh),
        "options": args.build_options,
        "runs": args.runs,
        "cores": os.cpu_count(),
        "total_s_median": statistics.median(r["total_s"] for r in runs),
        "total_s_min": min(r["total_s"] for r in runs),
        "stage_s_median": {s: statistics.median(r["timings_s"][s] for r in runs) for s in stages},
        "peak_memory_mib": max(r["peak_memory_bytes"] for r in runs) / 2**20,
        "file_size_mib": runs[0]["file_size_bytes"] / 2**20,
        "dims": runs[0]["voxelmap"]["dims"],
        "points": runs[0]["pointshell"]["points"],
        "points_per_level": runs[0]["pointshell"]["points_per_level"],
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"voxfmt build {result['mesh']} {' '.join(args.build_options)}  ({args.runs} runs, {result['cores']} cores)")
    print(f"{'stage':<24}{'median s':>10}")
    for s, t in result["stage_s_median"].items():
        print(f"{s:<24}{t:>10.3f}")
    print(f"{'total':<24}{result['total_s_median']:>10.3f}   (min {result['total_s_min']:.3f})")
    print(f"peak memory {result['peak_memory_mib']:.0f} MiB, file {result['file_size_mib']:.1f} MiB, "
          f"grid {'x'.join(map(str, result['dims']))}, {result['points']} points, levels {result['points_per_level']}")


def scaling_run(args, resolution, tmp):
    """One resolution: bake, file, validate, load, accuracy, floor."""
    asset = os.path.join(tmp, f"r{resolution}.vox.h5")
    run = {"resolution": resolution}
    r, bake_s, bake_mb = timed([args.voxfmt, "build", args.mesh, "-o", asset, "--json", "--resolution",
                                str(resolution), "--points", str(args.points)])
    if r.returncode != 0:
        run["error"] = (r.stdout.strip() or r.stderr.strip())[-400:]
        return run
    report = json.loads(r.stdout)
    dims = report["voxelmap"]["dims"]
    run.update({
        "voxels": dims[0] * dims[1] * dims[2],
        "dims": dims,
        "bake_s": bake_s,
        "peak_rss_mb": bake_mb,
        "file_mb": os.path.getsize(asset) / 1e6,
        "stages_s": report["timings_s"],
    })
    validate = [args.voxfmt, "validate", "--level", "full", "--max-memory", str(args.max_memory), asset]
    r, run["validate_s"], run["validate_peak_rss_mb"] = timed(validate)
    run["valid"] = r.returncode == 0
    if not run["valid"]:
        run["validate_output"] = r.stdout.strip()[-400:]
    r = subprocess.run([os.path.join(args.bin, "asset-check"), asset, args.mesh, "--samples", str(args.samples),
                        "--max-memory", str(args.max_memory)],
                       capture_output=True, text=True)
    if r.returncode == 0:
        run.update(json.loads(r.stdout))
    else:
        run["asset_check_error"] = r.stderr.strip()[-400:]
    add_floor(args, args.mesh, resolution, run)
    os.remove(asset)
    return run


def plot(runs, path):
    try:
        import matplotlib
    except ImportError:
        sys.exit(f"bench_bake: --png needs matplotlib (Debian: python3-matplotlib, for /usr/bin/python3); "
                 f"{sys.executable} has none")

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in runs if "bake_s" in r]
    res = [r["resolution"] for r in ok]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    a.loglog(res, [r["bake_s"] for r in ok], "o-", label="voxfmt build (whole bake)")
    a.loglog(res, [r.get("floor_s", float("nan")) for r in ok], "s--", label="OpenVDB meshToLevelSet alone (floor)")
    a.set_xlabel("resolution (voxels along the longest axis)")
    a.set_ylabel("seconds")
    a.set_title("time")
    b.loglog(res, [r["peak_rss_mb"] for r in ok], "o-", label="voxfmt build peak RSS")
    b.loglog(res, [r.get("floor_peak_rss_mb", float("nan")) for r in ok], "s--", label="floor peak RSS")
    b.loglog(res, [r["file_mb"] for r in ok], "^-", label="asset file")
    b.loglog(res, [r.get("runtime_mb", float("nan")) for r in ok], "v-", label="runtime memory")
    b.set_xlabel("resolution (voxels along the longest axis)")
    b.set_ylabel("MB")
    b.set_title("memory")
    for ax in (a, b):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_xticks(res)
        ax.set_xticklabels([str(x) for x in res])
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def scaling_bench(args):
    for tool in ("asset-check", "bake-floor"):
        if not os.path.exists(os.path.join(args.bin, tool)):
            sys.exit(f"bench_bake: {os.path.join(args.bin, tool)} not found; build first (bash scripts/build.sh)")
    resolutions = ([int(x) for x in args.resolutions.split(",")] if args.resolutions
                   else QUICK if args.quick else FULL)
    runs = []
    header = (f"{'res':>5} {'voxels':>13} {'bake s':>8} {'floor s':>8} {'x':>5} {'peak MB':>8} {'floor MB':>9} {'x':>5} "
              f"{'file MB':>8} {'run MB':>7} {'load s':>7} {'valid s':>8} {'band err':>9} {'est mean':>9}")
    print(f"bench_bake --scaling: {os.path.basename(args.mesh)}, --points {args.points}, {os.cpu_count()} cores",
          file=sys.stderr)
    print(header, file=sys.stderr)
    if args.tmp:
        os.makedirs(args.tmp, exist_ok=True)  # a fresh machine's scratch folder
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        for resolution in resolutions:
            run = scaling_run(args, resolution, tmp)
            runs.append(run)
            if "error" in run:
                print(f"{resolution:>5} failed: {run['error']}", file=sys.stderr)
                continue
            floor_s, floor_mb = run.get("floor_s", float("nan")), run.get("floor_peak_rss_mb", float("nan"))
            print(f"{resolution:>5} {run['voxels']:>13,} {run['bake_s']:>8.2f} {floor_s:>8.2f} "
                  f"{run['bake_s'] / floor_s:>5.2f} {run['peak_rss_mb']:>8.0f} {floor_mb:>9.0f} "
                  f"{run['peak_rss_mb'] / floor_mb:>5.2f} {run['file_mb']:>8.1f} {run.get('runtime_mb', 0):>7.1f} "
                  f"{run.get('load_s', 0):>7.2f} {run['validate_s']:>8.2f} {run.get('band_err_max_vox', 0):>9.2e} "
                  f"{run.get('estimate_err_mean_vox', 0):>9.3f}" + ("" if run["valid"] else "  INVALID"),
                  file=sys.stderr)
    result = {"mesh": os.path.basename(args.mesh), "points": args.points, "cores": os.cpu_count(),
              "command": " ".join(["python3", "bench/bench_bake.py", *sys.argv[1:]]), "runs": runs}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
            f.write("\n")
    if args.png:
        plot(runs, args.png)
    failed = [r for r in runs if "error" in r or not r.get("valid")]
    return 1 if failed else 0


def broken_run(args, mesh, resolution, tmp):
    """One bake of `mesh` at `resolution` and the floor beside it."""
    asset = os.path.join(tmp, "broken.vox.h5")
    run = {"mesh": os.path.basename(mesh), "resolution": resolution}
    r, run["bake_s"], run["peak_rss_mb"] = timed([args.voxfmt, "build", mesh, "-o", asset, "--json", "--resolution",
                                                   str(resolution), "--points", str(args.points)])
    if r.returncode != 0:
        run["error"] = (r.stdout.strip() or r.stderr.strip())[-400:]
        return run
    report = json.loads(r.stdout)
    run["stages_s"] = report["timings_s"]
    run["stored_distances"] = report["voxelmap"]["stored_distances"]
    run["warnings"] = [w["code"] for w in report["warnings"]]
    run["band_us_per_stored"] = 1e6 * report["timings_s"].get("voxelmap: band", float("nan")) / max(
        1, run["stored_distances"])
    add_floor(args, mesh, resolution, run)
    os.remove(asset)
    return run


def broken_bench(args):
    if not os.path.exists(os.path.join(args.bin, "bake-floor")):
        sys.exit(f"bench_bake: {os.path.join(args.bin, 'bake-floor')} not found; build first (bash scripts/build.sh)")
    resolutions = [int(x) for x in args.resolutions.split(",")] if args.resolutions else [128, 256, 512, 1024]
    runs = []
    if args.tmp:
        os.makedirs(args.tmp, exist_ok=True)  # a fresh machine's scratch folder
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        meshes = []
        for kind in ("clean", "broken"):
            path = os.path.join(tmp, f"shelf-{kind}.off")
            subprocess.run([sys.executable, os.path.join(ROOT, "bench", "make_shelf.py"), kind, path], check=True,
                           capture_output=True)
            meshes.append(path)
        meshes += args.extra_meshes
        print(f"bench_bake --broken: {', '.join(os.path.basename(m) for m in meshes)}, {os.cpu_count()} cores "
              f"(OpenVDB's signs are wrong on open meshes; its time is the floor for the distances)", file=sys.stderr)
        print(f"{'mesh':<22}{'res':>5} {'bake s':>8} {'band s':>8} {'stored':>11} {'band us/d':>10} {'peak MB':>8} "
              f"{'floor s':>8} {'floor MB':>9}  stages", file=sys.stderr)
        for resolution in resolutions:
            for mesh in meshes:
                run = broken_run(args, mesh, resolution, tmp)
                runs.append(run)
                if "error" in run:
                    print(f"{run['mesh']:<22}{resolution:>5} failed: {run['error']}", file=sys.stderr)
                    continue
                st = run["stages_s"]
                print(f"{run['mesh']:<22}{resolution:>5} {run['bake_s']:>8.2f} {st.get('voxelmap: band', 0):>8.2f} "
                      f"{run['stored_distances']:>11,} {run['band_us_per_stored']:>10.3f} {run['peak_rss_mb']:>8.0f} "
                      f"{run.get('floor_s', float('nan')):>8.2f} {run.get('floor_peak_rss_mb', float('nan')):>9.0f}  "
                      + " ".join(f"{k.replace('voxelmap: ', '')}={v:.2f}" for k, v in st.items()
                                 if k in ("repair", "voxelmap: band", "voxelmap: lattice", "point shell", "write")),
                      file=sys.stderr)
    result = {"cores": os.cpu_count(), "command": " ".join(["python3", "bench/bench_bake.py", *sys.argv[1:]]),
              "note": "OpenVDB's signs are wrong on open meshes; its time is the floor for the distances",
              "runs": runs}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
            f.write("\n")
    return 1 if any("error" in r for r in runs) else 0


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--max-memory", type=int, default=8192,
                        help="MiB validate and asset-check may read (a 4096^3 bake needs ~2.1 GB; default 8192)")
    parser.add_argument("--bin", default=BIN, help="where voxfmt, bake-floor and asset-check are (build/bin)")
    parser.add_argument("--voxfmt", default=None, help="the voxfmt to time (default: BIN/voxfmt)")
    parser.add_argument("--mesh", default=os.path.join(ROOT, "build", "cgal-data", "data", "meshes", "bunny00.off"))
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--scaling", action="store_true", help="measure how the cost grows with the resolution")
    parser.add_argument("--broken", action="store_true", help="broken meshes against clean ones (make_shelf.py)")
    parser.add_argument("--extra-mesh", dest="extra_meshes", action="append", default=[],
                        help="--broken: also bake this mesh (repeatable)")
    parser.add_argument("--quick", action="store_true", help="--scaling up to resolution 512 only")
    parser.add_argument("--resolutions", help="--scaling, --broken at these resolutions (comma-separated)")
    parser.add_argument("--points", type=int, default=35000, help="--scaling, --broken: points of the point shell")
    parser.add_argument("--samples", type=int, default=20000, help="--scaling: voxels sampled for the accuracy")
    parser.add_argument("--tmp", default=None, help="--scaling: folder for the assets (default: the system's)")
    parser.add_argument("--png", help="--scaling: write a log-log plot here")
    parser.add_argument("--json", nargs="?", const=True, default=False,
                        help="print JSON instead of a table (--scaling: write it to this file)")
    parser.add_argument("build_options", nargs="*", default=["--resolution", "306", "--points", "35000"])
    args = parser.parse_args()
    args.voxfmt = args.voxfmt or os.path.join(args.bin, "voxfmt")
    if not os.path.exists(args.voxfmt):
        sys.exit(f"bench_bake: {args.voxfmt} not found; build first (bash scripts/build.sh)")
    if args.broken:
        if args.json is True:
            sys.exit("bench_bake: --broken --json needs a file name")
        sys.exit(broken_bench(args))
    if args.scaling:
        if args.json is True:
            sys.exit("bench_bake: --scaling --json needs a file name")
        sys.exit(scaling_bench(args))
    stages_bench(args)


if __name__ == "__main__":
    main()
