"""The GPU batch measured on a CUDA machine that has only CUDA, Python and CuPy (scripts/gpu-check.sh): the
standalone runner (standalone.cu + loaders/gpu/src/kernels.cu) over an asset and poses exported where voxfmt is
built (bench/gpu_batch.py --prepare), against the CPU's results on the same poses.

  python3 scripts/gpu/check.py --input out/gpu-input/gpu-batch-input.npz --library LIB.so --json OUT.json
  python3 scripts/gpu/check.py --input ... --backend cpu --json OUT.json   # the same flow on voxfmt's CPU path

Reports (JSON): device, poses/s over environments from 1 to 1 M, per-call latency p50/p99 at 1, 64, 1024, 4096 and
16384 environments (host clock, launch to results in host memory with the outputs made once, beside the kernel's own time by CUDA events), the device memory
the asset's upload took (measured: the device's free memory before and after), and agreement with the CPU: every
output of every environment (counts, deepest penetration, force, torque, overflow, error codes and the first
max_contacts contacts: points, normals, depths, point indices, sides), touching (proximity 0) and near (1 mm),
compared for equality.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import sys
import time
from typing import Any, Callable

import numpy as np

LATENCY_ENVS = [1, 64, 1024, 4096, 16384]
THROUGHPUT_ENVS = [1, 16, 256, 4096, 16384, 65536, 262144, 1048576]


PER_ENV = ("count", "max_depth", "force", "torque", "overflow", "error")
CONTACTS = ("points", "normals", "depths", "point_index", "point_of_b")


def agreement(ref: dict[str, np.ndarray], got: dict[str, np.ndarray]) -> dict[str, Any]:
    """Per environment: every output equal to the CPU's (a contact row only where the environment has one)."""
    n = len(ref["count"])
    same = np.ones(n, dtype=bool)
    differs: dict[str, dict[str, float]] = {}
    for name in PER_ENV + (CONTACTS if "points" in ref else ()):
        a, b = np.asarray(ref[name]), np.asarray(got[name])
        equal = a == b
        if name in CONTACTS:  # rows past an environment's contacts are not written
            kept = np.minimum(ref["count"], a.shape[1])
            written = np.arange(a.shape[1])[None, :] < kept[:, None]
            equal |= ~(written.reshape(written.shape + (1,) * (a.ndim - 2)))
        per_env = equal.reshape(n, -1).all(axis=1)
        same &= per_env
        if not per_env.all():
            gap = np.abs(a.astype(np.float64) - b.astype(np.float64))[~per_env].max()
            differs[name] = {"environments": int((~per_env).sum()), "max_abs_difference": float(gap)}
    return {"environments": n, "identical": int(same.sum()), "differs": differs,
            "errors": int((np.asarray(got["error"]) != 0).sum())}


def plain_codes(apron_codes: np.ndarray) -> np.ndarray:
    """The runtime's 8^3 value bricks from bricks with an apron (9^3 codes, k, j, i from the slowest, then the
    mask): what the device reads without the apron."""
    bricks = np.asarray(apron_codes).reshape(-1, 736)[:, :729].reshape(-1, 9, 9, 9)
    return np.ascontiguousarray(bricks[:, :8, :8, :8]).reshape(-1)


