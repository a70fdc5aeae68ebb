#!/usr/bin/env python3
"""Whole-process benchmark of isostream against in-core peers, plus memory scaling and stage times.

One command runs everything and prints markdown tables (and writes all raw numbers as JSON):

    export CARGO_TARGET_DIR=/work/target-bench            # or pass --bin
    cargo build --release
    python3 tools/bench.py                                # engine, bonsai, cthead; 3 runs each
    python3 tools/bench.py --volumes engine --runs 1 --peers skimage-meshopt,vtk --skip-scaling

What is measured (every number is the median of --runs runs, default 3):

1. Real volumes (engine, bonsai, cthead from ../shared/data; `bonsai-ct`, bonsai upsampled to
   511 x 511 x 256 as the brief's 512^2-slice CT class), one target for every tool: the face
   count T = round(R * F), R = 0.2 and F = the full-resolution face count of isostream's own marching
   cubes (`faces_extracted` of its run). Tools:
   * `isostream`: the release binary on a generated job (mode rate, rate R), one process per run;
   * `skimage-meshopt`: scikit-image `marching_cubes` + meshoptimizer `simplify` to 3 T indices
     (target_error 1.0, i.e. unbounded: the face count decides);
   * `vtk`: vtkFlyingEdges3D + vtkCleanPolyData (merges the coincident points an integer iso makes;
     without it the decimation stalls far above the target) + vtkQuadricDecimation with
     TargetReduction 1 - T / F_vtk (F_vtk: triangles after cleaning);
   * `skimage-open3d` (not in the default --peers: about 70 s per run on engine): scikit-image
     `marching_cubes` + Open3D `simplify_quadric_decimation(T)`.
   Each run is a fresh child process (peers: `python3 tools/bench.py --worker ...`), timed from the
   parent as a whole process; peak RSS is the child's maximum resident set from GNU
   `/usr/bin/time -f %M` (the child is forked from `time`, so nothing of this script is counted). A peer's
   whole-process time includes the Python interpreter and library imports; its worker also reports
   the in-process seconds of load / extract / simplify, shown separately.
   Every output is checked: `isostream measure` (no --volume) on the mesh (SMB for isostream, a
   binary PLY written by the worker for peers) for edge/vertex manifoldness, orientation, boundary
   edges, zero-area triangles, Euler characteristic and components; numpy edge counting for the
   number of non-manifold edges (edges with 3+ triangles); self-intersecting triangles by casting
   every edge as a ray into an Open3D RaycastingScene (`self_intersections`; Open3D's own
   `get_self_intersecting_triangles` is quadratic, 109 s for 60k faces, and counts neighbours),
   which also counts pairs that only touch; and crossing or touching triangles by our exact
   referee (`crates/meshcheck`'s `self_intersections` example, the same count for every tool;
   before the fifty-seventh session it counted crossing ones alone).
   And every tool's accuracy on the same ruler (unless `--skip-distances`): `isostream measure
   --volume` against the full-resolution surface of the same volume and iso value, RMS, Hausdorff
   and the distance 99.9 % of the samples are within, in % of the bounding-box diagonal (about
   20-40 s a mesh on bonsai).
2. Memory scaling: procedural sphere at 128^3 .. 512^3, mode rate 0.1 and mode none: peak RSS from
   the OS and faces in/out per size.
3. Per-stage busy seconds from `<out>.run.json` for engine and bonsai (median over the runs of 1).

bonsai ships only as .vti: it is converted once (with VTK, outside any timing) to a raw file in the
work folder, so every tool reads the same headerless raw bytes.
"""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from quality_grid import measure_json, referee_count

ROOT = Path(__file__).resolve().parent.parent
DATA = (ROOT / ".." / "shared" / "data").resolve()

