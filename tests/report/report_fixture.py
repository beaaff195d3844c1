"""A small baked library for the report's tests: closed meshes, an open one (warnings), two that fail, one
asset damaged after its bake and a manifest line that is not a record; and a second bake of it at another
resolution for the comparison. Built with `voxfmt batch` at a low resolution (seconds)."""
import json
import os
import subprocess

VOXFMT = os.environ.get("VOXFMT_BIN")

TET = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n"
BOX = ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
       "f 1 4 3\nf 1 3 2\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n")
SHEET = "v 0 0 0\nv 1 0 0\nv 1 1 0.2\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"
MESHES = {
    "tet.obj": TET,
    "box.obj": BOX,
    "sheet.obj": SHEET,  # open: OPEN_BORDER and SHELL_MODE warnings
    "not_a_mesh.obj": "this is not a mesh\n",  # fails
    "points_only.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\n",  # fails: no triangles
    "damaged.obj": TET.replace("v 0 0 1", "v 0 0 2"),  # baked, then its asset is cut short
}
MESH_COUNT = len(MESHES) + 1  # and parts/tet.obj


def run(*args, check=True, cwd=None):
    p = subprocess.run([VOXFMT, *args], capture_output=True, text=True, cwd=cwd)
    if check and p.returncode not in (0, 1):  # batch exits 1 when a mesh failed
        raise AssertionError("voxfmt %s: exit %d\n%s%s" % (" ".join(args), p.returncode, p.stdout, p.stderr))
    return p


def manifest(library):
    records = {}
    with open(os.path.join(library, "manifest.jsonl")) as f:
        for line in f:
            try:
                r = json.loads(line)
            except (ValueError, RecursionError):  # torn, or nested too deep
                continue
            if isinstance(r, dict) and "output" in r:
                records[r["output"]] = r
    return list(records.values())


def make_library(root):
    """Returns (library, other_bake): two bakes of the same meshes."""
    meshes = os.path.join(root, "meshes")
    os.makedirs(meshes, exist_ok=True)
    for name, text in MESHES.items():
        with open(os.path.join(meshes, name), "w") as f:
            f.write(text)
    # The same file name in a subfolder: its own asset (parts/tet.obj.vox.h5), told apart everywhere.
    os.makedirs(os.path.join(meshes, "parts"), exist_ok=True)
    with open(os.path.join(meshes, "parts", "tet.obj"), "w") as f:
        f.write(BOX)
    library, other = os.path.join(root, "library"), os.path.join(root, "older")
    run("batch", meshes, "-o", library, "--resolution", "24", "--points", "600", "-j", "2", "-q")
    run("batch", meshes, "-o", other, "--resolution", "96", "--points", "600", "-j", "2", "-q")
    # Damage one asset after its bake: the manifest still says it was built.
    damaged = os.path.join(library, "damaged.obj.vox.h5")
    with open(damaged, "r+b") as f:
        f.truncate(os.path.getsize(damaged) // 3)
    with open(os.path.join(library, "manifest.jsonl"), "a") as f:
        f.write('{"torn line\n[1, 2, 3]\n')
        # A record whose keys try to make the page load a script and a picture from elsewhere.
        hostile = dict(manifest(library)[0])
        hostile.pop("output_from_manifest", None)  # written by hand: its "output" alone says where it is
        hostile.update(output=os.path.join(library, "hostile.vox.h5"), input="<img src=x onerror=alert(1)>.obj",
                       status="failed", detail="https://example.com/evil.js", views="https://example.com/x.png",
                       error={"code": "IMPORT_FAILED", "message": "<script>alert(1)</script>"})
        f.write(json.dumps(hostile) + "\n")
        # "__proto__" in a JavaScript object literal would set the row's prototype: inherited keys the page reads.
        proto = dict(hostile, output=os.path.join(library, "proto.vox.h5"), input="proto.obj")
        del proto["detail"], proto["views"]
        f.write(json.dumps(proto)[:-1] + ', "__proto__": {"detail": "https://example.com/evil.js", '
                '"views": "https://example.com/x.png", "slice": "file:///etc/passwd"}}\n')
        # Nested deeper than any record: skipped (copying or printing it would recurse 100,000 times).
        f.write('{"output": "deep", "x": ' + "[" * 100000 + "]" * 100000 + "}\n")
    return library, other


LONG_NAME = "long_" + "x" * 150 + ".obj"  # a file name wider than the card


def make_edge_library(root):
    """Returns (library, older): a flat sheet (baked as a shell), two failing meshes of one name in two
    subfolders, and a mesh with a long name; the older bake built a/x.obj, and its long-named asset is gone."""
    def write_meshes(folder, good_a):
        for sub in ("a", "b"):
            os.makedirs(os.path.join(folder, sub), exist_ok=True)
        files = {"flat.obj": "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n",  # SHELL_MODE
                 "a/x.obj": TET if good_a else "not a mesh\n", "b/x.obj": "not a mesh\n", LONG_NAME: TET}
        for name, text in files.items():
            with open(os.path.join(folder, name), "w") as f:
                f.write(text)
    write_meshes(os.path.join(root, "edge-meshes"), False)
    write_meshes(os.path.join(root, "edge-meshes-old"), True)
    library, older = os.path.join(root, "edge"), os.path.join(root, "edge-old")
    run("batch", os.path.join(root, "edge-meshes"), "-o", library, "--resolution", "16", "--points", "200", "-q")
    run("batch", os.path.join(root, "edge-meshes-old"), "-o", older, "--resolution", "16", "--points", "200", "-q")
    os.remove(os.path.join(older, LONG_NAME + ".vox.h5"))
    return library, older