class CudaBackend:
    """The standalone runner through ctypes, on CuPy arrays."""

    def __init__(self, library: str, data: dict[str, np.ndarray], apron: bool = True) -> None:
        import cupy

        self.cp = cupy
        self.lib = ctypes.CDLL(library)
        self.lib.voxfmt_gpu_check_run.restype = ctypes.c_int
        self.lanes = int(self.lib.voxfmt_gpu_check_lanes())
        self.min_blocks = int(self.lib.voxfmt_gpu_check_min_blocks())
        self.apron = apron
        arrays = {k: data[k] for k in ("bricks", "codes", "lattice", "nodes", "points", "normals")}
        if not apron:
            arrays["codes"] = plain_codes(data["codes"])
        cupy.cuda.Device().synchronize()
        free_before = cupy.cuda.runtime.memGetInfo()[0]
        self.d = {k: cupy.asarray(v) for k, v in arrays.items()}
        cupy.cuda.Device().synchronize()
        self.device_bytes = int(free_before - cupy.cuda.runtime.memGetInfo()[0])  # measured, pool rounding and all
        self.array_bytes = int(sum(a.nbytes for a in self.d.values()))
        self.host = {k: np.ascontiguousarray(data[k]) for k in ("field_floats", "field_dims", "body_doubles")}
        # standalone.cu rebuilds the shell without an anchor: an asset near its frame's origin only (the bunny).
        if np.any(np.asarray(data.get("anchor", np.zeros(3))) != 0):
            raise SystemExit("check.py: this asset's shell is anchored far from its origin; the standalone runner "
                             "places points from the origin only")
        self.count = int(data["points"].shape[0])
        self.levels = int(data["levels"])
        self.device = cupy.cuda.runtime.getDeviceProperties(cupy.cuda.runtime.getDevice())["name"].decode()

    def upload(self, poses: np.ndarray) -> Any:
        return self.cp.asarray(poses)

    def outputs(self, n: int, k: int = 0) -> dict[str, Any]:
        cp = self.cp
        out = {"count": cp.empty(n, cp.int32), "max_depth": cp.empty(n, cp.float32), "force": cp.empty((n, 3), cp.float32),
               "torque": cp.empty((n, 3), cp.float32), "overflow": cp.empty(n, cp.int32), "error": cp.empty(n, cp.int32)}
        if k:
            out |= {"points": cp.empty((n, k, 3), cp.float32), "normals": cp.empty((n, k, 3), cp.float32),
                    "depths": cp.empty((n, k), cp.float32), "point_index": cp.empty((n, k), cp.int32),
                    "point_of_b": cp.empty((n, k), cp.uint8)}
        return out

    def buffers(self, n: int) -> Any:
        """Outputs on the device and page-locked host arrays for them, made once, as a caller in a loop holds them."""
        import cupyx

        out = self.outputs(n)
        return out, {name: cupyx.empty_pinned(v.shape, v.dtype) for name, v in out.items()}

    def run(self, pa: Any, pb: Any, stiffness: float, proximity: float = 0.0, k: int = 0,
            timed: bool = False, buffers: Any = None) -> tuple[Callable[[], dict[str, np.ndarray]], float | None]:
        cp, n = self.cp, pa.shape[0]
        out, host = buffers if buffers is not None else (self.outputs(n, k), None)
        text = ctypes.create_string_buffer(512)
        ptr = lambda a: ctypes.c_void_p(a.data.ptr)  # noqa: E731
        maybe = lambda name: ptr(out[name]) if k else ctypes.c_void_p(0)  # noqa: E731
        hptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)  # noqa: E731
        kernel_ms = ctypes.c_float(0.0)
        status = self.lib.voxfmt_gpu_check_run(
            ptr(self.d["bricks"]), ptr(self.d["codes"]), ctypes.c_int(int(self.apron)), ptr(self.d["lattice"]), hptr(self.host["field_floats"]),
            hptr(self.host["field_dims"]), ptr(self.d["nodes"]), ptr(self.d["points"]), ptr(self.d["normals"]),
            hptr(self.host["body_doubles"]), ctypes.c_uint32(self.count), ctypes.c_uint32(self.levels), ptr(pa), ptr(pb),
            ctypes.c_size_t(n), ctypes.c_double(proximity), ctypes.c_double(stiffness), ptr(out["count"]),
            ptr(out["max_depth"]), ptr(out["force"]), ptr(out["torque"]), ptr(out["overflow"]), ptr(out["error"]),
            ctypes.c_uint32(k), maybe("points"), maybe("normals"), maybe("depths"), maybe("point_index"),
            maybe("point_of_b"), ctypes.byref(kernel_ms) if timed else None,
            ctypes.c_size_t(cp.cuda.get_current_stream().ptr), text, ctypes.c_size_t(512))
        if status != 0:
            raise RuntimeError(text.value.decode())

        def fetch() -> dict[str, np.ndarray]:
            stream = cp.cuda.get_current_stream()
            if host is None:
                stream.synchronize()
                return {name: cp.asnumpy(v) for name, v in out.items()}
            for name, v in out.items():  # every output copied on the stream, then one wait
                cp.cuda.runtime.memcpyAsync(host[name].ctypes.data, v.data.ptr, v.nbytes,
                                            cp.cuda.runtime.memcpyDeviceToHost, stream.ptr)
            stream.synchronize()
            return host

        return fetch, (float(kernel_ms.value) if timed else None)

    def sync(self) -> None:
        self.cp.cuda.get_current_stream().synchronize()


class CpuBackend:
    """voxfmt's CPU path (BatchScene on NumPy): the flow of this script without a GPU, for its own test."""

    def __init__(self, asset: str) -> None:
        import voxfmt

        self.scene = voxfmt.BatchScene([voxfmt.load(asset)])
        self.device = "cpu (voxfmt.BatchScene)"
        self.device_bytes = self.array_bytes = 0
        self.lanes, self.min_blocks, self.apron = 0, 0, False

    def upload(self, poses: np.ndarray) -> np.ndarray:
        return poses

    def buffers(self, n: int) -> Any:
        return None

    def run(self, pa: np.ndarray, pb: np.ndarray, stiffness: float, proximity: float = 0.0, k: int = 0,
            timed: bool = False, buffers: Any = None) -> tuple[Callable[[], dict[str, np.ndarray]], float | None]:
        r = self.scene.contacts(pa, pb, stiffness=stiffness, proximity=proximity, max_contacts=k, check=False)
        return (lambda: {name: getattr(r, name) for name in PER_ENV + (CONTACTS if k else ())}), None

    def sync(self) -> None:
        pass