VOLUMES = {
    "engine": dict(path="engine/engine_256x256x128_uint8.raw", dims=[256, 256, 128], dtype="u8",
                   spacing=[1.0, 1.0, 1.0], iso=70.0),
    "bonsai": dict(vti="bonsai/bonsai.vti", dims=[256, 256, 256], dtype="u8",
                   spacing=[1.0, 1.0, 1.0], iso=40.0),
    "cthead": dict(path="cthead_8bit/cthead_8bit_256x256x99_uint8.raw", dims=[256, 256, 99],
                   dtype="u8", spacing=[1.0, 1.0, 2.0], iso=52.0),
    "stent": dict(path="stent/stent_128x128x256_int16.raw", dims=[128, 128, 256], dtype="i16",
                  spacing=[1.0, 1.0, 1.0], iso=180.0),
    # The brief's job class (a CT of 512^2 slices, about 2.6 M faces): bonsai seen at twice its
    # resolution across the slices, written once as f32 by trilinear interpolation (the values
    # `[input] upsample = [2, 2, 1]` computes, exact in f32 for u8 input) so that every tool
    # reads the same voxels.
    "bonsai-ct": dict(upsample_of="bonsai", factors=[2, 2, 1], dims=[511, 511, 256],
                      dtype="f32", spacing=[0.5, 0.5, 1.0], iso=40.0),
}
NUMPY_DTYPE = {"u8": "<u1", "i8": "<i1", "u16": "<u2", "i16": "<i2", "u32": "<u4", "i32": "<i4",
               "f32": "<f4", "f64": "<f8"}
PEERS = ["skimage-meshopt", "vtk", "skimage-open3d"]
RATE = 0.2
TIME = "/usr/bin/time"  # GNU time: -f %M is the peak RSS in KiB


# ---------------------------------------------------------------------------------------------
# Meshes: binary PLY in the layout isostream writes (float x y z; uchar count + uint indices)

def write_ply(path, vertices, faces):
    vertices = np.ascontiguousarray(vertices, dtype="<f4")
    faces = np.asarray(faces, dtype=np.int64)
    rec = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<u4", (3,))])
    rec["n"] = 3
    rec["v"] = faces
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar uint vertex_indices\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(vertices.tobytes())
        f.write(rec.tobytes())


def read_ply(path):
    """Reads the PLY layout above (as written by write_ply and `isostream convert`)."""
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    nv = nf = 0
    props = 0
    for line in data[:end].decode().splitlines():
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            nv = int(parts[2])
        elif parts[:2] == ["element", "face"]:
            nf = int(parts[2])
        elif parts[:2] == ["property", "float"]:
            props += 1
    v = np.frombuffer(data, dtype="<f4", count=nv * props, offset=end).reshape(nv, props)[:, :3]
    rec = np.frombuffer(data, dtype=[("n", "u1"), ("v", "<u4", (3,))], count=nf,
                        offset=end + nv * props * 4)
    return v.astype(np.float64), rec["v"].astype(np.int64)


def compact(vertices, faces):
    """Drops unreferenced vertices (simplifiers leave them behind)."""
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


