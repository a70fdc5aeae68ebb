#!/usr/bin/env python3
"""Streaming against in-core quality at low rates, and Hou and Chen's Fig. 7 (RMS and time against B).

    cargo build --release
    python3 tools/quality_grid.py rates  --volumes engine,bonsai,aneurism,mni152,stent --rates 0.05,0.01,0.001
    python3 tools/quality_grid.py fig7   --volumes engine --rates 0.1,0.01 --batches 2000,5000,10000,20000,50000,200000
    python3 tools/quality_grid.py validity --volumes all --rates 0.2,0.05,0.01
    python3 tools/quality_grid.py validity --volumes all --rates 0.2,0.05,0.01 --pipeline 'memory_budget_mib = 16'
    python3 tools/quality_grid.py boundary --volumes engine,bonsai,aneurism,mni152,stent --rates 0.2,0.01

`rates`: for each volume and rate, one run with the defaults (a user who only writes `rate`) and one
in core (one simplifier stage, `batch` larger than the surface and a memory budget that holds it:
the whole surface resident and decimated at the end), each measured with `isostream measure --volume` (RMS,
Hausdorff and 99.9th-percentile distance to the full-resolution surface in % of the bounding-box
diagonal, both directions; the Hausdorff distance is one sample's and moves with any change of
the contraction order, the percentile follows the whole surface). Prints a markdown table with the ratios streaming / in-core and the face-target miss.
`fig7`: RMS and seconds against B at fixed rates, with the in-core line; writes a PNG plot when
matplotlib is importable (`--plot docs/fig7.png`).
`validity`: the guarantees, checked on the output of a default run for each volume and rate: edge- and
vertex-manifold, oriented, no zero-area triangle, Euler characteristic and component count equal to
the full-resolution surface's (a `mode = "none"` run), crossing or touching triangles counted by the referee
(`crates/meshcheck`, its `self_intersections` example), the face-target miss and peak RSS; `--pipeline`
runs the simplified jobs with extra `[pipeline]` lines (the tightest budget, one stage or two).
`boundary`: `[simplify] boundary = "exact"` against the default `"planar"` (default runs, RMS and
Hausdorff from `isostream measure --volume`, boundary edges of the output); where planar writes
fewer faces (exact's floor), one more planar run at exact's face count compares them at one size.
Needs only the release binary (`--bin`, default target/release/isostream) and ../shared/data.
"""
import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = (ROOT / ".." / "shared" / "data").resolve()
VOLUMES = {
    "engine": ('path = "{d}/engine/engine_256x256x128_uint8.raw"\ndims = [256, 256, 128]\ndtype = "u8"', 70.0),
    "bonsai": ('path = "{d}/bonsai/bonsai.vti"', 40.0),
    "aneurism": ('path = "{d}/aneurism/aneurism.vti"', 110.0),
    "mni152": ('path = "{d}/mni152/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"', 89.0),
    "stent": ('path = "{d}/stent/stent_128x128x256_int16.raw"\ndims = [128, 128, 256]\ndtype = "i16"', 180.0),
    "tooth": ('path = "{d}/tooth/tooth.nrrd"', 128.0),
    "hydrogen": ('path = "{d}/hydrogen/hydrogen.vti"', 0.17),
    "headsq": ('path = "{d}/headsq/quarter.nhdr"', 1150.0),
    "ironprot": ('path = "{d}/ironprot/ironProt.vtk"', 86.0),
    "mean_head": ('path = "{d}/mean_head/mean_reg2mean.nii.gz"', 137.0),
    "cthead": ('path = "{d}/cthead_8bit/cthead_8bit_256x256x99_uint8.raw"\ndims = [256, 256, 99]\ndtype = "u8"\n'
               'spacing = [1.0, 1.0, 2.0]', 52.0),
    "silicium": ('path = "{d}/silicium/silicium_98x34x34_uint8.raw"\ndims = [98, 34, 34]\ndtype = "u8"', 69.0),
}


def measure_json(binary, mesh, job=None):
    """`isostream measure --json` of `mesh`, parsed; with `job`, also the distances to the
    full-resolution surface of its volume and iso value (`--volume`)."""
    volume = [] if job is None else ["--volume", str(job)]
    res = subprocess.run([str(binary), "measure", *volume, str(mesh), "--json"],
                         capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"isostream measure {' '.join(volume)} {mesh} failed: {res.stderr}")
    return json.loads(res.stdout)


