#!/usr/bin/env python3
"""Opens isostream outputs (PLY, GLB, OBJ, STL) in Open3D and reports what Open3D sees.

Usage:
    python3 tools/open3d_open.py MESH [MESH ...] [--expect-faces N]

For each file, one JSON line: vertex and triangle counts, whether Open3D read per-vertex normals
and colours, and edge-manifold / vertex-manifold / watertight / orientable flags. Open3D's mesh
reader reads no other per-vertex values, so the `[[attributes]]` isostream writes do not show.
Exits 1 when a file does not open, has no triangles, or (with --expect-faces) has another
triangle count; the line's "error" says which. Open3D does not read SMB or SMA: convert them
first (`isostream convert X.smb X.ply`). Needs `pip install -r tools/requirements.txt`
(open3d-cpu). Checked by tests/tools.rs where Open3D is installed.
"""
import argparse
import json
import os
import sys

# isostream's own streaming formats, which no other tool reads.
STREAMING = (".smb", ".sma")


def inspect(path):
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(path)
    info = {
        "path": path,
        "vertices": len(mesh.vertices),
        "triangles": len(mesh.triangles),
        "vertex_normals": bool(mesh.has_vertex_normals()),
        "vertex_colors": bool(mesh.has_vertex_colors()),
    }
    if info["triangles"]:
        info.update(
            edge_manifold=bool(mesh.is_edge_manifold(allow_boundary_edges=True)),
            vertex_manifold=bool(mesh.is_vertex_manifold()),
            watertight=bool(mesh.is_watertight()),
            orientable=bool(mesh.is_orientable()),
        )
    return info


def check(path, expect_faces):
    """What Open3D sees of `path`, with an "error" when the file fails."""
    stem, ext = os.path.splitext(path)
    if ext.lower() in STREAMING:
        # Open3D only warns "unknown file extension" and reads 0 vertices.
        return {
            "path": path,
            "error": f"Open3D does not read {ext[1:].upper()}: convert it first "
            f"(isostream convert {path} {stem}.ply)",
        }
    try:
        info = inspect(path)
    except Exception as e:  # Open3D raises plain RuntimeErrors
        return {"path": path, "error": str(e)}
    if not info["triangles"]:
        info["error"] = "no triangles read"
    elif expect_faces is not None and info["triangles"] != expect_faces:
        info["error"] = f"{info['triangles']} triangles, --expect-faces {expect_faces}"
    return info


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="+")
    ap.add_argument("--expect-faces", type=int)
    args = ap.parse_args()
    results = [check(path, args.expect_faces) for path in args.meshes]
    for info in results:
        print(json.dumps(info))
    sys.exit(1 if any("error" in info for info in results) else 0)


if __name__ == "__main__":
    main()