def edge_stats(faces):
    """(edges, boundary edges, non-manifold edges) by counting undirected edges."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e.sort(axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int(len(counts)), int((counts == 1).sum()), int((counts > 2).sum())


def self_intersections(vertices, faces, eps=1e-4):
    """Triangles crossed by an edge of another triangle that shares no vertex with that edge.

    Every edge is cast as a ray (direction = the edge, so t in [0, 1] is on the edge) into an Open3D
    RaycastingScene (Embree, single precision) and all hits are listed; a hit with eps < t < 1 - eps
    on a triangle of non-zero area that has no vertex at either endpoint's position is a crossing,
    and both the crossed triangle and the triangles of the edge count as self-intersecting. Two
    triangles in general position intersect iff an edge of one crosses the other, so this finds
    every transversal intersection except folds between triangles sharing a vertex and coplanar
    overlaps. Vertices are compared by position, not index, so surfaces that touch at coincident
    vertices (marching cubes at an iso equal to voxel values) are not counted; zero-length edges
    cast no ray. Returns the number of distinct self-intersecting triangles.
    """
    import open3d as o3d
    _, canon = np.unique(vertices, axis=0, return_inverse=True)
    canon = canon.reshape(-1)
    welded = canon[faces]
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)),
                        o3d.core.Tensor(faces.astype(np.uint32)))
    all_edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    owner = np.tile(np.arange(len(faces)), 3)
    keys = np.sort(canon[all_edges], axis=1)
    uniq, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    e = all_edges[first]
    p, q = vertices[e[:, 0]], vertices[e[:, 1]]
    cast = np.flatnonzero(np.linalg.norm(q - p, axis=1) > 0)
    rays = np.concatenate([p[cast], (q - p)[cast]], axis=1).astype(np.float32)
    hits = scene.list_intersections(o3d.core.Tensor(rays))
    splits = hits["ray_splits"].numpy().astype(np.int64)
    t = hits["t_hit"].numpy()
    prim = hits["primitive_ids"].numpy().astype(np.int64)
    ray = cast[np.repeat(np.arange(len(cast)), np.diff(splits))]
    tri = welded[prim]
    ends = uniq[ray]
    shares = ((tri == ends[:, 0:1]) | (tri == ends[:, 1:2])).any(axis=1)
    crossing = (t > eps) & (t < 1 - eps) & ~shares & (area[prim] > 0)
    bad = np.zeros(len(faces), dtype=bool)
    bad[prim[crossing]] = True
    crossing_edge = np.zeros(len(uniq), dtype=bool)
    crossing_edge[ray[crossing]] = True
    bad[owner[crossing_edge[inverse.reshape(-1)]]] = True
    return int(bad.sum())


# ---------------------------------------------------------------------------------------------
# Worker: one peer in its own process

def load_volume(raw, dims, dtype):
    nx, ny, nz = dims
    return np.fromfile(raw, dtype=NUMPY_DTYPE[dtype]).reshape(nz, ny, nx)


def skimage_surface(vol, spacing, iso):
    from skimage.measure import marching_cubes
    # numpy order is (z, y, x): pass the spacing in that order and swap the vertices back to xyz.
    verts, faces, _, _ = marching_cubes(vol, level=iso, spacing=tuple(spacing[::-1]))
    return np.ascontiguousarray(verts[:, ::-1], dtype=np.float32), faces.astype(np.uint32)


def worker(args):
    t0 = time.perf_counter()
    stats = {}
    if args.worker == "skimage-meshopt":
        import meshoptimizer
        import skimage.measure  # noqa: F401  (import counted in load, not extract)
    elif args.worker == "skimage-open3d":
        import open3d as o3d
        import skimage.measure  # noqa: F401
    elif args.worker == "vtk":
        import vtk
        from vtk.util import numpy_support
    stats["import_s"] = time.perf_counter() - t0
    t = time.perf_counter()
    vol = load_volume(args.raw, args.dims, args.dtype)
    stats["load_s"] = time.perf_counter() - t
    target = args.target

    if args.worker in ("skimage-meshopt", "skimage-open3d"):
        t = time.perf_counter()
        verts, faces = skimage_surface(vol, args.spacing, args.iso)
        stats["extract_s"] = time.perf_counter() - t
        stats["faces_full"] = int(len(faces))
        del vol
        t = time.perf_counter()
        if args.worker == "skimage-meshopt":
            indices = faces.reshape(-1)
            dest = np.zeros_like(indices)
            n = meshoptimizer.simplify(dest, indices, verts, target_index_count=3 * target,
                                       target_error=1.0)
            out_faces = dest[:n].reshape(-1, 3).astype(np.int64)
            out_verts = verts.astype(np.float64)
        else:
            mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts.astype(np.float64)),
                                             o3d.utility.Vector3iVector(faces.astype(np.int32)))
            mesh = mesh.simplify_quadric_decimation(target_number_of_triangles=target)
            out_verts = np.asarray(mesh.vertices)
            out_faces = np.asarray(mesh.triangles).astype(np.int64)
        stats["simplify_s"] = time.perf_counter() - t
    elif args.worker == "vtk":
        t = time.perf_counter()
        nx, ny, nz = args.dims
        image = vtk.vtkImageData()
        image.SetDimensions(nx, ny, nz)
        image.SetSpacing(*args.spacing)
        arr = numpy_support.numpy_to_vtk(vol.reshape(-1), deep=False)
        image.GetPointData().SetScalars(arr)
        fe = vtk.vtkFlyingEdges3D()
        fe.SetInputData(image)
        fe.SetValue(0, args.iso)
        fe.ComputeNormalsOff()
        fe.ComputeGradientsOff()
        fe.ComputeScalarsOff()
        fe.Update()
        stats["faces_flying_edges"] = int(fe.GetOutput().GetNumberOfCells())
        # At an integer iso on integer data many vertices land exactly on voxels: FlyingEdges then
        # emits coincident points and zero-area triangles, and vtkQuadricDecimation stalls (engine:
        # 565k of 590k faces left for a 0.9 reduction). vtkCleanPolyData merges the points and
        # drops the degenerate triangles first, as a VTK user would.
        clean = vtk.vtkCleanPolyData()
        clean.SetInputConnection(fe.GetOutputPort())
        clean.Update()
        surf = clean.GetOutput()
        stats["extract_s"] = time.perf_counter() - t
        full = surf.GetNumberOfPolys()
        stats["faces_full"] = int(full)
        t = time.perf_counter()
        dec = vtk.vtkQuadricDecimation()
        dec.SetInputData(surf)
        dec.SetTargetReduction(max(0.0, min(1.0, 1.0 - target / max(full, 1))))
        dec.Update()
        out = dec.GetOutput()
        stats["simplify_s"] = time.perf_counter() - t
        out_verts = numpy_support.vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
        polys = numpy_support.vtk_to_numpy(out.GetPolys().GetConnectivityArray())
        out_faces = polys.reshape(-1, 3).astype(np.int64)
    else:
        sys.exit(f"unknown worker {args.worker}")
    stats["compute_s"] = time.perf_counter() - t0 - stats["import_s"]
    out_verts, out_faces = compact(out_verts, out_faces)
    stats["faces_out"] = int(len(out_faces))
    write_ply(args.out, out_verts, out_faces)
    Path(args.stats).write_text(json.dumps(stats))


# ---------------------------------------------------------------------------------------------
# Parent: processes, measurements, tables

def run_child(argv, log):
    """Runs argv as a fresh child under /usr/bin/time; returns (wall seconds, peak RSS MiB).

    The child is forked from `time` (a 2 MB process), not from this script: Linux keeps ru_maxrss
    across exec, so a child forked straight from a Python parent that has imported numpy, VTK or
    Open3D would report the parent's size as its own peak.
    """
    rss_file = Path(str(log) + ".rss")
    with open(log, "wb") as out:
        t = time.perf_counter()
        p = subprocess.run([TIME, "-f", "%M", "-o", str(rss_file), *map(str, argv)],
                           stdout=out, stderr=subprocess.STDOUT)
        wall = time.perf_counter() - t
    if p.returncode != 0:
        sys.exit(f"{' '.join(map(str, argv))} failed ({p.returncode}); see {log}:\n"
                 + Path(log).read_text(errors="replace")[-2000:])
    kib = int(rss_file.read_text().split()[-1])
    return wall, kib / 1024.0


def upsampled(vol, factors):
    """`vol` (z, y, x) at `factors` (x, y, z) times its resolution by trilinear interpolation,
    dims (n - 1) k + 1 per axis: each axis in turn, since trilinear is linear along each."""
    out = vol.astype(np.float32)
    for axis, k in zip((2, 1, 0), factors):
        n = out.shape[axis]
        pos = np.arange((n - 1) * k + 1) / k
        lo = np.minimum(np.floor(pos).astype(int), n - 2)
        t = (pos - lo).astype(np.float32)
        shape = [1, 1, 1]
        shape[axis] = -1
        t = t.reshape(shape)
        a, b = np.take(out, lo, axis=axis), np.take(out, lo + 1, axis=axis)
        out = a + (b - a) * t
    return np.ascontiguousarray(out, dtype=np.float32)


def prepare_raw(name, work):
    spec = VOLUMES[name]
    if "path" in spec:
        return DATA / spec["path"]
    if "upsample_of" in spec:
        raw = work / f"{name}_{'x'.join(map(str, spec['dims']))}_f32.raw"
        if not raw.exists():
            src = VOLUMES[spec["upsample_of"]]
            vol = load_volume(prepare_raw(spec["upsample_of"], work), src["dims"], src["dtype"])
            up = upsampled(vol, spec["factors"])
            assert list(up.shape[::-1]) == spec["dims"], up.shape
            up.astype("<f4").tofile(raw)
        return raw
    raw = work / f"{name}_{'x'.join(map(str, spec['dims']))}_{spec['dtype']}.raw"
    if not raw.exists():
        import vtk
        from vtk.util import numpy_support
        r = vtk.vtkXMLImageDataReader()
        r.SetFileName(str(DATA / spec["vti"]))
        r.Update()
        img = r.GetOutput()
        assert list(img.GetDimensions()) == spec["dims"], img.GetDimensions()
        a = numpy_support.vtk_to_numpy(img.GetPointData().GetScalars())
        a.astype(NUMPY_DTYPE[spec["dtype"]]).tofile(raw)
    return raw


def job_toml(input_lines, iso, mode, rate, out):
    simplify = f'mode = "{mode}"' + (f"\nrate = {rate}" if mode == "rate" else "")
    return (f"[input]\n{input_lines}\n\n[extract]\niso = {iso}\n\n[simplify]\n{simplify}\n\n"
            f'[output]\npath = "{out}"\n\n[log]\nlevel = "warn"\n')


def raw_input_lines(raw, spec):
    return (f'path = "{raw}"\ndims = {spec["dims"]}\ndtype = "{spec["dtype"]}"\n'
            f'spacing = {spec["spacing"]}')


def run_isostream(binary, job, work, tag):
    path = work / f"{tag}.toml"
    path.write_text(job)
    wall, rss = run_child([binary, "run", str(path)], work / f"{tag}.log")
    out = work / f"{tag}.smb"
    summary = json.loads((work / f"{tag}.smb.run.json").read_text())
    return wall, rss, summary, out


def measure_output(binary, mesh, work, selfx_max, ruler):
    """isostream measure + numpy edge counts + Open3D self-intersections; with `ruler` (a job
    naming the volume and iso value), the same `measure` call also gives the distances to the
    full-resolution surface: RMS, Hausdorff and 99.9th percentile, % of the diagonal."""
    m = measure_json(binary, mesh, ruler)
    q = m["quality"]
    ply = mesh
    if mesh.suffix != ".ply":
        ply = work / (mesh.stem + ".check.ply")
        subprocess.run([binary, "convert", str(mesh), str(ply)], check=True, capture_output=True)
    v, f = read_ply(ply)
    edges, boundary, nonmanifold = edge_stats(f)
    topo = {
        "faces": q["triangles"], "vertices": q["vertices"], "edge_manifold": q["edge_manifold"],
        "vertex_manifold": q["vertex_manifold"], "oriented": q["oriented"], "closed": q["closed"],
        "boundary_edges": q["boundary_edges"], "non_manifold_edges": nonmanifold,
        "zero_area": q["zero_area_triangles"], "euler": q["euler"], "components": q["components"],
        "anisotropy": q["anisotropy"], "self_intersecting": None, "selfx_seconds": None,
        "crossing_exact": referee_count(binary, ply),
    }
    assert boundary == q["boundary_edges"], (boundary, q["boundary_edges"])
    if selfx_max and len(f) <= selfx_max:
        t = time.perf_counter()
        topo["self_intersecting"] = self_intersections(v, f)
        topo["selfx_seconds"] = time.perf_counter() - t
    result = {"topology": topo}
    if ruler is not None:
        result["distances"] = {k: m["distances"][k] for k in ("rms_pct", "hausdorff_pct", "p999_pct")}
    return result


def med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def bench_volumes(args, binary, work):
    results = {}
    for name in args.volumes:
        spec = VOLUMES[name]
        raw = prepare_raw(name, work)
        entry = {"spec": {**spec, "raw": str(raw)}, "tools": {}}
        runs = []
        for i in range(args.runs):
            job = job_toml(raw_input_lines(raw, spec), spec["iso"], "rate", RATE,
                           work / f"{name}-isostream-{i}.smb")
            wall, rss, summary, out = run_isostream(binary, job, work, f"{name}-isostream-{i}")
            runs.append({"wall_s": wall, "rss_mib": rss, "summary": summary})
            print(f"  {name} isostream run {i}: {wall:.2f} s {rss:.0f} MiB", file=sys.stderr)
        full = runs[0]["summary"]["faces_extracted"]
        target = round(RATE * full)
        entry["faces_full_isostream"] = full
        entry["target_faces"] = target
        # The job of the runs above: it names the volume and iso value every tool's output is
        # measured against.
        ruler = None if args.skip_distances else work / f"{name}-isostream-0.toml"
        entry["tools"]["isostream"] = {
            "runs": runs, "wall_s": med([r["wall_s"] for r in runs]),
            "rss_mib": med([r["rss_mib"] for r in runs]),
            "compute_s": med([r["summary"]["seconds"] for r in runs]),
            "faces_full": full, "faces_out": runs[0]["summary"]["faces_written"],
            "stage_seconds": {k: med([r["summary"]["stage_seconds"][k] for r in runs])
                              for k in runs[0]["summary"]["stage_seconds"]},
            **measure_output(binary, out, work, args.selfx_max, ruler),
        }
        for peer in args.peers:
            runs = []
            for i in range(args.runs):
                tag = f"{name}-{peer}-{i}"
                ply, st = work / f"{tag}.ply", work / f"{tag}.json"
                argv = [sys.executable, str(Path(__file__).resolve()), "--worker", peer,
                        "--raw", str(raw), "--dims", *map(str, spec["dims"]), "--dtype",
                        spec["dtype"], "--spacing", *map(str, spec["spacing"]), "--iso",
                        str(spec["iso"]), "--target", str(target), "--out", str(ply),
                        "--stats", str(st)]
                wall, rss = run_child(argv, work / f"{tag}.log")
                runs.append({"wall_s": wall, "rss_mib": rss, **json.loads(st.read_text())})
                print(f"  {name} {peer} run {i}: {wall:.2f} s {rss:.0f} MiB", file=sys.stderr)
            entry["tools"][peer] = {
                "runs": runs, "wall_s": med([r["wall_s"] for r in runs]),
                "rss_mib": med([r["rss_mib"] for r in runs]),
                "compute_s": med([r["compute_s"] for r in runs]),
                "extract_s": med([r["extract_s"] for r in runs]),
                "simplify_s": med([r["simplify_s"] for r in runs]),
                "faces_full": runs[0]["faces_full"], "faces_out": runs[0]["faces_out"],
                **measure_output(binary, ply, work, args.selfx_max, ruler),
            }
        results[name] = entry
    return results


def bench_scaling(args, binary, work):
    rows = []
    for mode in ("rate", "none"):
        for n in args.sizes:
            runs = []
            for i in range(args.runs):
                tag = f"sphere{n}-{mode}-{i}"
                job = job_toml(f'shape = "sphere"\nsize = [{n}, {n}, {n}]', 0.0, mode, 0.1,
                               work / f"{tag}.smb")
                wall, rss, summary, out = run_isostream(binary, job, work, tag)
                runs.append({"wall_s": wall, "rss_mib": rss,
                             "faces_in": summary["faces_extracted"],
                             "faces_out": summary["faces_written"],
                             "peak_resident_faces": summary["peak_resident_faces"]})
                out.unlink(missing_ok=True)
                print(f"  sphere {n}^3 {mode} run {i}: {wall:.2f} s {rss:.0f} MiB", file=sys.stderr)
            rows.append({"size": n, "mode": mode, "runs": runs,
                         "wall_s": med([r["wall_s"] for r in runs]),
                         "rss_mib": med([r["rss_mib"] for r in runs]),
                         "faces_in": runs[0]["faces_in"], "faces_out": runs[0]["faces_out"],
                         "peak_resident_faces": runs[0]["peak_resident_faces"],
                         "voxels": n ** 3})
    return rows


def fmt(x, spec=".2f"):
    return "-" if x is None else format(x, spec)


def yes(b):
    return "yes" if b else "**no**"


def tables(results, scaling, runs):
    out = []
    if results:
        out.append(f"### Real volumes, R = {RATE} (median of {runs} runs)\n")
        out.append("| volume | tool | faces full | faces out | process s | compute s | peak RSS MiB "
                   "| time ratio | memory ratio |")
        out.append("|---|---|---:|---:|---:|---:|---:|---:|---:|")
        for name, e in results.items():
            base = e["tools"]["isostream"]
            for tool, t in e["tools"].items():
                out.append(f"| {name} | {tool} | {t['faces_full']} | {t['faces_out']} | "
                           f"{fmt(t['wall_s'])} | {fmt(t['compute_s'])} | {fmt(t['rss_mib'], '.0f')} | "
                           f"{fmt(t['wall_s'] / base['wall_s'])} | "
                           f"{fmt(t['rss_mib'] / base['rss_mib'])} |")
        out.append("\nRatios are tool / isostream (process seconds, peak RSS). `compute s` excludes "
                   "interpreter start and imports (peers) and is isostream's own `seconds`.\n")
        out.append("### Output validity\n")
        out.append("| volume | tool | faces | edge-manifold | non-manifold edges | vertex-manifold "
                   "| oriented | boundary edges | zero-area | Euler | components | "
                   "self-intersecting tris (ray cast) | crossing or touching tris (referee) |")
        out.append("|---|---|---:|---|---:|---|---|---:|---:|---:|---:|---:|---:|")
        for name, e in results.items():
            for tool, t in e["tools"].items():
                q = t["topology"]
                sx = "n/a" if q["self_intersecting"] is None else str(q["self_intersecting"])
                out.append(f"| {name} | {tool} | {q['faces']} | {yes(q['edge_manifold'])} | "
                           f"{q['non_manifold_edges']} | {yes(q['vertex_manifold'])} | "
                           f"{yes(q['oriented'])} | {q['boundary_edges']} | {q['zero_area']} | "
                           f"{q['euler']} | {q['components']} | {sx} | "
                           f"{q['crossing_exact']} |")
        measured = [(n, tool, t) for n, e in results.items() for tool, t in e["tools"].items()
                    if "distances" in t]
        if measured:
            out.append("\n### Accuracy: distance to the full-resolution surface (% of the diagonal)\n")
            out.append("| volume | tool | faces | RMS | Hausdorff | 99.9 % within | RMS ratio |")
            out.append("|---|---|---:|---:|---:|---:|---:|")
            for name, tool, t in measured:
                d, base = t["distances"], results[name]["tools"]["isostream"]["distances"]
                out.append(f"| {name} | {tool} | {t['faces_out']} | {d['rms_pct']:.4f} | "
                           f"{d['hausdorff_pct']:.3f} | {d['p999_pct']:.4f} | "
                           f"{fmt(d['rms_pct'] / base['rms_pct'])} |")
            out.append("\nMeasured by `isostream measure --volume` against isostream's own "
                       "marching-cubes surface of the same volume and iso value; RMS ratio is "
                       "tool / isostream.\n")
        stage_rows = [(n, e) for n, e in results.items() if n in ("engine", "bonsai")]
        if stage_rows:
            out.append(f"\n### isostream stage busy seconds (median of {runs} runs)\n")
            out.append("| volume | faces in | faces out | read | extract | detect | simplify | write "
                       "| total s | peak RSS MiB |")
            out.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
            for name, e in stage_rows:
                t = e["tools"]["isostream"]
                s = t["stage_seconds"]
                out.append(f"| {name} | {t['faces_full']} | {t['faces_out']} | {fmt(s['read'])} | "
                           f"{fmt(s['extract'])} | {fmt(s['detect'])} | {fmt(s['simplify'])} | "
                           f"{fmt(s['write'])} | {fmt(t['compute_s'])} | {fmt(t['rss_mib'], '.0f')} |")
    if scaling:
        out.append(f"\n### Memory scaling, procedural sphere (median of {runs} runs)\n")
        out.append("| size | voxels | mode | faces in | faces out | peak resident faces | "
                   "process s | peak RSS MiB |")
        out.append("|---|---:|---|---:|---:|---:|---:|---:|")
        for r in scaling:
            out.append(f"| {r['size']}^3 | {r['voxels']} | {r['mode']} | {r['faces_in']} | "
                       f"{r['faces_out']} | {r['peak_resident_faces']} | {fmt(r['wall_s'])} | "
                       f"{fmt(r['rss_mib'], '.0f')} |")
    return "\n".join(out)


def main():
    global RATE
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", help="isostream binary (default: $CARGO_TARGET_DIR or target/release)")
    ap.add_argument("--volumes", default="engine,bonsai,cthead",
                    help=f"comma list of {','.join(VOLUMES)}; empty to skip")
    ap.add_argument("--peers", default="skimage-meshopt,vtk", help=f"comma list of {','.join(PEERS)}")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--rate", type=float, default=0.2, help="R, the same face target for every tool (default 0.2)")
    ap.add_argument("--sizes", default="128,256,384,512", help="sphere sizes for the scaling run")
    ap.add_argument("--skip-scaling", action="store_true")
    ap.add_argument("--skip-distances", action="store_true",
                    help="do not measure every output's distance to the full surface")
    ap.add_argument("--selfx-max", type=int, default=2000000,
                    help="check self-intersections on outputs up to this many faces (0: never)")
    ap.add_argument("--work", default="/tmp/isostream-bench", help="scratch folder (meshes, logs)")
    ap.add_argument("--json", default="bench.json", help="where to write all numbers")
    # worker mode (internal)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--raw", help=argparse.SUPPRESS)
    ap.add_argument("--dims", type=int, nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--dtype", help=argparse.SUPPRESS)
    ap.add_argument("--spacing", type=float, nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--iso", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--target", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--stats", help=argparse.SUPPRESS)
    args = ap.parse_args()
    RATE = args.rate
    if args.worker:
        return worker(args)

    target_dir = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    binary = Path(args.bin) if args.bin else target_dir / "release" / "isostream"
    if not binary.exists():
        sys.exit(f"{binary} not found: run `cargo build --release` (or pass --bin)")
    args.volumes = [v for v in args.volumes.split(",") if v]
    args.peers = [p for p in args.peers.split(",") if p]
    for v in args.volumes:
        if v not in VOLUMES:
            sys.exit(f"unknown volume {v}; known: {', '.join(VOLUMES)}")
    for p in args.peers:
        if p not in PEERS:
            sys.exit(f"unknown peer {p}; known: {', '.join(PEERS)}")
    args.sizes = [int(s) for s in args.sizes.split(",") if s]
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)

    started = time.time()
    load_start = os.getloadavg()
    results = bench_volumes(args, binary, work) if args.volumes else {}
    scaling = [] if args.skip_scaling else bench_scaling(args, binary, work)
    report = {
        "machine": {"cpus": os.cpu_count(), "uname": " ".join(os.uname()),
                    "python": sys.version.split()[0]},
        "binary": str(binary), "runs": args.runs, "rate": RATE, "volumes": results,
        "scaling": scaling, "seconds": time.time() - started,
        "loadavg_start": load_start, "loadavg_end": os.getloadavg(),
        "note": "median of runs; shared 2-core machine, expect noise",
    }
    Path(args.json).write_text(json.dumps(report, indent=1))
    print(tables(results, scaling, args.runs))
    print(f"\n(all numbers in {args.json}; meshes and logs in {work})")


if __name__ == "__main__":
    main()
