"""The batched contact query on a GPU against the CPU batch, on the same bunny-on-bunny poses (issue 34).

Two halves, because the GPU machines that measure it have CUDA and Python but none of voxfmt's libraries:

  .venv/bin/python bench/gpu_batch.py --prepare out/gpu-input        # here: asset, poses, the CPU's figures
  bash scripts/gpu-check.sh out/gpu-input                             # there: the kernel, timed (JSON in $OUT)
  .venv/bin/python bench/gpu_batch.py --report GPU.json --input out/gpu-input \\
      --json bench/results/gpu-batch-CARD.json --markdown bench/results/gpu-batch-CARD.md

--prepare bakes CGAL's bunny at the seed's settings (0.15 m, resolution 306, 35,000 points), makes the 40,000 poses
bench/python_peers.py --parts batch makes (B approaches A until they touch, then 0.5 mm short to 1.5 mm in), runs
them through voxfmt.BatchScene on the CPU (runtime::BatchScene, the runtime's query: its results are the reference) and
through contacts_batch on 2 threads (the CPU batch's figure), and exports the asset's arrays as the query core
reads them. --report joins the GPU's JSON and the CPU's figures into the committed result.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def prepare(folder: Path, poses: int, seed: int, bunny_mesh: str, threads: int) -> None:
    import python_peers as peers  # the batch bench's asset and pose generator

    import voxfmt
    from voxfmt._voxfmt import _export_core

    folder.mkdir(parents=True, exist_ok=True)
    bunny = peers.baked("bunny00-0.15m", Path(bunny_mesh), 0.15, folder)
    rng = np.random.default_rng(seed)
    pa, pb = peers.bunny_poses(bunny.body, poses, rng)
    pa, pb = pa.astype(np.float32), pb.astype(np.float32)  # what a GPU caller holds
    stiffness = 2e4
    scene = voxfmt.BatchScene([bunny.body])
    start = time.perf_counter()
    ref = scene.contacts(pa, pb, stiffness=stiffness, threads=threads)
    scene_rate = poses / (time.perf_counter() - start)
    # The references the device must equal, output for output: touching, and near (1 mm), 8 contacts kept each.
    max_contacts = 8
    references = {}
    for case, proximity in (("touching", 0.0), ("near", 1e-3)):
        r = scene.contacts(pa, pb, stiffness=stiffness, proximity=proximity, max_contacts=max_contacts,
                           threads=threads)
        references[f"{case}_proximity"] = proximity
        references |= {f"{case}_{name}": getattr(r, name) for name in (
            "count", "max_depth", "force", "torque", "overflow", "error", "points", "normals", "depths",
            "point_index", "point_of_b")}
    start = time.perf_counter()
    voxfmt.contacts_batch(bunny.body, pa.astype(np.float64), bunny.body, pb.astype(np.float64), stiffness=stiffness,
                          threads=threads)
    batch_rate = poses / (time.perf_counter() - start)
    core = _export_core(bunny.body)
    np.savez(folder / "gpu-batch-input.npz", poses_a=pa, poses_b=pb, stiffness=stiffness, max_contacts=max_contacts,
             **references, **{k: np.asarray(v) for k, v in core.items()})
    device_arrays = sum(np.asarray(core[k]).nbytes for k in ("bricks", "codes", "lattice", "nodes", "points", "normals"))
    # The export's codes carry the device's apron (736 codes a brick); the runtime holds 512 a brick.
    arrays = device_arrays - np.asarray(core["codes"]).nbytes * (736 - 512) // 736
    cpu = {"poses": poses, "threads": threads, "cpu_poses_per_s": batch_rate, "batch_scene_cpu_poses_per_s": scene_rate,
           "runtime_arrays_mb": arrays / 1e6, "device_arrays_mb": device_arrays / 1e6, "touching": int((ref.count > 0).sum()),
           "machine": f"{platform.machine()}, {os.cpu_count()} cores", "load_average": list(os.getloadavg()),
           "asset": str(folder / "bunny00-0.15m-r306-p35000.vox.h5")}
    (folder / "cpu.json").write_text(json.dumps(cpu, indent=1))
    print(json.dumps(cpu, indent=1))


def variant_row(gpu: dict) -> dict:
    """One build's figures (scripts/gpu-check.sh runs several block sizes, and the default without the apron)."""
    at = {r["envs"]: r for r in gpu["latency"]}
    agreed = all(a["identical"] == a["environments"] for a in gpu["agreement"].values())
    return {"block_lanes": gpu.get("block_lanes"), "min_blocks": gpu.get("min_blocks", 0), "apron": gpu.get("apron"),
            "gpu_poses_per_s": gpu["gpu_poses_per_s"],
            "p50_us_4096": at.get(4096, {}).get("p50_us"), "kernel_p50_us_4096": at.get(4096, {}).get("kernel_p50_us"),
            "p50_us_16384": at.get(16384, {}).get("p50_us"),
            "kernel_p50_us_16384": at.get(16384, {}).get("kernel_p50_us"),
            "device_memory_mb": gpu["device_memory_mb"], "device_array_mb": gpu.get("device_array_mb"),
            "every_output_equal": agreed}


