"""voxfmt.newton: the asset's texture SDF read by Newton's own sampler against the runtime's field, a Newton scene
whose contacts come from the asset's SDF (an SDF moved outward moves the rest height by as much), the CPU finalize,
the version check and the refusals. CPU device; Newton's kernels are compiled once into WARP_CACHE_PATH."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import warp as wp

import voxfmt
import voxfmt.newton as vn
from conftest import MESHES

newton = vn.newton
from newton._src.geometry.sdf_texture import TextureSDFData, texture_sample_sdf  # noqa: E402  (Newton's sampler)


@wp.kernel
def _sample(sdf: TextureSDFData, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = texture_sample_sdf(sdf, points[i])


def test_newtons_sampler_reads_the_runtimes_field_within_one_quantum(assets: dict[str, Path]) -> None:
    body = voxfmt.load(assets["bunny"])
    layout = vn.texture_layout(body)
    sdf = vn.sdf(body, device="cpu")
    lo, hi = body.bounds
    points = np.random.default_rng(5).uniform(lo, hi, size=(50000, 3))
    out = wp.zeros(len(points), dtype=float, device="cpu")
    wp.launch(_sample, dim=len(points), inputs=[sdf.texture_data, wp.array(points.astype(np.float32), dtype=wp.vec3,
                                                                            device="cpu"), out], device="cpu")
    w, d = out.numpy(), body.signed_distance(points)
    h = body.voxel_size
    quantum = layout["value_range"] / 65535
    assert quantum < 1e-3 * h
    near = np.abs(d) < h
    assert near.sum() > 500
    assert np.abs(w[near] - d[near]).max() < quantum  # and float rounding of metres
    # Elsewhere the coarse grid stands in only where it is within the asset's estimate quantum, 1/16 voxel.
    assert np.abs(w - d).max() < h / 16 + quantum
    assert layout["value_bricks"] > 0 and layout["texels"].dtype == np.uint16


def offset(layout: dict, metres: float) -> dict:
    """The same field moved outward by `metres` (every value less by as much)."""
    moved = dict(layout)
    moved["coarse"] = layout["coarse"] - np.float32(metres)
    moved["value_min"] = layout["value_min"] - metres
    return moved


def rest_height(assets: dict[str, Path], shift: float) -> float:
    """Where the sphere asset comes to rest on the static cube asset (XPBD, 1 ms steps), both with their SDFs
    moved outward by `shift`."""
    builder = newton.ModelBuilder()
    cfg = newton.ModelBuilder.ShapeConfig(gap=0.01, margin=0.0, mu=1.0)
    for name, body in (("cube", -1), ("sphere", builder.add_body(xform=wp.transform((0, 0, 0.27), wp.quat_identity())))):
        asset = voxfmt.load(assets[name])
        vertices, triangles = voxfmt.read_mesh(MESHES / f"{name}.off", unit_scale=0.2 if name == "cube" else 0.1)
        data, _, _ = vn._texture_sdf_data(offset(vn.texture_layout(asset), shift), "uint16", wp.get_device("cpu"))
        mesh = newton.Mesh(vertices.astype(np.float32), triangles.reshape(-1),
                           sdf=newton.SDF.create_from_data(texture_data=data))
        builder.add_shape_mesh(body, mesh=mesh, cfg=cfg)
    model = vn.finalize(builder, "cpu")
    assert model._shape_sdf_index.numpy().tolist() == [0, 1]
    pipeline = newton.CollisionPipeline(model)
    contacts = pipeline.contacts()
    solver = newton.solvers.SolverXPBD(model, iterations=10)
    s0, s1, control = model.state(), model.state(), model.control()
    for _ in range(400):
        s0.clear_forces()
        pipeline.collide(s0, contacts)
        solver.step(s0, s1, control, contacts, 0.001)
        s0, s1 = s1, s0
    assert np.linalg.norm(s0.body_qd.numpy()[0][:3]) < 1e-3  # at rest
    return float(s0.body_q.numpy()[0][2])


def test_the_contacts_come_from_the_assets_sdf(assets: dict[str, Path]) -> None:
    plain = rest_height(assets, 0.0)
    assert plain == pytest.approx(0.2 + 0.05, abs=1e-3)  # the sphere (r 5 cm) on the cube's top (20 cm)
    moved = rest_height(assets, 0.005)
    assert moved - plain == pytest.approx(0.005, abs=5e-4)


def test_add_shape_reads_the_mesh_as_the_bake_did(assets: dict[str, Path]) -> None:
    builder = newton.ModelBuilder()
    shape = vn.add_shape(builder, -1, assets["sphere"], MESHES / "sphere.off")  # unit_scale 0.1 from the asset
    mesh = builder.shape_source[shape]
    assert np.abs(mesh.vertices).max() == pytest.approx(0.05, rel=1e-6)
    assert mesh.sdf is not None and mesh.sdf.texture_data is not None
    body = voxfmt.load(assets["sphere"])
    vertices, triangles = voxfmt.read_mesh(MESHES / "sphere.off", unit_scale=0.1)
    assert len(vn.mesh(body, (vertices, triangles)).vertices) == len(vertices)
    with pytest.raises(voxfmt.OptionError):
        vn.mesh(body, 3.0)
    with pytest.raises(voxfmt.OptionError):
        vn.texture_layout(body, texture_format="half")
    # Arrays that a reshape or a cast would make into another mesh, and tolerances that would store no brick.
    flat = vertices.reshape(-1, 2) if vertices.size % 2 == 0 else vertices[:, :2]
    for bad in ((flat, triangles), (vertices, triangles + 0.5), (vertices, triangles.astype(np.int64) + 2**32),
                (vertices, triangles.reshape(-1)[:-1]), (np.full_like(vertices, np.nan), triangles),
                (vertices.astype(np.float64) * 1e300, triangles),  # finite, but not in float32
                (vertices, triangles + len(vertices)), (vertices, -triangles - 1)):
        with pytest.raises(voxfmt.OptionError) as error:
            vn.mesh(body, bad)
        assert error.value.code == "BAD_OPTION"
    assert len(vn.mesh(body, (vertices, triangles.reshape(-1))).vertices) == len(vertices)  # Newton's flat layout
    for tolerance in (float("nan"), float("inf"), -1.0, "1", True, 10**400, np.complex128(1), np.timedelta64(1)):
        with pytest.raises(voxfmt.OptionError) as error:
            vn.texture_layout(body, coarse_tolerance=tolerance)
        assert error.value.code == "BAD_OPTION"
    assert vn.texture_layout(body, coarse_tolerance=np.float32(0.5))["coarse_stored"] >= 0
    for call in (lambda: vn.sdf(body, device="bogus"), lambda: vn.finalize(newton.ModelBuilder(), "cuda:97")):
        with pytest.raises(voxfmt.OptionError) as error:
            call()
        assert error.value.code == "BAD_OPTION"


def test_a_shapes_mass_properties_are_the_assets_or_the_given_meshs(tmp_path: Path) -> None:
    # An open box (its top missing): Newton's own integration of the triangles gives 6.67 and a centre of mass
    # 0.15 below the middle; the asset's solid is the closed box (8, in the middle).
    asset = tmp_path / "open.vox.h5"
    voxfmt.bake(MESHES / "cube-ouvert.off", asset, resolution=32, points=500)
    body = voxfmt.load(asset)
    shape_mesh = vn.mesh(body, MESHES / "cube-ouvert.off")
    assert shape_mesh.mass == pytest.approx(body.volume, rel=1e-6)
    assert np.allclose(np.array(shape_mesh.com), body.center_of_mass, atol=1e-6)
    assert np.allclose(np.array(shape_mesh.inertia).reshape(3, 3), body.inertia / body.density, rtol=1e-5, atol=1e-9)
    # A newton.Mesh of the user's is copied with what it holds (a shell with its hull's vertex limit stayed solid and
    # took another mass); only its SDF is the asset's.
    vertices, triangles = voxfmt.read_mesh(MESHES / "cube-ouvert.off", unit_scale=vn._unit_scale(body))
    given = newton.Mesh(vertices, triangles, is_solid=False, maxhullvert=12)
    copied = vn.mesh(body, given)
    assert (copied.is_solid, copied.maxhullvert, copied.mass) == (False, 12, given.mass)
    assert copied.sdf is not None and given.sdf is None
    with pytest.raises(voxfmt.OptionError):
        vn.texture_layout(body, texture_format=np.array(["uint16", "uint8"]))


def test_a_damaged_asset_is_refused_with_its_code(assets: dict[str, Path], tmp_path: Path) -> None:
    import h5py

    damaged = tmp_path / "damaged.vox.h5"
    damaged.write_bytes(assets["cube"].read_bytes())
    with h5py.File(damaged, "r+") as f:
        lattice = f["voxelmap/lattice"][()]
        lattice *= 3  # a lattice off by a factor
        f["voxelmap/lattice"][...] = lattice
    with pytest.raises(voxfmt.AssetError) as error:
        vn.sdf(damaged, device="cpu")
    assert error.value.code == "ESTIMATE_MISMATCH"  # the estimates no longer follow the lattice


def test_the_supported_versions_are_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(newton, "__version__", "9.9.9")
    with pytest.raises(ImportError, match=r"voxfmt\[newton\]"):
        vn._import_newton()
