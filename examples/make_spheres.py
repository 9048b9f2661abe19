#!/usr/bin/env python3
"""Writes spheres.glb: 256 UV spheres on a floor under a directional light.

    python3 examples/make_spheres.py [OUT.glb]      (default: examples/spheres.glb)

A Sponza-sized load for the tracer and the atlas (245,764 triangles) that a
script can make, so the repository holds the script, not the 6.4 MB file
(examples/SOURCES.md). The file is the same, byte for byte, on every run
(tests/test_scene_loader.cpp checks its size and triangles; scripts/common.sh
makes it at set-up):

  * an 18 x 18 m floor at y = 0 (normal up) and a 3 x 3 m panel at y = 4
    over one corner (normal down), two triangles each;
  * 16 x 16 spheres on a 1 m grid (x, z from -7.5 to 7.5, x fastest), each
    of radius uniform(0.15, 0.4) lifted by uniform(0, 0.3) above the floor
    (Python's random.Random(7), radius then lift per sphere); 16 stacks and
    32 slices, the seam's column doubled (17 x 33 vertices), the poles'
    degenerate triangles left out (960 triangles a sphere), normals
    exact;
  * one grey Lambertian material (base colour 0.7, metallic 0, roughness 1);
  * a KHR_lights_punctual directional light, colour (1, 0.95, 0.9),
    intensity 3, its node turned 45 degrees down and 45 degrees about y.
"""
import json
import math
import os
import random
import struct
import sys

STACKS, SLICES = 16, 32
GRID, SPACING = 16, 1.0


def sphere(centre, radius):
    """Positions and normals of one UV sphere, ring by ring from the top."""
    positions, normals = [], []
    for i in range(STACKS + 1):
        theta = math.pi * i / STACKS
        for j in range(SLICES + 1):
            phi = 2.0 * math.pi * j / SLICES
            n = (math.sin(theta) * math.cos(phi), math.cos(theta), math.sin(theta) * math.sin(phi))
            normals.append(n)
            positions.append(tuple(c + radius * d for c, d in zip(centre, n)))
    return positions, normals


def sphere_triangles(first):
    """Its triangles, quad by quad, the poles' degenerate halves left out."""
    row = SLICES + 1
    triangles = []
    for i in range(STACKS):
        for j in range(SLICES):
            a = first + i * row + j
            b = a + row
            if i != 0:
                triangles.append((a, a + 1, b))
            if i != STACKS - 1:
                triangles.append((a + 1, b + 1, b))
    return triangles


def quad(corners, normal, first):
    return list(corners), [normal] * 4, [(first, first + 1, first + 2), (first, first + 2, first + 3)]


def scene():
    rng = random.Random(7)
    positions, normals, triangles = [], [], []
    for k in range(GRID * GRID):
        x = (k % GRID - (GRID - 1) / 2) * SPACING
        z = (k // GRID - (GRID - 1) / 2) * SPACING
        radius = rng.uniform(0.15, 0.4)
        lift = rng.uniform(0.0, 0.3)
        p, n = sphere((x, radius + lift, z), radius)
        triangles += sphere_triangles(len(positions))
        positions += p
        normals += n
    for corners, normal in (
        (((-9, 0, -9), (-9, 0, 9), (9, 0, 9), (9, 0, -9)), (0, 1, 0)),  # the floor, facing up
        (((-9, 4, -9), (-6, 4, -9), (-6, 4, -6), (-9, 4, -6)), (0, -1, 0)),  # a panel over one corner, facing down
    ):
        p, n, t = quad(corners, normal, len(positions))
        positions += p
        normals += n
        triangles += t
    return positions, normals, triangles


def glb(positions, normals, triangles):
    pack = lambda fmt, rows: b"".join(struct.pack(fmt, *r) for r in rows)
    position_bytes, normal_bytes, index_bytes = pack("<3f", positions), pack("<3f", normals), pack("<3I", triangles)
    views, offset = [], 0
    for data, target in ((position_bytes, 34962), (normal_bytes, 34962), (index_bytes, 34963)):
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data), "target": target})
        offset += len(data)
    binary = position_bytes + normal_bytes + index_bytes
    lo = [min(p[a] for p in positions) for a in range(3)]
    hi = [max(p[a] for p in positions) for a in range(3)]
    # The same float32 values the buffer holds.
    lo, hi = (list(struct.unpack("<3f", struct.pack("<3f", *v))) for v in (lo, hi))
    gltf = {
        "asset": {"version": "2.0", "generator": "lightfarm-steering make_scenes.py"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "directional", "color": [1, 0.95, 0.9], "intensity": 3.0}]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"mesh": 0},
            {"rotation": [-0.3535534, 0.3535534, 0.1464466, 0.8535534], "extensions": {"KHR_lights_punctual": {"light": 0}}},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.7, 0.7, 1], "metallicFactor": 0, "roughnessFactor": 1}}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3", "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5126, "count": len(normals), "type": "VEC3"},
            {"bufferView": 2, "componentType": 5125, "count": 3 * len(triangles), "type": "SCALAR"},
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": len(binary)}],
    }
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)), "spheres.glb")
    data = glb(*scene())
    part = out + ".part"
    with open(part, "wb") as f:
        f.write(data)
    os.replace(part, out)


if __name__ == "__main__":
    main()
