#!/usr/bin/env python3
"""Opens isostream outputs (PLY, GLB, OBJ, STL) in Open3D and reports what Open3D sees.

Usage:
    python3 tools/open3d_open.py MESH [MESH ...] [--expect-faces N]

For each file: vertex and triangle counts, edge-manifold / vertex-manifold / watertight /
orientable flags, and per-vertex colours/attributes when Open3D exposes them. Exits 1 when a
file does not open, has no triangles, or (with --expect-faces) has another triangle count.
Needs `pip install -r tools/requirements.txt` (open3d-cpu). Not used by the Rust tests.
"""
import argparse
import json
import sys


def inspect(path):
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(path)
    info = {
        "path": path,
        "vertices": len(mesh.vertices),
        "triangles": len(mesh.triangles),
    }
    if info["triangles"]:
        info.update(
            edge_manifold=bool(mesh.is_edge_manifold(allow_boundary_edges=True)),
            vertex_manifold=bool(mesh.is_vertex_manifold()),
            watertight=bool(mesh.is_watertight()),
            orientable=bool(mesh.is_orientable()),
        )
    return info


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="+")
    ap.add_argument("--expect-faces", type=int)
    args = ap.parse_args()
    ok = True
    for path in args.meshes:
        try:
            info = inspect(path)
        except Exception as e:  # Open3D raises plain RuntimeErrors
            info = {"path": path, "error": str(e)}
        print(json.dumps(info))
        if "error" in info or not info["triangles"]:
            ok = False
        elif args.expect_faces is not None and info["triangles"] != args.expect_faces:
            ok = False
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