def run(binary, work, volume, rate, simplify_extra="", pipeline_extra=""):
    """One job at `rate` (`None`: `mode = "none"`, the full-resolution surface), measured."""
    inp, iso = VOLUMES[volume]
    tag = f"{volume}_{rate}_{abs(hash(simplify_extra + pipeline_extra)) % 10**8}"
    job, out = work / f"{tag}.toml", work / f"{tag}.smb"
    mode = 'mode = "none"' if rate is None else f'mode = "rate"\nrate = {rate}'
    job.write_text(
        f"[input]\n{inp.format(d=DATA)}\n[extract]\niso = {iso}\n[simplify]\n{mode}\n"
        f"{simplify_extra}\n[output]\npath = \"{out}\"\n[pipeline]\n{pipeline_extra}\n[log]\nlevel = \"warn\"\n")
    t = time.time()
    subprocess.run([binary, "run", str(job)], check=True, capture_output=True)
    seconds = time.time() - t
    summary = json.loads((work / f"{tag}.smb.run.json").read_text())
    d = measure_json(binary, out, None if rate is None else job)
    q = d["quality"]
    return dict(volume=volume, rate=rate, faces_in=summary["faces_extracted"], faces=summary["faces_written"],
                target=round(summary["faces_extracted"] * (rate or 1)), seconds=seconds,
                rss_mib=(summary.get("peak_rss_bytes") or 0) / 2**20,
                rms=(d["distances"] or {}).get("rms_pct"), haus=(d["distances"] or {}).get("hausdorff_pct"),
                p999=(d["distances"] or {}).get("p999_pct"),
                valid=q["edge_manifold"] and q["vertex_manifold"] and q["oriented"],
                quality=q, out=out, warnings=summary.get("warnings", []))


def referee_count(binary, ply):
    """Self-intersecting triangles of a PLY mesh by the referee (the `self_intersections` example
    of `crates/meshcheck`, next to `binary`; built when missing): triangles that cross or touch
    another beyond their shared corners, in exact orientation signs (its last field; the field
    before it counts the crossing ones alone)."""
    referee = Path(binary).parent / "examples" / "self_intersections"
    if not referee.exists():
        subprocess.run(["cargo", "build", "--release", "-p", "isostream-meshcheck", "--example",
                        "self_intersections"], check=True, cwd=ROOT, capture_output=True)
    r = subprocess.run([str(referee), str(ply)], check=True, capture_output=True, text=True)
    return int(r.stdout.rsplit(",", 1)[1].split()[0])


def crossings(binary, out):
    """Crossing or touching triangles of an SMB output, by the referee."""
    ply = out.with_suffix(".ply")
    subprocess.run([binary, "convert", str(out), str(ply)], check=True, capture_output=True)
    count = referee_count(binary, ply)
    ply.unlink()
    return count


# One simplifier with the whole surface resident, decimated at the end (a cascade's first stage
# retires by a lag, so it is never in core).
IN_CORE = ("batch = 1000000000", "memory_budget_mib = 16384\nsimplify_stages = 1")


def rates(args, work):
    rows = []
    print("| volume | R | target | faces (stream / in core) | RMS % stream / in core (ratio) | Hausdorff % stream / in core (ratio) "
          "| 99.9 % within, % stream / in core (ratio) | s stream / in core | peak RSS MiB stream / in core |")
    print("|---|---|---|---|---|---|---|---|---|")
    for v in args.volumes.split(","):
        for r in [float(x) for x in args.rates.split(",")]:
            s = run(args.bin, work, v, r)
            c = run(args.bin, work, v, r, *IN_CORE)
            rows.append(dict(stream=s, in_core=c))
            print(f"| {v} | {r} | {s['target']} | {s['faces']} / {c['faces']} | {s['rms']:.4f} / {c['rms']:.4f} ({s['rms'] / c['rms']:.2f}) "
                  f"| {s['haus']:.3f} / {c['haus']:.3f} ({s['haus'] / c['haus']:.2f}) "
                  f"| {s['p999']:.4f} / {c['p999']:.4f} ({s['p999'] / c['p999']:.2f}) | {s['seconds']:.1f} / {c['seconds']:.1f} "
                  f"| {s['rss_mib']:.0f} / {c['rss_mib']:.0f} |", flush=True)
    return rows