def report(gpu_json: Path, folder: Path, out_json: Path | None, out_md: Path | None,
           variants: list[Path] | None = None) -> None:
    gpu = json.loads(gpu_json.read_text())
    cpu = json.loads((folder / "cpu.json").read_text())
    rows = [variant_row(gpu)] + [variant_row(json.loads(v.read_text())) for v in variants or []]
    result = {
        "device": gpu["device"],
        "block_lanes": gpu.get("block_lanes"),
        "apron": gpu.get("apron"),
        "gpu_poses_per_s": gpu["gpu_poses_per_s"],
        "cpu_poses_per_s": cpu["cpu_poses_per_s"],
        "cpu_threads": cpu["threads"],
        "device_memory_mb": gpu["device_memory_mb"],
        "runtime_memory_mb": cpu["runtime_arrays_mb"],
        "latency": gpu["latency"],
        "throughput": gpu["throughput"],
        "agreement": gpu["agreement"],
        "variants": rows,
        "cpu": cpu,
    }
    if out_json:
        out_json.write_text(json.dumps(result, indent=1))
    lines = [f"# GPU batch on {result['device']}", "",
             f"bunny on bunny, {cpu['poses']:,} poses; GPU: {result['gpu_poses_per_s']:,.0f} poses/s (the machine "
             f"that prepared the poses, another run, so no ratio: contacts_batch on {cpu['threads']} threads of "
             f"{cpu['machine']}, {result['cpu_poses_per_s']:,.0f} poses/s). Device memory {result['device_memory_mb']:.1f} MB for the asset "
             f"(measured; the CPU runtime's arrays: {result['runtime_memory_mb']:.1f} MB). Every output equal to the "
             "CPU's (counts, depths, wrench, overflow, errors, the first 8 contacts): "
             + "; ".join(f"{case} {a['identical']:,} of {a['environments']:,} environments"
                         + (f" (differing: {', '.join(a['differs'])})" if a["differs"] else "")
                         for case, a in result["agreement"].items()) + ".", "",
             "| environments | p50 µs | p99 µs | kernel p50 µs |", "|--:|--:|--:|--:|"]
    lines += [f"| {r['envs']:,} | {r['p50_us']:.1f} | {r['p99_us']:.1f} | {r.get('kernel_p50_us', float('nan')):.1f} |"
              for r in result["latency"]]
    lines += ["", "| environments | poses/s |", "|--:|--:|"]
    lines += [f"| {r['envs']:,} | {r['poses_per_s']:,.0f} |" for r in result["throughput"]]
    if len(rows) > 1:
        def us(v: float | None) -> str:
            return "–" if v is None else f"{v:,.0f}"
        lines += ["", "Builds measured in the same run (the first is the default):", "",
                  "| lanes a block | register cap (blocks a multiprocessor) | apron | peak poses/s "
                  "| 4,096 envs p50 / kernel µs | 16,384 envs p50 / kernel µs "
                  "| device MB (measured / arrays) | every output equal |", "|--:|--:|:-:|--:|--:|--:|--:|:-:|"]
        lines += [f"| {r['block_lanes']} | {r['min_blocks'] or 'none'} | {'yes' if r['apron'] else 'no'} | "
                  f"{r['gpu_poses_per_s']:,.0f} | "
                  f"{us(r['p50_us_4096'])} / {us(r['kernel_p50_us_4096'])} | "
                  f"{us(r['p50_us_16384'])} / {us(r['kernel_p50_us_16384'])} | "
                  f"{r['device_memory_mb']:.1f} / {r['device_array_mb'] or 0:.1f} | "
                  f"{'yes' if r['every_output_equal'] else 'NO'} |" for r in rows]
    text = "\n".join(lines) + "\n"
    if out_md:
        out_md.write_text(text)
    print(text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--prepare", type=Path, help="write the inputs and the CPU's figures into this folder")
    parser.add_argument("--poses", type=int, default=40000)
    parser.add_argument("--seed", type=int, default=20261127)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--bunny", default=os.environ.get("VOXFMT_BUNNY", "build/cgal-data/data/meshes/bunny00.off"))
    parser.add_argument("--report", type=Path, help="the GPU's JSON (scripts/gpu-check.sh) to join with --input")
    parser.add_argument("--input", type=Path, default=Path("out/gpu-input"))
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", type=Path)
    parser.add_argument("--variants", type=Path, nargs="*", help="other builds' JSON files from the same run")
    args = parser.parse_args()
    if args.prepare:
        prepare(args.prepare, args.poses, args.seed, args.bunny, args.threads)
    if args.report:
        report(args.report, args.input, args.json, args.markdown, args.variants)
    if not args.prepare and not args.report:
        parser.error("nothing to do: --prepare FOLDER and/or --report GPU.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
