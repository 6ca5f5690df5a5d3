#!/usr/bin/env python3
"""Writes the hand-made glTF 2.0 test files (run from this folder; the output is committed).

transformed.gltf: two triangles with normals and uvs, one under a node with translation and
scale (metallic material "gold"), one under a parent node rotated 90 degrees about +z
(diffuse "paint" with an external base-colour texture and an emissive "glow" on a second
primitive). embedded.gltf: one triangle whose base-colour texture is a data: URI, which
Assimp turns into an embedded texture. embedded.glb: the same as binary glTF, the texture in
a buffer view. unmappable.gltf: a material ("glass") with parts the loader cannot map:
transmission, a normal map, alpha blending, and a metallicFactor between 0 and 1.
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

views, accessors = views_and_accessors()
unmappable = {
    "asset": {"version": "2.0", "generator": "pbgi tests/data/meshes/make_gltf.py"},
    "extensionsUsed": ["KHR_materials_transmission"],
    "scene": 0,
    "scenes": [{"nodes": [0]}],
    "nodes": [{"name": "node", "mesh": 0}],
    "meshes": [{"name": "glass_mesh", "primitives": [prim(0)]}],
    "materials": [{
        "name": "glass",
        "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.9, 0.9, 0.5],
                                 "metallicFactor": 0.3, "roughnessFactor": 0.1},
        "normalTexture": {"index": 0},
        "alphaMode": "BLEND",
        "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0}},
    }],
    "textures": [{"source": 0}],
    "images": [{"uri": "../textures/checker.png"}],
    "buffers": [{"byteLength": len(blob), "uri": buffer_uri(blob)}],
    "bufferViews": views,
    "accessors": accessors,
}

for name, doc in (("transformed.gltf", transformed), ("embedded.gltf", embedded),
                  ("unmappable.gltf", unmappable)):
    with open(name, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")

# Binary glTF: the geometry, then the PNG (4-byte aligned), in the one BIN chunk.
padded_blob = blob + b"\0" * (-len(blob) % 4)
bin_chunk = padded_blob + png + b"\0" * (-len(png) % 4)
glb_views, glb_accessors = views_and_accessors()
glb_views.append({"buffer": 0, "byteOffset": len(padded_blob), "byteLength": len(png)})
glb = dict(embedded)
glb["materials"] = [dict(embedded["materials"][0], name="packed_glb")]
glb["images"] = [{"bufferView": len(glb_views) - 1, "mimeType": "image/png"}]
glb["buffers"] = [{"byteLength": len(bin_chunk)}]
glb["bufferViews"] = glb_views
glb["accessors"] = glb_accessors
json_chunk = json.dumps(glb).encode()
json_chunk += b" " * (-len(json_chunk) % 4)
body = (struct.pack("<II", len(json_chunk), 0x4E4F534A) + json_chunk +
        struct.pack("<II", len(bin_chunk), 0x004E4942) + bin_chunk)
with open("embedded.glb", "wb") as f:
    f.write(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