def percentiles_us(samples: list[float]) -> tuple[float, float]:
    s = np.asarray(samples) * 1e6
    return float(np.percentile(s, 50)), float(np.percentile(s, 99))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", required=True, help="bench/gpu_batch.py --prepare's .npz")
    parser.add_argument("--backend", choices=["cuda", "cpu"], default="cuda")
    parser.add_argument("--library", help="the standalone runner (cuda backend)")
    parser.add_argument("--asset", help="the asset file (cpu backend)")
    parser.add_argument("--max-envs", type=int, default=THROUGHPUT_ENVS[-1])
    parser.add_argument("--agreement-poses", type=int, help="compare only the first N poses (default: all)")
    parser.add_argument("--no-apron", action="store_true", help="upload the runtime's plain bricks (cuda backend)")
    parser.add_argument("--reps", type=int, default=50, help="timed calls per latency size")
    parser.add_argument("--json", required=True)
    args = parser.parse_args()
    data = dict(np.load(args.input))
    stiffness, k = float(data["stiffness"]), int(data["max_contacts"])
    backend = CudaBackend(args.library, data, not args.no_apron) if args.backend == "cuda" else CpuBackend(args.asset)
    pa_all, pb_all = data["poses_a"], data["poses_b"]
    count = len(pa_all)

    # Agreement on every pose of the bench, touching and near, every output.
    report: dict[str, Any] = {"device": backend.device, "device_memory_mb": backend.device_bytes / 1e6,
                              "device_array_mb": backend.array_bytes / 1e6, "block_lanes": backend.lanes,
                              "min_blocks": backend.min_blocks,
                              "apron": backend.apron, "agreement": {}, "latency": [], "throughput": []}
    compared = slice(0, args.agreement_poses)
    pa, pb = backend.upload(pa_all[compared]), backend.upload(pb_all[compared])
    for case in ("touching", "near"):
        proximity = float(data[f"{case}_proximity"])
        got = backend.run(pa, pb, stiffness, proximity, k)[0]()
        ref = {name: data[f"{case}_{name}"][compared] for name in PER_ENV + CONTACTS}
        report["agreement"][case] = agreement(ref, got) | {"proximity_m": proximity, "max_contacts": k}
    # Latency: host clock from the launch to results in host memory (outputs and page-locked host arrays made once,
    # as a caller in a loop holds them: the launch, the kernel, the copies, one wait); the kernel's by CUDA events.
    for envs in [e for e in LATENCY_ENVS if e <= args.max_envs]:
        pa, pb = backend.upload(pa_all[:envs] if envs <= count else np.resize(pa_all, (envs, 4, 4))), \
            backend.upload(pb_all[:envs] if envs <= count else np.resize(pb_all, (envs, 4, 4)))
        samples, kernel = [], []
        buffers = backend.buffers(envs)
        for rep in range(args.reps + 3):
            start = time.perf_counter()
            backend.run(pa, pb, stiffness, buffers=buffers)[0]()
            if rep >= 3:  # the first calls warm the device and the caches
                samples.append(time.perf_counter() - start)
                kernel_ms = backend.run(pa, pb, stiffness, timed=True)[1]
                if kernel_ms is not None:
                    kernel.append(kernel_ms * 1e-3)
        p50, p99 = percentiles_us(samples)
        row = {"envs": envs, "p50_us": p50, "p99_us": p99}
        if kernel:
            row["kernel_p50_us"], row["kernel_p99_us"] = percentiles_us(kernel)
        report["latency"].append(row)
        print(f"latency {envs:>7} envs: p50 {p50:9.1f} us  p99 {p99:9.1f} us"
              + (f"  kernel p50 {row['kernel_p50_us']:9.1f} us" if kernel else ""), flush=True)
    # Throughput: poses per second at growing batch sizes (the bench's poses, repeated).
    for envs in [e for e in THROUGHPUT_ENVS if e <= args.max_envs]:
        pa, pb = backend.upload(np.resize(pa_all, (envs, 4, 4))), backend.upload(np.resize(pb_all, (envs, 4, 4)))
        backend.run(pa, pb, stiffness)[0]()
        reps = max(3, min(50, int(2e6 // envs)))
        start = time.perf_counter()
        for _ in range(reps):
            backend.run(pa, pb, stiffness)
        backend.sync()
        rate = envs * reps / (time.perf_counter() - start)
        report["throughput"].append({"envs": envs, "poses_per_s": rate})
        print(f"throughput {envs:>7} envs: {rate / 1e6:8.2f} M poses/s", flush=True)
    report["gpu_poses_per_s"] = max(r["poses_per_s"] for r in report["throughput"])
    with open(args.json, "w") as fh:
        json.dump(report, fh, indent=1)
    print(json.dumps(report["agreement"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
