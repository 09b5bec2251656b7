"""Read a mesh split written by `dynaserve sim mesh-d1` ... `mesh-d4` with numpy and safetensors.

    python3 crates/sim/python/read_mesh_split.py data/physi/d1/train [scene]

Prints the scene's objects and checks what the format promises: vertex ranges tile the
vertices, faces stay inside their object, rigid objects keep their edge lengths, and every
vertex stays in the box.
"""

import json
import sys

import numpy as np
from safetensors.numpy import load_file


def load_scene(split, index):
    """Scene `index` of a split: positions [V, T, 3], faces [F, 3] over the scene's vertices,
    per-object vertex ranges, material codes (0 rigid, 1 elastic) and the manifest."""
    manifest = json.load(open(f"{split}/manifest.json"))
    assert manifest["content"] == "mesh", "not a mesh dataset"
    shard_info = next(s for s in manifest["shards"]
                      if s["first_scene"] <= index < s["first_scene"] + s["scenes"])
    shard = load_file(f"{split}/{shard_info['file']}")
    s = index - shard_info["first_scene"]
    objects = shard["scene_object_offsets"]           # int64 [S+1]
    vo, fo = shard["vertex_offsets"], shard["face_offsets"]  # int64 [O+1]
    rows = range(objects[s], objects[s + 1])
    v0 = vo[objects[s]]
    positions = shard["vertex_positions"][v0:vo[objects[s + 1]]]  # float32 [V, T, 3]
    # faces are local to their object: shift them to the scene's vertex rows
    faces = np.concatenate([shard["faces"][fo[o]:fo[o + 1]] + (vo[o] - v0) for o in rows])
    ranges = [(int(vo[o] - v0), int(vo[o + 1] - v0)) for o in rows]
    material = shard["material"][objects[s]:objects[s + 1]]
    template = shard["template_id"][objects[s]:objects[s + 1]]
    return positions, faces, ranges, material, template, manifest


def main():
    split = sys.argv[1]
    index = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    x, faces, ranges, material, template, manifest = load_scene(split, index)
    names = [t["name"] for t in manifest["templates"]]
    print(f"{manifest['generator']} / {manifest['split']} scene {index}: "
          f"positions {x.shape} (V, T, 3), faces {faces.shape}, dt {manifest['dt_frame']:.4f} s")
    assert ranges[0][0] == 0 and ranges[-1][1] == x.shape[0]
    assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))
    for (a, b), m, t in zip(ranges, material, template):
        f = faces[(faces >= a).all(1) & (faces < b).all(1)]
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        length = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=-1)  # [E, T]
        change = np.abs(length / length[:, :1] - 1).max()
        print(f"  vertices {a:3d}..{b:3d} {names[t]:20s} {manifest['materials'][m]:7s} "
              f"max edge length change {change:.2e}")
        if m == 0:
            assert change < 1e-4, "a rigid object deforms"
    lo, hi = np.array(manifest["bounds"][0]), np.array(manifest["bounds"][1])
    outside = max((lo - x).max(), (x - hi).max(), 0.0)
    print(f"  largest distance outside the box: {outside:.4f} m")
    assert outside < 0.01


if __name__ == "__main__":
    main()
