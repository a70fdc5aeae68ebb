#!/usr/bin/env python3
"""Independent cross-check of `isostream measure` distances with Open3D.

Computes Metro-style distances between two triangle meshes (Tandem paper, section 4 "Approximation
error"): directed mean (L1), RMS (L2) and Hausdorff (L_inf) distances in both directions, estimated
from points sampled uniformly per unit of area, and the undirected distance as the larger of the two
directions. Point-to-surface distances are exact queries against Open3D's RaycastingScene (Embree,
single precision), so nothing here shares code with the Rust implementation (crates/measure).

Usage:
    pip install -r tools/requirements.txt        # open3d-cpu (~300 MB) and numpy
    # Debian/Ubuntu: open3d's import also needs `apt-get install libusb-1.0-0`
    python3 tools/measure_crosscheck.py FULL.ply OUTPUT.ply [--samples 200000] [--seed 1]
    python3 tools/measure_crosscheck.py FULL.ply OUTPUT.ply --compare measure.json [--tolerance 0.05]

FULL is the full-resolution iso-surface (for instance `isostream run` with policy `none`, exported
to PLY/OBJ), OUTPUT the simplified mesh given to `isostream measure`. Any format Open3D reads works
(PLY, OBJ, OFF, STL, GLB). The JSON printed on stdout uses the field names of the Rust `Distances`
(full_to_output, output_to_full, mean, rms, hausdorff, diagonal, *_pct).

--compare reads `isostream measure --json` output (a report with a "distances" object, or the
distances object itself) and adds, for every mean/rms/hausdorff value, the relative difference
|rust - open3d| / max(open3d, 1e-3 * diagonal). The exit status is 1 when a mean or RMS differs by
more than --tolerance (Hausdorff distances are sample maxima and only reported: two independent
sample sets legitimately disagree on them), and when the Rust side clipped output samples at its
search radius (`clipped_samples`, written by versions before the second pass over the surface:
its output -> full values are then lower bounds; `far_samples` are measured exactly).
"""

import argparse
import json
import sys

import numpy as np
import open3d as o3d


def load(path):
    mesh = o3d.io.read_triangle_mesh(path)
    if len(mesh.triangles) == 0:
        sys.exit(f"{path}: no triangles read; check the file and its format")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    triangles = np.asarray(mesh.triangles, dtype=np.int64)
    return vertices, triangles


def sample_surface(vertices, triangles, count, rng):
    """`count` points uniform per unit of area: triangles chosen with probability proportional to
    area, then the square-root barycentric map (Osada et al. 2002)."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = areas.sum()
    if total <= 0.0:
        sys.exit("a mesh has no area; nothing to sample")
    chosen = rng.choice(len(triangles), size=count, p=areas / total)
    r1 = np.sqrt(rng.random(count))[:, None]
    r2 = rng.random(count)[:, None]
    return a[chosen] * (1.0 - r1) + b[chosen] * (r1 * (1.0 - r2)) + c[chosen] * (r1 * r2)


def scene_of(vertices, triangles):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(vertices.astype(np.float32)),
        o3d.core.Tensor(triangles.astype(np.uint32)),
    )
    return scene


def directed(points, scene):
    d = scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy().astype(np.float64)
    return {
        "mean": float(d.mean()),
        "rms": float(np.sqrt((d * d).mean())),
        "hausdorff": float(d.max()),
        "samples": int(len(d)),
    }


def distances(full, output, samples, seed):
    rng = np.random.default_rng(seed)
    f2o = directed(sample_surface(*full, samples, rng), scene_of(*output))
    o2f = directed(sample_surface(*output, samples, rng), scene_of(*full))
    everything = np.vstack([full[0][np.unique(full[1])], output[0][np.unique(output[1])]])
    diagonal = float(np.linalg.norm(everything.max(axis=0) - everything.min(axis=0)))
    result = {"full_to_output": f2o, "output_to_full": o2f, "diagonal": diagonal}
    for key in ("mean", "rms", "hausdorff"):
        result[key] = max(f2o[key], o2f[key])
        result[f"{key}_pct"] = 100.0 * result[key] / diagonal
    result["full_resolution_triangles"] = int(len(full[1]))
    return result


def compare(ours, rust, tolerance):
    """Relative differences per value; returns (table, failures)."""
    table, failures = {}, []
    floor = 1e-3 * ours["diagonal"]
    for direction in ("full_to_output", "output_to_full", None):
        for key in ("mean", "rms", "hausdorff"):
            o = ours[direction][key] if direction else ours[key]
            r = rust[direction][key] if direction else rust[key]
            name = f"{direction}.{key}" if direction else key
            rel = abs(r - o) / max(o, floor)
            table[name] = {"rust": r, "open3d": o, "relative_difference": rel}
            if key != "hausdorff" and rel > tolerance:
                failures.append(f"{name}: rust {r:.6g} vs open3d {o:.6g} ({100 * rel:.1f}%)")
    if rust.get("clipped_samples", 0) > 0:
        failures.append(
            f"rust clipped {rust['clipped_samples']} output samples at max_distance "
            f"{rust.get('max_distance')}: its output -> full values are lower bounds"
        )
    return table, failures


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("full", help="full-resolution surface (PLY, OBJ, ...)")
    parser.add_argument("output", help="simplified output mesh (PLY, OBJ, ...)")
    parser.add_argument("--samples", type=int, default=200_000, help="points per direction")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--compare", metavar="JSON", help="`isostream measure --json` output")
    parser.add_argument("--tolerance", type=float, default=0.05,
                        help="largest relative difference of mean and RMS accepted by --compare")
    args = parser.parse_args()

    result = distances(load(args.full), load(args.output), args.samples, args.seed)
    failures = []
    if args.compare:
        with open(args.compare) as f:
            rust = json.load(f)
        if "quality" in rust:  # a whole MeasureReport
            rust = rust["distances"]
            if rust is None:
                sys.exit(f"{args.compare}: the report has no distances; run measure with a volume")
        result["comparison"], failures = compare(result, rust, args.tolerance)
        result["agrees"] = not failures
    json.dump(result, sys.stdout, indent=2)
    print()
    for failure in failures:
        print(f"disagreement: {failure}", file=sys.stderr)
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
