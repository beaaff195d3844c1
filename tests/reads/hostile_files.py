"""Small hostile asset files, one per class of harm a reader must refuse before paying for it (issue 31), each
with the codes every consumer must report and the CLI's exit status. Written with h5py from the spec's sphere
fixture (tests/spec/spec_fixture.py): quick to write, a few MB at most, whatever they declare."""

from __future__ import annotations

import os
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "spec"))
import spec_fixture as sf  # noqa: E402


@dataclass(frozen=True)
class Case:
    path: str
    codes: tuple[str, ...]  # a refusal names one of these
    exit: int  # voxfmt validate's exit status: 1 invalid, 2 not judged (over the read budget)
    why: str


def _replace(f: h5py.File, path: str, shape: tuple[int, ...], dtype: str, chunks: tuple[int, ...], **create) -> None:
    """Dataset `path` replaced by an unwritten one of `shape`: it declares its size and stores nothing."""
    parent, name = sf.split_path(path)
    del f[path]
    f[parent].create_dataset(name, shape=shape, dtype=dtype, chunks=chunks, **create)


def _set_dims(f: h5py.File, dims: tuple[int, int, int]) -> None:
    f["/voxelmap"].attrs.create("dims", np.array(dims, dtype="<u4"), dtype="<u4")


def _raw_string_attr(obj, name: bytes, raw: bytes) -> None:
    """A fixed-length, null-terminated UTF-8-tagged string attribute holding exactly `raw` (maybe not UTF-8)."""
    if h5py.h5a.exists(obj.id, name):
        h5py.h5a.delete(obj.id, name)
    tid = h5py.h5t.C_S1.copy()
    tid.set_size(len(raw) + 1)
    tid.set_strpad(h5py.h5t.STR_NULLTERM)
    tid.set_cset(h5py.h5t.CSET_UTF8)
    aid = h5py.h5a.create(obj.id, name, tid, h5py.h5s.create(h5py.h5s.SCALAR))
    aid.write(np.array(raw + b"\0", dtype="S%d" % (len(raw) + 1)), mtype=tid)