def validity(args, work):
    rows = []
    print("| volume | R | faces (target) | edge/vertex-manifold, oriented | zero-area | Euler out / full (components) "
          "| closed facing out / in, out (full) | crossing or touching triangles | peak RSS MiB | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for v in args.volumes.split(","):
        full = run(args.bin, work, v, None)["quality"]
        for r in [float(x) for x in args.rates.split(",")]:
            s = run(args.bin, work, v, r, pipeline_extra=args.pipeline.replace(";", "\n"))
            q = s["quality"]
            s["crossings"] = crossings(args.bin, s["out"])
            s["euler_kept"] = (q["euler"], q["components"]) == (full["euler"], full["components"])
            # A closed component turned inside out keeps every count above: only the sign of
            # its volume tells.
            s["signs_kept"] = q["closed_by_sign"] == full["closed_by_sign"]
            rows.append(s)
            miss = 100 * (s["faces"] - s["target"]) / s["target"]
            floor = " (topology floor)" if any("topology" in w for w in s["warnings"]) else ""
            print(f"| {v} | {r} | {s['faces']} ({s['target']}, {miss:+.1f} %{floor}) | {'yes' if s['valid'] else 'NO'} "
                  f"| {q['zero_area_triangles']} | {q['euler']} / {full['euler']} ({q['components']} / {full['components']})"
                  f"{'' if s['euler_kept'] else ' CHANGED'} "
                  f"| {q['closed_by_sign'][0]} / {q['closed_by_sign'][1]} ({full['closed_by_sign'][0]} / {full['closed_by_sign'][1]})"
                  f"{'' if s['signs_kept'] else ' CHANGED'} | {s['crossings']} | {s['rss_mib']:.0f} | {s['seconds']:.1f} |",
                  flush=True)
    return rows


def fig7(args, work):
    rows = []
    for v in args.volumes.split(","):
        for r in [float(x) for x in args.rates.split(",")]:
            c = run(args.bin, work, v, r, *IN_CORE)
            print(f"{v} R={r} in core: RMS {c['rms']:.4f} % in {c['seconds']:.1f} s", flush=True)
            for b in [int(x) for x in args.batches.split(",")]:
                s = run(args.bin, work, v, r, f"batch = {b}")
                s["batch"] = b
                rows.append(dict(stream=s, in_core=c))
                print(f"{v} R={r} B={b}: RMS {s['rms']:.4f} % ({s['rms'] / c['rms']:.2f}x in core), {s['faces']} faces, "
                      f"{s['seconds']:.1f} s, {s['rss_mib']:.0f} MiB", flush=True)
    if args.plot:
        try:
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            print("matplotlib not importable: no plot", file=sys.stderr)
            return rows
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
        keys = sorted({(x["stream"]["volume"], x["stream"]["rate"]) for x in rows})
        for k in keys:
            pts = [x for x in rows if (x["stream"]["volume"], x["stream"]["rate"]) == k]
            b = [x["stream"]["batch"] for x in pts]
            line, = a1.plot(b, [x["stream"]["rms"] for x in pts], "o-", label=f"{k[0]} R={k[1]}")
            a1.axhline(pts[0]["in_core"]["rms"], color=line.get_color(), ls="--")
            a2.plot(b, [x["stream"]["seconds"] for x in pts], "o-", color=line.get_color())
            a2.axhline(pts[0]["in_core"]["seconds"], color=line.get_color(), ls="--")
        for a, y in ((a1, "RMS distance, % of diagonal"), (a2, "seconds (whole process)")):
            a.set_xscale("log"); a.set_xlabel("batch B (faces)"); a.set_ylabel(y)
        a1.legend(); a1.set_title("dashed: in core")
        fig.tight_layout(); fig.savefig(args.plot, dpi=100)
    return rows


def boundary(args, work):
    rows = []
    print("| volume | R | faces exact / planar | RMS % exact / planar | Hausdorff % exact / planar | boundary edges exact / planar | at exact's face count: planar RMS % / Hausdorff % |")
    print("|---|---|---|---|---|---|---|")
    for v in args.volumes.split(","):
        for r in [float(x) for x in args.rates.split(",")]:
            e = run(args.bin, work, v, r, 'boundary = "exact"')
            p = run(args.bin, work, v, r)
            same = None
            if e["faces"] > 1.02 * p["faces"]:
                same = run(args.bin, work, v, e["faces"] / p["faces_in"])
            rows.append(dict(exact=e, planar=p, planar_at_exact_faces=same))
            at = "" if same is None else f"{same['rms']:.4f} / {same['haus']:.3f} ({same['faces']} faces)"
            print(f"| {v} | {r} | {e['faces']} / {p['faces']} | {e['rms']:.4f} / {p['rms']:.4f} ({p['rms'] / e['rms']:.2f}) "
                  f"| {e['haus']:.3f} / {p['haus']:.3f} ({p['haus'] / e['haus']:.2f}) "
                  f"| {e['quality']['boundary_edges']} / {p['quality']['boundary_edges']} | {at} |", flush=True)
    return rows


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["rates", "fig7", "validity", "boundary"])
    p.add_argument("--bin", default=str(ROOT / "target" / "release" / "isostream"))
    p.add_argument("--volumes", default="engine,bonsai,aneurism,mni152,stent",
                   help=f"comma list of {','.join(VOLUMES)}, or all")
    p.add_argument("--rates", default="0.05,0.01,0.001")
    p.add_argument("--batches", default="2000,5000,10000,20000,50000,200000")
    p.add_argument("--work", default="/tmp/isostream-quality")
    p.add_argument("--json", help="write the raw rows here")
    p.add_argument("--plot", help="fig7: write a PNG here")
    p.add_argument("--pipeline", default="",
                   help="validity: extra [pipeline] lines for the simplified runs, ';' between them "
                        "(e.g. 'memory_budget_mib = 16;simplify_stages = 1')")
    args = p.parse_args()
    if args.volumes == "all":
        args.volumes = ",".join(VOLUMES)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    rows = {"rates": rates, "fig7": fig7, "validity": validity, "boundary": boundary}[args.what](args, work)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
