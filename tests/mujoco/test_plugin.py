"""The plugin voxfmt.sdf.asset inside MuJoCo: it loads once, at the pinned version; a baked sphere rests at its
radius; the bunny comes to rest on a box; one file is loaded once for every geom; every format version loads."""

from __future__ import annotations

import math
import re
import sys

import mujoco
import numpy as np
import pytest
from conftest import MESHES, REPO, SPHERE_RADIUS, SPHERE_VOXEL, UPRIGHT, speed

import voxfmt
import voxfmt.mujoco as vm

BOX = '<geom name="table" type="box" size="1 1 0.1" pos="0 0 -0.1"/>'


def scene(body: str = "", option: str = "") -> str:
    return f'<mujoco><option timestep="0.001" {option}/><worldbody>{BOX}{body}</worldbody></mujoco>'


def test_the_pin_is_one_version_everywhere() -> None:
    requirements = (REPO / "python/requirements-dev.txt").read_text()
    assert f"mujoco=={vm.MUJOCO_VERSION}" in requirements.split()
    assert mujoco.__version__ == vm.MUJOCO_VERSION
    built = vm._library.voxfmt_mujoco_built_version()  # type: ignore[union-attr]
    assert built == mujoco.mj_version()


def test_load_plugin_is_idempotent() -> None:
    first = vm.load_plugin()
    library = vm._library
    assert vm.load_plugin() == first
    assert vm._library is library
    mujoco.MjModel.from_xml_string(scene())  # MuJoCo itself is untouched


def test_another_mujoco_version_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mujoco, "__version__", "3.3.7")
    with pytest.raises(vm.MujocoVersionError) as raised:
        vm._mujoco()
    assert raised.value.code == "VERSION_UNSUPPORTED"
    assert "3.3.7" in str(raised.value) and vm.MUJOCO_VERSION in str(raised.value)


def test_sphere_rests_at_its_radius(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    # Against MuJoCo's own sphere of the same radius and mass on the same box: both sink into the box by the
    # solver's soft contact alike, so the difference is the field's.
    ball = vm.part(sphere_asset, "ball", pos=(0, 0, SPHERE_RADIUS + 0.03))
    model = mujoco.MjModel.from_xml_string(vm.insert(scene(), ball))
    inertial = re.search(r"<inertial[^>]*/>", ball.body).group(0)  # type: ignore[union-attr]
    reference = mujoco.MjModel.from_xml_string(
        scene(f'<body pos="0 0 {SPHERE_RADIUS + 0.03}"><freejoint/>{inertial}<geom type="sphere" size="{SPHERE_RADIUS}"/></body>')
    )
    heights = []
    for m in (model, reference):
        d = mujoco.MjData(m)
        for _ in range(1500):
            mujoco.mj_step(m, d)
        assert abs(d.qvel[2]) < 1e-3  # settled (it may roll: a ball on a flat box has nothing to stop that)
        heights.append(d.qpos[2])
    assert abs(heights[0] - heights[1]) < 0.5 * SPHERE_VOXEL, heights


def test_bunny_settles_on_a_box(bunny_asset) -> None:  # type: ignore[no-untyped-def]
    # The seed's bunny (1 m) dropped 0.2 m, MuJoCo's default sdf_initpoints and sdf_iterations. Within a second of
    # landing its centre of mass is below 5 mm/s and stays there, where MuJoCo's own convex hull rests it. (The
    # issue's 1 mm/s is not met reliably: MuJoCo's SDF contacts rock the body at 1-5 mm/s, its native SDF's too;
    # docs/mujoco.md.)
    body = voxfmt.load(bunny_asset)
    v = body.points @ np.array(mujoco_matrix(UPRIGHT)).T
    start = 0.2 - v[:, 2].min()
    bunny = vm.part(bunny_asset, "bunny", pos=(0, 0, start), quat=UPRIGHT)
    model = mujoco.MjModel.from_xml_string(vm.insert(scene(), bunny))
    hull_mesh = REPO / "build/cgal-data/data/meshes/bunny00.off"
    data = mujoco.MjData(model)
    landed, speeds, heights = None, [], []
    for step in range(2000):
        mujoco.mj_step(model, data)
        if landed is None and data.ncon:
            landed = step
        speeds.append(speed(model, data, 1))
        heights.append(data.xipos[1][2])
    assert landed is not None and 150 < landed < 250  # it fell 0.2 m: 0.2 s
    assert np.array(speeds[landed : landed + 100]).max() > 0.1  # it did land (and bounce) in the window
    settled = np.array(speeds[landed + 1000 :])
    assert settled.max() < 5e-3, settled.max()
    # Where the convex hull rests it: the bunny stands on its flat base, so the hull's support is the mesh's.
    import shapes

    vertices, faces = shapes.read_off(hull_mesh)
    hull_body = re.sub(r'<geom name="bunny"[^>]*>.*?</geom>', '<geom type="mesh" mesh="hull"/>', bunny.body)
    hull = mujoco.MjModel.from_xml_string(scene(hull_body).replace(
        "<worldbody>", f'<asset><mesh name="hull" vertex="{" ".join(map(str, vertices.ravel()))}" '
                       f'face="{" ".join(map(str, faces.ravel()))}"/></asset><worldbody>'))
    hull_data = mujoco.MjData(hull)
    for _ in range(2000):
        mujoco.mj_step(hull, hull_data)
    assert abs(np.array(heights[landed + 1000 :]).mean() - hull_data.xipos[1][2]) < 0.5 * body.voxel_size


def mujoco_matrix(quat: tuple[float, ...]) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(quat, dtype=float))
    return m.reshape(3, 3)