def write_cases(folder: str | os.PathLike[str]) -> dict[str, Case]:
    folder = Path(folder)
    cases: dict[str, Case] = {}

    def add(name: str, codes: tuple[str, ...], exit: int, why: str, **write) -> None:
        path = str(folder / f"{name}.vox.h5")
        sf.write_fixture_h5py(path, **write)
        cases[name] = Case(path, codes, exit, why)

    # -- sizes: declared, never paid ----------------------------------------------------------------------------
    def grid_10000(f: h5py.File) -> None:
        _set_dims(f, (10000, 10000, 10000))
        _replace(f, "/voxelmap/bricks", (1250,) * 3, "<i4", (32, 32, 32), fillvalue=-1)
        _replace(f, "/voxelmap/lattice", (1251,) * 3, "<f4", (32, 32, 32))

    add("declared_grid", ("VALUE_OUT_OF_RANGE",), 1,
        "a 10000^3 grid: brick table and lattice of 7.8 GB each, no chunk written", post=grid_10000)
    add("one_huge_chunk", ("VALUE_OUT_OF_RANGE",), 1, "brick_values in one chunk of 1 GiB",
        post=lambda f: _replace(f, "/voxelmap/brick_values", (1 << 20, 512), "<i2", (1 << 20, 512)))
    add("unwritten_rows", ("VALUE_OUT_OF_RANGE",), 1, "brick_values of 2^22 rows (4 GiB), none written",
        post=lambda f: _replace(f, "/voxelmap/brick_values", (1 << 22, 512), "<i2", (64, 512)))

    def tiny_chunks(f: h5py.File) -> None:
        _set_dims(f, (640, 640, 640))
        _replace(f, "/voxelmap/bricks", (80, 80, 80), "<i4", (1, 1, 1), fillvalue=-1)
        _replace(f, "/voxelmap/lattice", (81, 81, 81), "<f4", (27, 27, 27))

    add("tiny_chunks", ("VALUE_OUT_OF_RANGE",), 1, "a brick table of 512,000 one-entry chunks", post=tiny_chunks)

    def deflate_bomb(f: h5py.File) -> None:
        # 256 chunks of 4 MiB of zeros, each deflated to ~4 KB: 1 GiB that inflates from ~1 MB. Padding (an
        # unknown dataset of incompressible bytes, ignored by readers) keeps the file within the format's
        # declared-per-stored limit, so what refuses it is the reader's budget, not the format.
        rows, chunk_rows = 1 << 20, 4096
        _replace(f, "/voxelmap/brick_values", (rows, 512), "<i2", (chunk_rows, 512), shuffle=True,
                 compression="gzip")
        packed = zlib.compress(bytes(chunk_rows * 512 * 2), 9)
        ds = f["/voxelmap/brick_values"]
        for start in range(0, rows, chunk_rows):
            ds.id.write_direct_chunk((start, 0), packed, filter_mask=0)
        f.create_dataset("/padding", data=np.random.default_rng(1).integers(0, 255, 4 << 20, dtype=np.uint8))

    add("deflate_bomb", ("OUT_OF_MEMORY",), 2, "1 GiB of deflated zeros in a ~5 MB file", post=deflate_bomb)

    # -- strings: bytes that are not text -------------------------------------------------------------------------
    add("format_not_utf8", ("STRING_NOT_UTF8",), 1, "/@format holds b'vox\\xffmt'",
        post=lambda f: _raw_string_attr(f, b"format", b"vox\xffmt"))
    add("generator_not_utf8", ("STRING_NOT_UTF8",), 1, "/provenance/@generator holds a lone continuation byte",
        post=lambda f: _raw_string_attr(f["/provenance"], b"generator", b"write_\x80sphere"))
    add("group_name_not_utf8", ("MISSING_OBJECT",), 1, "the group pointshell renamed b'point\\xffhell'",
        post=lambda f: f.id.move(b"pointshell", b"point\xffhell"))
    add("attribute_name_not_utf8", ("MISSING_OBJECT",), 1, "/provenance/@generator renamed b'gen\\xffrator'",
        post=lambda f: h5py.h5a.rename(f["/provenance"].id, b"generator", b"gen\xffrator"))

    # -- values that change a query's answer ------------------------------------------------------------------
    table = sf.encode_voxelmap(sf.FINE_GRID)["/voxelmap/bricks"]
    inside = np.argwhere(table == -2)
    table[tuple(inside[len(inside) // 2])] = -1
    add("coarse_sign_flipped", ("SIGN_MISMATCH",), 1, "a coarse brick inside marked outside",
        grid=sf.FINE_GRID, values={"/voxelmap/bricks": table})
    enc = sf.encode_voxelmap(sf.FINE_GRID)
    add("lattice_doubled", ("LATTICE_MISMATCH", "ESTIMATE_MISMATCH"), 1, "every lattice value doubled",
        grid=sf.FINE_GRID, values={"/voxelmap/lattice": enc["/voxelmap/lattice"] * np.float32(2)})
    huge = enc["/voxelmap/lattice"].copy()
    huge[4, 4, 4] = np.float32(3e38)
    add("lattice_3e38", ("VALUE_OUT_OF_RANGE",), 1, "one lattice value 3e38 m", grid=sf.FINE_GRID,
        values={"/voxelmap/lattice": huge})
    corner = enc["/voxelmap/lattice"].copy()
    corner[0, 0, 0] += np.float32(0.2)  # 20 voxels more, under coarse bricks only: no code depends on it
    add("lattice_point_raised", ("LATTICE_MISMATCH",), 1, "a lattice value under coarse bricks 20 voxels high",
        grid=sf.FINE_GRID, values={"/voxelmap/lattice": corner})
    codes = enc["/voxelmap/brick_values"].copy()
    codes[(codes % 2) == 0] = 0
    add("estimates_zero", ("ESTIMATE_MISMATCH",), 1, "every estimate code 0", grid=sf.FINE_GRID,
        values={"/voxelmap/brick_values": codes})
    add("estimates_interpolated_in_2_2", ("ESTIMATE_MISMATCH",), 1,
        "a 2.2 file holding 2.1's interpolated estimates, not settled ones (spec §3.1)", grid=sf.FINE_GRID,
        format_version=[2, 2], values={"/voxelmap/brick_values": enc["/voxelmap/brick_values"]})
    shared = enc["/voxelmap/bricks"].copy()
    rows = np.argwhere(shared >= 0)
    shared[tuple(rows[1])] = shared[tuple(rows[0])]
    add("row_shared", ("VALUE_OUT_OF_RANGE",), 1, "two bricks share a brick_values row", grid=sf.FINE_GRID,
        values={"/voxelmap/bricks": shared})

    # -- one file: nothing read from elsewhere --------------------------------------------------------------------
    def lattice_moved_out(f: h5py.File, name: str) -> h5py.ExternalLink:
        """The lattice moved into another file `name` beside the asset; the link to it there."""
        other = folder / name
        with h5py.File(other, "w") as o:
            o.create_dataset("lattice", data=f["/voxelmap/lattice"][()])
        del f["/voxelmap/lattice"]
        return h5py.ExternalLink(str(other), "/lattice")

    def lattice_elsewhere(f: h5py.File) -> None:
        f["/voxelmap/lattice"] = lattice_moved_out(f, "lattice_elsewhere.data.h5")

    add("external_link", ("READ_FAILED",), 1, "/voxelmap/lattice an external link to a dataset of another file",
        post=lattice_elsewhere)

    def lattice_elsewhere_through_a_soft_link(f: h5py.File) -> None:
        f["/elsewhere"] = lattice_moved_out(f, "soft_external.data.h5")
        f["/voxelmap/lattice"] = h5py.SoftLink("/elsewhere")

    add("soft_link_to_external", ("READ_FAILED",), 1, "/voxelmap/lattice a soft link to an external link",
        post=lattice_elsewhere_through_a_soft_link)

    def values_elsewhere(f: h5py.File) -> None:
        values = f["/voxelmap/brick_values"][()]
        raw = folder / "brick_values.raw"
        raw.write_bytes(values.astype("<i2").tobytes())
        del f["/voxelmap/brick_values"]
        f.create_dataset("/voxelmap/brick_values", shape=values.shape, dtype="<i2",
                         external=[(str(raw), 0, values.size * 2)])

    add("external_storage", ("READ_FAILED",), 1, "brick_values stored in a raw file beside the asset",
        post=values_elsewhere)

    def grid_moved(f: h5py.File) -> None:
        f["/voxelmap"].attrs["origin"] = f["/voxelmap"].attrs["origin"] + np.array([5.0, 0.0, 0.0])

    add("grid_moved", ("VALUE_OUT_OF_RANGE",), 1, "the voxelmap's origin moved 5 m off its object (spec §3)",
        post=grid_moved)

    def voxelmap_emptied(f: h5py.File) -> None:
        f["/voxelmap/bricks"][...] = -1  # every brick coarse, outside: no surface anywhere
        del f["/voxelmap/brick_values"]
        f["/voxelmap"].create_dataset("brick_values", shape=(0, 512), maxshape=(None, 512), dtype="<i2",
                                      chunks=(1, 512))

    add("voxelmap_emptied", ("POINT_OFF_SURFACE",), 1,
        "a 2.2 file whose bricks are all coarse: its points lie on no surface of its voxelmap (spec §4)",
        format_version=[2, 2], post=voxelmap_emptied)
    return cases


def string_flips(good: str | os.PathLike[str], folder: str | os.PathLike[str]) -> list[str]:
    """Copies of `good` with one byte of a name or a string value set to 0xFF (the damage a bad disk or a
    transfer does), one file per byte: every string the fixture's root and provenance hold."""
    data = Path(good).read_bytes()
    out = []
    for word in (b"voxfmt", b"right-handed", b"pointshell", b"provenance", b"generator", b"build_warnings"):
        at = data.find(word)
        if at < 0:
            continue
        for offset in range(len(word)):
            damaged = bytearray(data)
            damaged[at + offset] = 0xFF
            path = Path(folder) / f"flip_{word.decode()}_{offset}.vox.h5"
            path.write_bytes(bytes(damaged))
            out.append(str(path))
    return out


if __name__ == "__main__":  # seeds for the fuzzers (scripts/run-fuzzers.sh): python3 hostile_files.py FOLDER
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    write_cases(out)
    sf.write_fixture_h5py(str(out / "fine-2.0.vox.h5"), grid=sf.FINE_GRID)
    sf.write_legacy_fixture_h5py(str(out / "sphere-1.1.vox.h5"))
