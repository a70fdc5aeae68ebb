#!/usr/bin/env python3
"""Where along the sweep a streamed output loses to the in-core one: faces and distances by z.

Runs three jobs on one volume (the default streamed job at rate R, the same simplifier in core,
and `mode = "none"` for the full-resolution surface), then bins along z (the sweep axis):
* each output's faces by centroid, as the cumulative share of the full-resolution faces kept
  from z = 0 up to the bin (a stream that keeps R of every prefix stays at R; in core does not);
* the distance from area-uniform samples of the full-resolution surface to each output (Open3D
  `RaycastingScene.compute_distance`, exact point-triangle distances), as the streamed over
  in-core RMS of the samples in the bin;
* the overall ratio if the streamed distances below each cut were the in-core ones (how much
  of the gap lies below it).

    python3 tools/zprofile.py --bin target/release/isostream --volume bonsai --rate 0.2
    python3 tools/zprofile.py --bin target/release/isostream --volume engine --rate 0.2 --step 8

Needs open3d and numpy (tools/requirements.txt) and ../shared/data. In core is the run the
quality grid compares with (one stage, `batch = 1000000000`, `memory_budget_mib = 16384`).
"""

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np
import open3d as o3d

from quality_grid import DATA, VOLUMES

IN_CORE = ("batch = 1000000000", "memory_budget_mib = 16384\nsimplify_stages = 1\nthreads = 2")


def job(binary, work, volume, name, simplify, pipeline=""):
    """Runs one job and converts its output to PLY; returns the PLY's path."""
    inp, iso = VOLUMES[volume]
    toml, smb, ply = (work / f"{volume}_{name}.{ext}" for ext in ("toml", "smb", "ply"))
    toml.write_text(f"[input]\n{inp.format(d=DATA)}\n[extract]\niso = {iso}\n[simplify]\n{simplify}\n"
                    f"[output]\npath = \"{smb}\"\n[pipeline]\n{pipeline}\n[log]\nlevel = \"warn\"\n")
    subprocess.run([binary, "run", str(toml)], check=True, capture_output=True)
    subprocess.run([binary, "convert", str(smb), str(ply)], check=True, capture_output=True)
    return ply


def area_samples(mesh, n, seed):
    """`n` points uniformly distributed by area over `mesh`."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(f), n, p=area / area.sum())
    s, t = np.sqrt(rng.random(n))[:, None], rng.random(n)[:, None]
    return a[idx] * (1 - s) + b[idx] * (s * (1 - t)) + c[idx] * (s * t)


def distances(mesh, points):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def face_counts(mesh, bins):
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    return np.histogram(v[f].mean(1)[:, 2], bins=bins)[0]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default="target/release/isostream")
    ap.add_argument("--volume", default="bonsai", help=f"one of {','.join(VOLUMES)}")
    ap.add_argument("--rate", type=float, default=0.2)
    ap.add_argument("--step", type=float, default=16.0, help="bin height along z, in the volume's units")
    ap.add_argument("--samples", type=int, default=1_500_000)
    ap.add_argument("--work", default="/tmp/isostream-zprofile")
    args = ap.parse_args()
    if args.volume not in VOLUMES:
        sys.exit(f"error: unknown volume {args.volume!r}; use one of {', '.join(VOLUMES)}")
    if not DATA.is_dir():
        sys.exit(f"error: {DATA}: not found; the real volumes live in ../shared/data")
    if not Path(args.bin).exists():
        sys.exit(f"error: {args.bin}: no such binary; build it with `cargo build --release`")
    binary = str(Path(args.bin).resolve())
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    rate = f'mode = "rate"\nrate = {args.rate}'
    meshes = {
        "full": job(binary, work, args.volume, "full", 'mode = "none"'),
        "in core": job(binary, work, args.volume, "in_core", f"{rate}\n{IN_CORE[0]}", IN_CORE[1]),
        "streamed": job(binary, work, args.volume, "streamed", rate),
    }
    meshes = {k: o3d.io.read_triangle_mesh(str(p)) for k, p in meshes.items()}
    points = area_samples(meshes["full"], args.samples, 5)
    z = points[:, 2]
    d = {k: distances(meshes[k], points) for k in ("in core", "streamed")}
    bins = np.arange(np.floor(z.min() / args.step) * args.step, z.max() + args.step, args.step)
    kept = {k: np.cumsum(face_counts(m, bins)) for k, m in meshes.items()}
    rms = lambda x: np.sqrt((x ** 2).mean())  # noqa: E731
    print(f"{args.volume}, R = {args.rate}: streamed / in-core RMS {rms(d['streamed']) / rms(d['in core']):.3f}"
          f" ({len(meshes['streamed'].triangles)} / {len(meshes['in core'].triangles)} faces)\n")
    print("| z | in core: faces kept / full, cumulative | streamed, the same | streamed / in-core RMS in the bin"
          " | overall, in-core distances below the bin's top |")
    print("|---|---|---|---|---|")
    for i, (lo, hi) in enumerate(zip(bins[:-1], bins[1:])):
        inside = (z >= lo) & (z < hi)
        if inside.sum() < 100 or kept["full"][i] == 0:
            continue
        below = z < hi
        hybrid = np.concatenate([d["in core"][below], d["streamed"][~below]])
        print(f"| {lo:g}-{hi:g} | {kept['in core'][i] / kept['full'][i]:.3f} | {kept['streamed'][i] / kept['full'][i]:.3f}"
              f" | {rms(d['streamed'][inside]) / rms(d['in core'][inside]):.3f} | {rms(hybrid) / rms(d['in core']):.3f} |")


if __name__ == "__main__":
    main()
