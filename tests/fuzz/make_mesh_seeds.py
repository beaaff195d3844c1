#!/usr/bin/env python3
"""Seed corpora for the mesh fuzz targets: a tetrahedron and a cube in every format the bake distinguishes
(OFF, OBJ, PLY ascii and binary, STL ascii and binary, glTF with an embedded buffer), written to
<out>/<format>/. Small, so a fuzzer can mutate them quickly; each one bakes."""
import base64
import json
import os
import struct
import sys

TETRA = ([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)])
CUBE = ([(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)],
        [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 4), (1, 5, 4),
         (2, 6, 3), (3, 6, 7), (0, 4, 2), (2, 4, 6), (1, 3, 5), (3, 7, 5)])


def normal(v, t):
    a, b, c = (v[i] for i in t)
    u = [b[k] - a[k] for k in range(3)]
    w = [c[k] - a[k] for k in range(3)]
    return (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])


def off(v, t):
    return ("OFF\n%d %d 0\n" % (len(v), len(t)) + "".join("%g %g %g\n" % p for p in v)
            + "".join("3 %d %d %d\n" % f for f in t)).encode()


def obj(v, t):
    return ("# seed\no shape\n" + "".join("v %g %g %g\n" % p for p in v)
            + "".join("f %d %d %d\n" % tuple(i + 1 for i in f) for f in t)).encode()


def ply_ascii(v, t):
    head = ("ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
            "element face %d\nproperty list uchar int vertex_indices\nend_header\n" % (len(v), len(t)))
    return (head + "".join("%g %g %g\n" % p for p in v) + "".join("3 %d %d %d\n" % f for f in t)).encode()


def ply_binary(v, t):
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
            "property float z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n"
            % (len(v), len(t))).encode()
    return head + b"".join(struct.pack("<3f", *p) for p in v) + b"".join(struct.pack("<B3i", 3, *f) for f in t)


def stl_ascii(v, t):
    out = "solid seed\n"
    for f in t:
        out += " facet normal %g %g %g\n  outer loop\n" % normal(v, f)
        out += "".join("   vertex %g %g %g\n" % v[i] for i in f) + "  endloop\n endfacet\n"
    return (out + "endsolid seed\n").encode()


def stl_binary(v, t):
    body = b"".join(struct.pack("<12fH", *normal(v, f), *(c for i in f for c in v[i]), 0) for f in t)
    return b"seed".ljust(80, b" ") + struct.pack("<I", len(t)) + body


def gltf(v, t):
    positions = b"".join(struct.pack("<3f", *p) for p in v)
    indices = b"".join(struct.pack("<3H", *f) for f in t)
    buffer = positions + indices
    lo = [min(p[k] for p in v) for k in range(3)]
    hi = [max(p[k] for p in v) for k in range(3)]
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(buffer),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(positions)},
                        {"buffer": 0, "byteOffset": len(positions), "byteLength": len(indices)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(v), "type": "VEC3", "min": lo, "max": hi},
                      {"bufferView": 1, "componentType": 5123, "count": 3 * len(t), "type": "SCALAR"}],
    }
    return json.dumps(doc).encode()


WRITERS = {"off": [off], "obj": [obj], "ply": [ply_ascii, ply_binary], "stl": [stl_ascii, stl_binary],
           "gltf": [gltf]}

out = sys.argv[1]
for fmt, writers in WRITERS.items():
    os.makedirs(os.path.join(out, fmt), exist_ok=True)
    for name, (v, t) in (("tetra", TETRA), ("cube", CUBE)):
        for k, write in enumerate(writers):
            with open(os.path.join(out, fmt, "%s-%d.%s" % (name, k, fmt)), "wb") as f:
                f.write(write(v, t))