def test_one_file_is_loaded_once_for_every_geom(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    vm.load_plugin()
    parts = [vm.part(sphere_asset, f"ball{i}", pos=(0.3 * i, 0, 0.2)) for i in range(3)]
    before = vm.loaded_files()
    xml = vm.insert(scene(), *parts)
    assert xml.count("<mesh ") == 1 and xml.count("<instance ") == 1  # one mesh and instance for the file
    model = mujoco.MjModel.from_xml_string(xml)
    mujoco.MjModel.from_xml_string(xml)  # a second model of the same file: still loaded once
    assert model.ngeom == 4
    assert vm.loaded_files() - before <= 1  # 0 if an earlier test loaded it
    # Parts of that file inserted one call at a time: its instance and mesh still once (MuJoCo refuses a repeat).
    again = vm.insert(vm.insert(scene(), parts[0]), parts[1])
    assert again.count("<mesh ") == 1 and again.count("<instance ") == 1 and again.count("<extension>") == 1
    assert mujoco.MjModel.from_xml_string(again).ngeom == 3


def test_a_path_mjcf_cannot_name_is_a_coded_error(sphere_asset, tmp_path) -> None:  # type: ignore[no-untyped-def]
    import os
    import shutil

    odd = os.fsdecode(os.fsencode(str(tmp_path)) + b"/ball\xff.vox.h5")  # a name that is not UTF-8
    shutil.copy(sphere_asset, os.fsencode(odd))
    with pytest.raises(voxfmt.OptionError, match="not UTF-8"):
        vm.part(odd, "ball")


def test_part_carries_the_assets_mass_properties(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    ball = vm.part(sphere_asset, "ball", pos=(0, 0, 1), density=7800.0)
    model = mujoco.MjModel.from_xml_string(vm.insert(scene(), ball))
    body = voxfmt.load(sphere_asset, density=7800.0)
    assert model.body_mass[1] == pytest.approx(body.mass, rel=1e-9)
    assert model.body_mass[1] == pytest.approx(7800.0 * 4 / 3 * math.pi * SPHERE_RADIUS**3, rel=0.01)
    assert np.allclose(model.body_ipos[1], body.center_of_mass, atol=1e-9)
    assert np.allclose(np.sort(model.body_inertia[1]), np.sort(np.linalg.eigvalsh(body.inertia)), rtol=1e-6)


def test_geom_box_holds_the_object(sphere_asset, bunny_asset) -> None:  # type: ignore[no-untyped-def]
    # MuJoCo takes the geom's box and bounding sphere from the marching-cubes mesh, which cuts tips: the plugin
    # grows that mesh by half a cell, so the broad phase never skips a pair whose tips touch.
    for asset in (sphere_asset, bunny_asset):
        model = mujoco.MjModel.from_xml_string(vm.insert(scene(), vm.part(asset, "a", pos=(0, 0, 1))))
        body = voxfmt.load(asset)
        lo, hi = (np.asarray(b) for b in body.bounds)
        centre, half = model.geom_aabb[1][:3], model.geom_aabb[1][3:]
        assert (centre - half <= lo + 1e-9).all() and (centre + half >= hi - 1e-9).all(), (asset, centre, half, lo, hi)
        assert (centre - half >= lo - body.voxel_size).all() and (centre + half <= hi + body.voxel_size).all()
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        assert model.geom_rbound[1] >= np.linalg.norm(body.points, axis=1).max() - 1e-9
        assert model.geom_rbound[1] <= np.linalg.norm(corners, axis=1).max() + body.voxel_size


def test_static_part_and_geom_attributes(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    fixed = vm.part(sphere_asset, "fixed", static=True, geom={"friction": "0.3", "rgba": "1 0 0 1"})
    model = mujoco.MjModel.from_xml_string(vm.insert(scene(), fixed))
    assert model.nq == 0
    assert model.geom_friction[1][0] == pytest.approx(0.3)
    assert model.geom_type[1] == mujoco.mjtGeom.mjGEOM_SDF


def test_insert_needs_a_mujoco_document(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    ball = vm.part(sphere_asset, "ball")
    for not_mjcf in ("<worldbody/>", "<mujoco><worldbody></mujoco>", "<!-- <mujoco> --><x></x>"):
        with pytest.raises(voxfmt.OptionError, match="mjcf"):
            vm.insert(not_mjcf, ball)


def test_insert_reads_the_document_as_xml(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    # Tags inside comments, sections written as empty elements, the plugin declared by the author with an
    # instance of their own: the parts go where MuJoCo reads them, and nothing the author wrote is repeated.
    ball = vm.part(sphere_asset, "ball", pos=(0, 0, 0.2))
    author = ball.extension.replace(f'name="{ball.instance}"', 'name="mine"')
    document = (
        '<?xml version="1.0"?><mujoco model="m"><!-- </worldbody> <asset> </mujoco> -->'
        f'<extension><plugin plugin="{vm.PLUGIN_NAME}">{author}</plugin></extension>'
        f'<option timestep="0.001"/><asset/><worldbody/><worldbody>{BOX}</worldbody></mujoco>'
    )
    xml = vm.insert(document, ball)
    assert "<!-- </worldbody> <asset> </mujoco> -->" in xml  # the author's comment is kept
    assert xml.count("<extension>") == 1 and xml.count(f'plugin="{vm.PLUGIN_NAME}"') == 1
    model = mujoco.MjModel.from_xml_string(xml)
    assert model.ngeom == 2 and model.nbody == 2
    assert vm.insert(xml, ball).count("<mesh ") == 1  # the part's mesh and instance once, its body again


def test_part_refuses_what_mjcf_cannot_hold(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    for bad in (
        {"pos": (0, math.nan, 0)},
        {"pos": (0, 0)},
        {"quat": (1, 0, 0)},
        {"quat": (0, 0, 0, 0)},
        {"geom": {'friction="1" name': "x"}},  # a key that would write an attribute of its own
        {"geom": {"name": "other"}},  # set by part() itself
        {"geom": {"rgba": "1 0 0\x01"}},
    ):
        with pytest.raises(voxfmt.OptionError):
            vm.part(sphere_asset, "ball", **bad)  # type: ignore[arg-type]
    with pytest.raises(voxfmt.OptionError, match="name"):
        vm.part(sphere_asset, "ball\x00")
    # Quotes, markup and a line break in a name reach MuJoCo as written.
    odd = 'a "b" <c> & d\ne'
    model = mujoco.MjModel.from_xml_string(vm.insert(scene(), vm.part(sphere_asset, odd, pos=(0, 0, 0.2))))
    assert model.body(1).name == odd


def test_evaluate_is_the_runtimes_field(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    body = voxfmt.load(sphere_asset)
    rng = np.random.default_rng(5)
    points = rng.normal(size=(2000, 3))
    points = points / np.linalg.norm(points, axis=1, keepdims=True) * (SPHERE_RADIUS + rng.normal(0, SPHERE_VOXEL, (2000, 1)))
    distances, gradients = vm.evaluate(sphere_asset, points, gradients=True)
    assert np.allclose(distances, body.signed_distance(points), atol=1e-6 * SPHERE_RADIUS)
    assert np.allclose(np.linalg.norm(gradients, axis=1), 1.0, atol=1e-6)
    radial = points / np.linalg.norm(points, axis=1, keepdims=True)
    band = np.abs(distances) < 1.5 * SPHERE_VOXEL  # where the 8 voxels around store distances
    assert (np.einsum("ij,ij->i", radial, gradients)[band] > 0.99).all()
    with pytest.raises(voxfmt.OptionError):
        vm.evaluate(sphere_asset, np.zeros((3, 2)))


def test_a_nan_point_is_nowhere(sphere_asset) -> None:  # type: ignore[no-untyped-def]
    # A NaN point indexed the brick table far out of bounds (a segfault), from Python and from inside mj_step,
    # whose own check of NaN covers qpos and qvel, not a mocap body's position.
    points = np.array([[np.nan, 0, 0], [0, 0, np.nan], [np.inf, 0, 0], [-np.inf, 0, 0], [0, 0, SPHERE_RADIUS]])
    distances, gradients = vm.evaluate(sphere_asset, points, gradients=True)
    assert np.isposinf(distances[:4]).all() and abs(distances[4]) < SPHERE_VOXEL
    assert np.allclose(np.linalg.norm(gradients, axis=1), 1.0)
    # Weightless, far above the table: the two balls touch only each other, so any call is at the NaN pose.
    ball = vm.part(sphere_asset, "ball", pos=(0, 0, 1.0))
    held = vm.part(sphere_asset, "held", pos=(0, 0, 1.0 + 1.9 * SPHERE_RADIUS), static=True)
    held_body = held.body.replace('<body name="held"', '<body name="held" mocap="true"', 1)
    xml = vm.insert(scene(option='gravity="0 0 0"'), ball).replace("</worldbody>", held_body + "</worldbody>")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_step(model, data)
    assert data.ncon > 0  # they touch
    data.mocap_pos[0] = np.nan
    vm.lookup_profile(restart=True)
    mujoco.mj_step(model, data)  # MuJoCo's business from here; the plugin must only not crash
    assert vm.lookup_profile(restart=False)["distance_calls"] > 0  # the plugin was asked at NaN points


def test_a_failed_load_holds_no_place_and_a_mended_file_loads(tmp_path, sphere_asset) -> None:  # type: ignore[no-untyped-def]
    # Every failed load held one of the cache's 4,095 places for good: 4,096 mistyped paths and then no file
    # loaded at all, with OUT_OF_MEMORY.
    import shutil

    vm.load_plugin()
    before = vm.loaded_files()
    missing = tmp_path / "later.vox.h5"
    for i in range(200):
        with pytest.raises(voxfmt.AssetError, match="FILE_NOT_FOUND"):
            vm.field_bytes(tmp_path / f"typo{i}.vox.h5")
    with pytest.raises(voxfmt.AssetError, match="FILE_NOT_FOUND"):
        vm.evaluate(missing, np.zeros((1, 3)))
    assert vm.loaded_files() == before
    shutil.copyfile(sphere_asset, missing)  # the file appears: it loads now
    assert vm.field_bytes(missing) > 0
    assert vm.loaded_files() == before + 1


@pytest.mark.parametrize("version", ["1.0", "1.1", "2.0"])
def test_every_format_version_loads(tmp_path, version: str) -> None:  # type: ignore[no-untyped-def]
    sys.path.insert(0, str(REPO / "tests" / "spec"))
    import spec_fixture

    path = str(tmp_path / f"sphere-{version}.vox.h5")
    major, minor = (int(x) for x in version.split("."))
    spec_fixture.write_fixture_h5py(
        path, legacy=version != "2.0", grid=spec_fixture.FINE_GRID, format_version=[major, minor]
    )
    part = vm.part(path, "ball", pos=(0, 0, 0.5))
    model = mujoco.MjModel.from_xml_string(vm.insert(scene(), part))
    assert model.ngeom == 2
    centre = np.array(spec_fixture.CENTER)
    rng = np.random.default_rng(6)
    directions = rng.normal(size=(500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = centre + directions * (spec_fixture.RADIUS + 0.005)
    assert np.abs(vm.evaluate(path, points) - 0.005).max() < 0.1 * spec_fixture.FINE_GRID.voxel_size


def test_a_thread_pool_steps_as_one_thread_does(bunny_asset) -> None:  # type: ignore[no-untyped-def]
    # With a thread pool MuJoCo runs one mjData's collision pairs on several threads at once; the plugin's kept
    # evaluations were per mjData, so threads read each other's points: every threaded run differed from step 0.
    parts = [vm.part(bunny_asset, f"b{i}", pos=(1.6 * (i % 3), 1.6 * (i // 3), 0.3), quat=UPRIGHT) for i in range(6)]
    big_box = '<geom type="box" size="20 20 0.1" pos="0 0 -0.1"/>'
    model = mujoco.MjModel.from_xml_string(vm.insert(scene().replace(BOX, big_box), *parts))

    def run(threads: int) -> list[np.ndarray]:
        data = mujoco.MjData(model)
        if threads:
            mujoco.mju_threadpool(data, threads)
        states = []
        for _ in range(400):
            mujoco.mj_step(model, data)
            states.append(np.concatenate([[data.ncon], data.qpos]))
        return states

    serial = run(0)
    assert serial[-1][0] > 0  # they landed
    for _ in range(2):
        threaded = run(4)
        first = next((i for i, (a, b) in enumerate(zip(serial, threaded)) if not np.array_equal(a, b)), None)
        assert first is None, f"the threaded run differs from step {first}"


def test_an_mjdata_outlives_its_file(tmp_path, sphere_asset) -> None:  # type: ignore[no-untyped-def]
    # A model compiled from a file in a temporary folder: once the folder is cleaned up, new mjData (resets,
    # rollouts, copies) use the version the process loaded, as the compiled model does.
    import copy
    import shutil

    asset = tmp_path / "ball.vox.h5"
    shutil.copyfile(sphere_asset, asset)
    xml = vm.insert(scene(), vm.part(asset, "ball", pos=(0, 0, 0.15)))
    model = mujoco.MjModel.from_xml_string(xml)
    before = mujoco.MjData(model)
    asset.unlink()
    again = mujoco.MjModel.from_xml_string(xml)  # compiled again: the same version, mesh and field
    runs = [(model, mujoco.MjData(model)), (model, mujoco.MjData(copy.copy(model))), (model, copy.copy(before)),
            (again, mujoco.MjData(again))]
    for m, data in [(model, before), *runs]:
        for _ in range(200):
            mujoco.mj_step(m, data)
    for _, data in runs:
        assert np.array_equal(data.qpos, before.qpos)
    assert before.ncon > 0
    # A name this process never loaded is still an error.
    with pytest.raises(ValueError, match="FILE_NOT_FOUND"):
        mujoco.MjModel.from_xml_string(xml.replace("ball.vox.h5", "never.vox.h5"))


def test_memory_the_field_cannot_get_is_out_of_memory(tmp_path) -> None:  # type: ignore[no-untyped-def]
    # The plugin builds its field in the caller's process: an allocation that fails there crashed the interpreter
    # (an exception unwinding through MuJoCo's C frames). Under address-space limits from a few MiB to beyond the
    # field's size, every outcome is a field or a coded error.
    import subprocess

    mesh = MESHES / "bunny00.off"
    if not mesh.exists():
        pytest.skip(f"{mesh}: CGAL's sample meshes are not unpacked")
    asset = tmp_path / "bunny.vox.h5"
    voxfmt.bake(mesh, asset, resolution=200, points=2000)
    child = (
        "import resource, sys\n"
        "import numpy as np\n"
        "import voxfmt, voxfmt.mujoco as vm\n"
        "vm.load_plugin()\n"
        "size = int([l for l in open('/proc/self/status') if l.startswith('VmSize')][0].split()[1]) * 1024\n"
        "limit = size + int(sys.argv[2]) * 2**20\n"
        "resource.setrlimit(resource.RLIMIT_AS, (limit, limit))\n"
        "try:\n"
        "    vm.evaluate(sys.argv[1], np.zeros((1, 3)))\n"
        "    print('OK')\n"
        "except voxfmt.Error as e:\n"
        "    print(e.code)\n"
        "except MemoryError:\n"
        "    print('MemoryError')\n"
    )
    outcomes = []
    for extra_mib in range(4, 20, 2):
        run = subprocess.run([sys.executable, "-c", child, str(asset), str(extra_mib)], capture_output=True,
                             text=True, timeout=120)
        assert run.returncode == 0, (extra_mib, run.returncode, run.stderr[-2000:])
        outcomes.append(run.stdout.strip())
    assert set(outcomes) <= {"OK", "OUT_OF_MEMORY", "MemoryError"}, outcomes
    assert "OUT_OF_MEMORY" in outcomes and outcomes[-1] == "OK", outcomes


def test_a_pickled_mjdata_steps_as_the_original(tmp_path, sphere_asset) -> None:  # type: ignore[no-untyped-def]
    # Pickling an mjData copies plugin_data as bytes, and the plugin kept a heap pointer there: unpickled in
    # another process, the first step crashed (rc 139); in the same one, both mjData freed it (rc 134 at exit).
    # Each side runs in a child interpreter, which must step the copy as the original steps and exit normally.
    import json
    import pickle
    import subprocess

    xml = vm.insert(scene(), vm.part(sphere_asset, "ball", pos=(0, 0, 0.15)))
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    for _ in range(100):
        mujoco.mj_step(model, data)
    (tmp_path / "data.pkl").write_bytes(pickle.dumps(data))
    (tmp_path / "scene.xml").write_text(xml)
    for _ in range(300):
        mujoco.mj_step(model, data)
    assert data.ncon > 0
    child = (
        "import json, pickle, sys\n"
        "import mujoco, numpy as np, voxfmt.mujoco as vm\n"
        "vm.load_plugin()\n"
        "if sys.argv[2] == 'other':\n"
        "    copies = [pickle.loads(open(sys.argv[1] + '/data.pkl', 'rb').read())]\n"
        "else:  # the original made here, and its copy\n"
        "    m = mujoco.MjModel.from_xml_string(open(sys.argv[1] + '/scene.xml').read())\n"
        "    copies = [mujoco.MjData(m)]\n"
        "    for _ in range(100):\n"
        "        mujoco.mj_step(m, copies[0])\n"
        "    copies.append(pickle.loads(pickle.dumps(copies[0])))\n"
        "for d in copies:\n"
        "    for _ in range(300):\n"
        "        mujoco.mj_step(d.model, d)\n"
        "print(json.dumps(np.concatenate([[c.ncon] for c in copies] + [c.qpos for c in copies]).tolist()))\n"
        "del copies, d\n"
        "import gc; gc.collect()\n"
    )
    for mode, count in [("same", 2), ("other", 1)]:
        run = subprocess.run([sys.executable, "-c", child, str(tmp_path), mode], capture_output=True,
                             text=True, timeout=120)
        assert run.returncode == 0, (mode, run.returncode, run.stderr[-2000:])
        values = json.loads(run.stdout.strip().splitlines()[-1])
        expected = [float(data.ncon)] * count + list(data.qpos) * count
        assert values == expected, (mode, values, expected)
