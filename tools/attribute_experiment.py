#!/usr/bin/env python3
"""Data-dependent simplification experiment (issue 5): at equal face count, compare the
geometric priority, seed 001's data-dependent priority over several lambda, and the attribute
quadric, by attribute RMS error and geometric RMS distance (`isostream measure`).

Cases:
  step-vortex  a gently curved sheet (z = 16 + 3 sin(x / 10)) through a 64x64x32 volume whose
               second field has a sharp step (tanh, width 0.7 voxel) and a thin vortex core;
  tooth        the tooth CT (../shared/data/tooth/tooth.nrrd, 103x94x161) at iso 128 with
               gradient_magnitude;
  ironprot     the iron protein (../shared/data/ironprot/ironProt.vtk, 68^3) at iso 86 with
               gradient_magnitude;
  engine       the engine CT (../shared/data/engine) at iso 70 with gradient_magnitude.

Meshes are written as SMB (which carries the attributes) and measured from it.

Usage: tools/attribute_experiment.py [--bin PATH] [--out out/attr-exp]
                                    [--cases step-vortex,tooth] [--rate 0.1] [--lambdas 0,0.5,1]
                                    [--weights 0.02,0.05,0.2]
The binary defaults to $ISOSTREAM_BIN, else $CARGO_TARGET_DIR/release/isostream, else
target/release/isostream. Prints a Markdown table per case (the ones in docs/attributes.md) and
writes results.json.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def step_vortex(out):
    nx, ny, nz = 64, 64, 32
    z, y, x = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    sheet = 16.0 + 3.0 * np.sin(x / 10.0)
    iso = (sheet - z).astype(np.float32)  # > 0 below the sheet
    r2 = (x - 22.0) ** 2 + (y - 40.0) ** 2
    vortex = 2.0 * np.sqrt(r2) / (r2 + 2.0**2) * 2.0  # peak 1 at r = 2 voxels
    step = 0.5 * (1.0 + np.tanh((x - 44.3) / 0.7))
    feature = (vortex + step).astype(np.float32)
    iso.tofile(os.path.join(out, "sv_iso.raw"))
    feature.tofile(os.path.join(out, "sv_feature.raw"))
    head = f"""[input]
path = "sv_iso.raw"
dims = [{nx}, {ny}, {nz}]
dtype = "f32"
[extract]
iso = 0.0
[[attributes]]
name = "feature"
path = "sv_feature.raw"
dims = [{nx}, {ny}, {nz}]
dtype = "f32"
"""
    return head, 5.0


DATA = os.path.normpath(os.path.join(ROOT, "..", "shared", "data"))

# Real volumes: (file under DATA, extra [input] keys, iso, attribute-quadric weight). The weight
# scales |grad f| (value units per voxel, tens to hundreds on these u8 scans) against positions
# (voxels): 0.05 makes a gradient difference of 20 cost like one voxel of displacement.
REAL = {
    "tooth": ("tooth/tooth.nrrd", "", 128.0, 0.05),
    "ironprot": ("ironprot/ironProt.vtk", "", 86.0, 0.05),
    "engine": ("engine/engine_256x256x128_uint8.raw", 'dims = [256, 256, 128]\ndtype = "u8"\n',
               70.0, 0.05),
}


def real(name):
    rel, keys, iso, weight = REAL[name]
    path = os.path.join(DATA, rel)
    if not os.path.exists(path):
        return None, None
    head = f"""[input]
path = "{path}"
{keys}[extract]
iso = {iso}
[[attributes]]
name = "gradient"
derive = "gradient_magnitude"
"""
    return head, weight


def run(binary, out, name, head, simplify):
    job = os.path.join(out, name + ".toml")
    mesh = os.path.join(out, name + ".smb")
    with open(job, "w") as f:
        f.write(head + "[simplify]\n" + simplify + "\n[output]\npath = \"" + mesh + "\"\n")
    start = time.monotonic()
    subprocess.run([binary, "run", job], check=True, capture_output=True)
    seconds = time.monotonic() - start
    m = subprocess.run([binary, "measure", "--volume", job, mesh, "--json"], check=True,
                       capture_output=True, text=True)
    rep = json.loads(m.stdout)
    a = rep["attributes"][0]
    return {
        "run": name,
        "faces": rep["quality"]["triangles"],
        "attr_rms": a["rms"],
        "attr_max": a["max"],
        "geom_rms": rep["distances"]["rms"],
        "geom_hausdorff": rep["distances"]["hausdorff"],
        "run_seconds": round(seconds, 2),
    }


def main():
    ap = argparse.ArgumentParser()
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
    default_bin = os.environ.get("ISOSTREAM_BIN", os.path.join(target, "release", "isostream"))
    ap.add_argument("--bin", default=default_bin)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "attr-exp"))
    ap.add_argument("--cases", default="step-vortex,tooth")
    ap.add_argument("--rate", type=float, default=0.1)
    ap.add_argument("--lambdas", default="0,0.25,0.5,0.75,1")
    ap.add_argument("--weights", default="",
                    help="attribute-quadric weights to try (default: one per case)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    results = {}
    for case in args.cases.split(","):
        if case == "step-vortex":
            head, weight = step_vortex(args.out)
        else:
            head, weight = real(case)
        if head is None:
            print(f"{case}: data missing, skipped", file=sys.stderr)
            continue
        rate = f"mode = \"rate\"\nrate = {args.rate}\n"
        runs = [("geometric", rate)]
        runs += [(f"data-dependent lambda={l}", rate + f"priority = \"data-dependent\"\nlambda = {l}")
                 for l in args.lambdas.split(",")]
        weights = args.weights.split(",") if args.weights else [weight]
        runs += [(f"attribute-quadric w={w}",
                  rate + f"priority = \"attribute-quadric\"\nattribute_weights = [{w}]")
                 for w in weights]
        rows = []
        for i, (label, simplify) in enumerate(runs):
            r = run(args.bin, args.out, f"{case}-{i}", head, simplify)
            r["run"] = label
            rows.append(r)
            print(f"{case} {label}: {r}", file=sys.stderr)
        results[case] = rows
        print(f"\n**{case}** (rate {args.rate})\n")
        print("| priority | faces | attribute RMS | attribute max | geometric RMS | Hausdorff | run s |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['run']} | {r['faces']} | {r['attr_rms']:.4g} | {r['attr_max']:.4g} | "
                  f"{r['geom_rms']:.4g} | {r['geom_hausdorff']:.4g} | {r['run_seconds']:.1f} |")
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    main()
