#!/usr/bin/env python3
"""Writes the hand-made glTF 2.0 test files (run from this folder; the output is committed).

transformed.gltf: two triangles with normals and uvs, one under a node with translation and
scale (metallic material "gold"), one under a parent node rotated 90 degrees about +z
(diffuse "paint" with an external base-colour texture and an emissive "glow" on a second
primitive). embedded.gltf: one triangle whose base-colour texture is a data: URI, which
Assimp turns into an embedded texture.
"""
import base64
import json
import struct

def buffer_uri(data):
    return "data:application/octet-stream;base64," + base64.b64encode(data).decode()

positions = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
normals = [(0, 0, 1)] * 3
uvs = [(0, 0), (1, 0), (0, 1)]
indices = [0, 1, 2]

blob = b"".join(struct.pack("<3f", *p) for p in positions)
blob += b"".join(struct.pack("<3f", *n) for n in normals)
blob += b"".join(struct.pack("<2f", *t) for t in uvs)
blob += struct.pack("<3H", *indices) + b"\0\0"

def views_and_accessors():
    views = [
        {"buffer": 0, "byteOffset": 0, "byteLength": 36},
        {"buffer": 0, "byteOffset": 36, "byteLength": 36},
        {"buffer": 0, "byteOffset": 72, "byteLength": 24},
        {"buffer": 0, "byteOffset": 96, "byteLength": 6},
    ]
    accessors = [
        {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
         "min": [0, 0, 0], "max": [1, 1, 0]},
        {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"},
        {"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC2"},
        {"bufferView": 3, "componentType": 5123, "count": 3, "type": "SCALAR"},
    ]
    return views, accessors

prim = lambda material: {"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                         "indices": 3, "material": material}

views, accessors = views_and_accessors()
transformed = {
    "asset": {"version": "2.0", "generator": "pbgi tests/data/meshes/make_gltf.py"},
    "scene": 0,
    "scenes": [{"nodes": [0, 1]}],
    "nodes": [
        {"name": "gold_node", "mesh": 0, "translation": [10, 20, 30], "scale": [2, 2, 2]},
        {"name": "turned", "rotation": [0, 0, 0.7071067811865476, 0.7071067811865476],
         "children": [2]},
        {"name": "painted_node", "mesh": 1},
    ],
    "meshes": [
        {"name": "gold_mesh", "primitives": [prim(0)]},
        {"name": "painted_mesh", "primitives": [prim(1), prim(2)]},
    ],
    "materials": [
        {"name": "gold", "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 0.75, 0.25, 1.0], "metallicFactor": 1.0,
            "roughnessFactor": 0.5}},
        {"name": "paint", "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0], "baseColorTexture": {"index": 0},
            "metallicFactor": 0.0, "roughnessFactor": 1.0}},
        {"name": "glow", "emissiveFactor": [1.0, 0.5, 0.25],
         "pbrMetallicRoughness": {"metallicFactor": 0.0}},
    ],
    "textures": [{"source": 0}],
    "images": [{"uri": "../textures/checker.png"}],
    "buffers": [{"byteLength": len(blob), "uri": buffer_uri(blob)}],
    "bufferViews": views,
    "accessors": accessors,
}

with open("../textures/checker.png", "rb") as f:
    png = f.read()
embedded = {
    "asset": {"version": "2.0", "generator": "pbgi tests/data/meshes/make_gltf.py"},
    "scene": 0,
    "scenes": [{"nodes": [0]}],
    "nodes": [{"name": "node", "mesh": 0}],
    "meshes": [{"name": "packed_mesh", "primitives": [prim(0)]}],
    "materials": [{"name": "packed", "pbrMetallicRoughness": {
        "baseColorFactor": [0.5, 0.5, 0.5, 1.0], "baseColorTexture": {"index": 0},
        "metallicFactor": 0.0}}],
    "textures": [{"source": 0}],
    "images": [{"uri": "data:image/png;base64," + base64.b64encode(png).decode()}],
    "buffers": [{"byteLength": len(blob), "uri": buffer_uri(blob)}],
    "bufferViews": views,
    "accessors": accessors,
}

for name, doc in (("transformed.gltf", transformed), ("embedded.gltf", embedded)):
    with open(name, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
