#!/usr/bin/env python3
"""Render a PNG of an isostream output mesh with Open3D, offscreen (no display needed).

    python3 tools/render.py OUT.smb [-o OUT.png] [--size 1024x768] [--view iso|x|y|z]
                            [--bin target/release/isostream]

Any output format works: SMB and SMA are converted to a temporary PLY with `isostream convert`
first (Open3D cannot read streaming meshes); PLY, OBJ, STL and GLB are read directly.

Needs (see tools/README.md): `pip install -r tools/requirements.txt` (open3d-cpu) and, on
Debian/Ubuntu, `apt-get install libusb-1.0-0 libvulkan1 mesa-vulkan-drivers libegl1`: Open3D
0.20's offscreen renderer (Filament) loads the Vulkan loader and runs on Mesa's CPU driver
(lavapipe) when there is no GPU; without libvulkan1 it fails with "Failed to load vulkan
library!".
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

DIRECTIONS = {
    "iso": (1.0, -1.2, 0.8),
    "x": (1.0, 0.0, 0.0),
    "y": (0.0, -1.0, 0.0),
    "z": (0.0, 0.0, 1.0),
}


def fail(message):
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


def isostream_binary(given):
    for candidate in [given, "target/release/isostream", "target/debug/isostream"]:
        if candidate and os.path.isfile(candidate):
            return candidate
    found = shutil.which("isostream")
    if not found:
        fail("no isostream binary to convert SMB/SMA: build it (cargo build --release) or pass --bin")
    return found


def readable_mesh(path, binary, tmp):
    """A path Open3D can read: the mesh itself, or a PLY converted from a streaming mesh."""
    if path.lower().endswith((".smb", ".sma")):
        ply = os.path.join(tmp, "mesh.ply")
        done = subprocess.run([isostream_binary(binary), "convert", path, ply],
                              capture_output=True, text=True)
        if done.returncode != 0:
            fail(done.stderr.strip().removeprefix("error: "))
        return ply
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("-o", "--output", help="PNG to write (default: MESH with .png)")
    ap.add_argument("--size", default="1024x768", help="WIDTHxHEIGHT in pixels")
    ap.add_argument("--view", choices=sorted(DIRECTIONS), default="iso",
                    help="direction the camera looks from")
    ap.add_argument("--bin", help="the isostream binary (for SMB/SMA inputs)")
    args = ap.parse_args()
    if not os.path.isfile(args.mesh):
        fail(f"{args.mesh}: no such file")
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        fail(f"--size {args.size}: expected WIDTHxHEIGHT, e.g. 1024x768")
    output = args.output or os.path.splitext(args.mesh)[0] + ".png"

    try:
        import numpy as np
        import open3d as o3d
    except ImportError as e:
        fail(f"{e}: pip install -r tools/requirements.txt (and apt-get install libusb-1.0-0)")

    with tempfile.TemporaryDirectory() as tmp:
        mesh = o3d.io.read_triangle_mesh(readable_mesh(args.mesh, args.bin, tmp))
    if len(mesh.triangles) == 0:
        fail(f"{args.mesh}: no triangles read")
    mesh.compute_vertex_normals()
    mesh.paint_uniform_color((0.62, 0.70, 0.80))

    try:
        renderer = o3d.visualization.rendering.OffscreenRenderer(width, height)
    except RuntimeError as e:
        fail(f"Open3D offscreen rendering: {e}: apt-get install libvulkan1 mesa-vulkan-drivers libegl1")
    material = o3d.visualization.rendering.MaterialRecord()
    material.shader = "defaultLit"
    renderer.scene.set_background([1.0, 1.0, 1.0, 1.0])
    renderer.scene.add_geometry("mesh", mesh, material)
    box = mesh.get_axis_aligned_bounding_box()
    center = box.get_center()
    extent = np.linalg.norm(box.get_extent())
    direction = np.array(DIRECTIONS[args.view])
    direction /= np.linalg.norm(direction)
    up = (0.0, 1.0, 0.0) if args.view == "z" else (0.0, 0.0, 1.0)
    renderer.setup_camera(35.0, center, center + direction * extent * 1.6, up)
    renderer.scene.scene.set_sun_light(-direction, (1.0, 1.0, 1.0), 90000)
    renderer.scene.scene.enable_sun_light(True)
    image = renderer.render_to_image()
    if not o3d.io.write_image(output, image):
        fail(f"{output}: cannot write the PNG")
    print(f"{output}: {len(mesh.triangles)} triangles, {width}x{height}, view {args.view}")


if __name__ == "__main__":
    main()
