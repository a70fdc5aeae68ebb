#!/usr/bin/env python3
"""Peak RSS and time per Gvoxel of `isostream run` on a real volume upsampled to growing sizes.

Each size is the volume seen through `[input] upsample = [k, k, k]` (dims (n - 1) k + 1),
simplified to the same `[output] faces`. For each run it reads the run summary
(`<output>.run.json`: seconds, peak RSS from the OS, faces, skipped cubes) and the peak RSS the
OS reports for the child (`resource.getrusage(RUSAGE_CHILDREN)`, in case the summary is
missing), prints one JSON line, appends it to `--results`, and plots every result in that file
(peak RSS and seconds per Gvoxel against Gvoxels) into `--plot`.

    python3 tools/scale.py --factors 1,2,4 --faces 10000          # bonsai 256^3 .. 1021^3
    python3 tools/scale.py --factors 8 --faces 10000              # adds 2041^3 to the results
    python3 tools/scale.py --factors 1,2 --budget-mib 40          # [pipeline] memory_budget_mib
    python3 tools/scale.py --factors 1,2,4,8 --stages 1           # [pipeline] simplify_stages

The plot draws one whole-run curve per memory budget and stage count asked for (a size run
again replaces its earlier result on the curve).

    python3 tools/scale.py --factors 8,16 --count-only            # the front half alone
    python3 tools/scale.py --factors 1,2 --from-summaries --keep DIR --contended
                                        # record runs of this tool's jobs made by hand in DIR

`--count-only` measures the front half of a run (read, upsample, empty-space skipping, parallel
extraction) at sizes where the simplifier would take too long: the run's first pass (the face
count `[output] faces` needs) is timed from its log line (`first pass ...`), the peak RSS read from
/proc/PID/status (VmHWM) at that moment, and the run is then stopped (SIGTERM). Those results go
to `--count-results` and are plotted as a second curve.

Needs a release build (`cargo build --release`) and matplotlib.
"""

import argparse
import json
import math
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def job_text(volume: Path, iso: float, k: int, faces: int, output: Path, threads: int,
             budget_mib: int = 0, stages: int = 0) -> str:
    threads_line = f"threads = {threads}\n" if threads else ""
    threads_line += f"memory_budget_mib = {budget_mib}\n" if budget_mib else ""
    threads_line += f"simplify_stages = {stages}\n" if stages else ""
    return (
        f'[input]\npath = "{volume}"\nupsample = [{k}, {k}, {k}]\n\n'
        f"[extract]\niso = {iso}\n\n"
        f'[output]\npath = "{output}"\nfaces = {faces}\n\n'
        f"[pipeline]\n{threads_line}"
        f'[log]\nprogress_seconds = 30\n'
    )


def run_one(binary: Path, volume: Path, iso: float, k: int, faces: int, threads: int, keep: Path,
            budget_mib: int, stages: int):
    keep.mkdir(parents=True, exist_ok=True)
    output = keep / f"{volume.stem}_x{k}.smb"
    job = keep / f"{volume.stem}_x{k}.toml"
    job.write_text(job_text(volume, iso, k, faces, output, threads, budget_mib, stages))
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    started = time.monotonic()
    subprocess.run([str(binary), "run", str(job)], check=True, stderr=subprocess.DEVNULL)
    wall = time.monotonic() - started
    child_rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    return result(volume, k, faces, budget_mib, stages, output, wall,
                  child_rss if child_rss > before * 1024 else None)


def result(volume: Path, k: int, faces: int, budget_mib: int, stages: int, output: Path, wall,
           child_rss) -> dict:
    """One result line from the run summary next to `output`; `wall` (seconds) and `child_rss`
    (bytes, the OS's peak) are the run's when this process made it, else None."""
    summary = json.loads(Path(str(output) + ".run.json").read_text())
    gvox = summary["voxels"] / 1e9
    if wall is None:
        wall = summary["seconds"]
    return {
        "volume": volume.name,
        "factor": k,
        "dims": summary["dims"],
        "gvoxels": gvox,
        "faces_target": faces,
        "memory_budget_mib": budget_mib or None,
        # Asked for with --stages; None where the default chose (the summary says which).
        "simplify_stages_asked": stages or None,
        "simplify_stages": len(summary.get("simplify_stages") or [None]),
        "peak_resident_faces": summary.get("peak_resident_faces"),
        "faces_extracted": summary["faces_extracted"],
        "faces_written": summary["faces_written"],
        "rate": summary.get("rate"),
        "seconds": summary["seconds"],
        "wall_seconds": wall,
        "seconds_per_gvoxel": summary["seconds"] / gvox,
        "stage_seconds": summary["stage_seconds"],
        "peak_rss_mib": (summary.get("peak_rss_bytes") or child_rss) / 2**20,
        # Only meaningful for the first child of this process (RUSAGE_CHILDREN keeps the max).
        "child_peak_rss_mib": child_rss / 2**20 if child_rss else None,
        "skipped_cubes": summary["extract"]["skipped_cubes"],
        "cubes": summary["extract"]["cubes"],
        "output": str(output),
    }


def count_only(binary: Path, volume: Path, iso: float, k: int, threads: int, keep: Path):
    keep.mkdir(parents=True, exist_ok=True)
    output = keep / f"{volume.stem}_x{k}_count.smb"
    job = keep / f"{volume.stem}_x{k}_count.toml"
    job.write_text(job_text(volume, iso, k, 10000, output, threads).replace(
        "[log]\n", '[log]\nformat = "json"\n'))
    child = subprocess.Popen([str(binary), "run", str(job)], stderr=subprocess.PIPE, text=True)
    found, dims = None, None
    for line in child.stderr:
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            continue
        fields = event.get("fields", {})
        if fields.get("message") == "job start":
            dims = fields["dims"]  # logged with Debug: "[2041, 2041, 2041]"
            dims = json.loads(dims) if isinstance(dims, str) else dims
        # The first pass's line ("first pass (output.faces, ...)"; "counting pass ..." before).
        message = fields.get("message", "")
        if message.startswith("first pass") or "counting pass" in message:
            status = Path(f"/proc/{child.pid}/status").read_text()
            hwm = next(int(l.split()[1]) for l in status.splitlines() if l.startswith("VmHWM"))
            found = {"fields": fields, "peak_rss_mib": hwm / 1024}
            child.send_signal(signal.SIGTERM)
            break
    child.wait()
    if found is None:
        raise SystemExit(f"no counting pass line from {job}")
    f = found["fields"]
    return {
        "volume": volume.name,
        "factor": k,
        "dims": dims,
        "gvoxels": math.prod(dims) / 1e9,
        "faces_extracted": f["extracted"],
        "count_seconds": f["seconds"],
        "peak_rss_mib": found["peak_rss_mib"],
    }


def plot(results: list, counts: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = sorted(counts, key=lambda r: r["gvoxels"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    if counts:
        cg = [r["gvoxels"] for r in counts]
        a.plot(cg, [r["peak_rss_mib"] for r in counts], "s--", label="first pass only (read, upsample, skip, extract)")
        b.plot(cg, [r["count_seconds"] / r["gvoxels"] for r in counts], "s--", label="first pass only")
    # One curve per memory budget and stage count asked for; a size run again replaces its
    # earlier result. A row marked `"contended"` (its run shared the cores with other work)
    # counts for memory, not for time.
    def curves(rows):
        by_job = {}
        for r in rows:
            job = (r.get("memory_budget_mib") or 0, r.get("simplify_stages_asked") or 0)
            by_job.setdefault(job, {})[r["factor"]] = r
        return {k: sorted(v.values(), key=lambda r: r["gvoxels"]) for k, v in by_job.items()}

    def label(job):
        budget, stages = job
        text = f"whole run, budget {budget} MiB" if budget else "whole run, default budget"
        return text + (f", {stages} stage{'s' if stages > 1 else ''}" if stages else "")

    for budget, runs in sorted(curves(results).items()):
        a.plot([r["gvoxels"] for r in runs], [r["peak_rss_mib"] for r in runs], "o-", label=label(budget))
        for r in runs:
            a.annotate("x".join(str(d) for d in r["dims"]), (r["gvoxels"], r["peak_rss_mib"]),
                       fontsize=7, textcoords="offset points", xytext=(4, 4))
    timed = [r for r in results if not r.get("contended")]
    for budget, runs in sorted(curves(timed).items()):
        b.plot([r["gvoxels"] for r in runs], [r["seconds_per_gvoxel"] for r in runs], "o-",
               label=f"{label(budget)} (both passes)")
    a.set_xscale("log")
    a.set_ylim(bottom=0)
    a.set_xlabel("Gvoxels (upsampled)")
    a.set_ylabel("peak RSS (MiB)")
    a.set_title("peak RSS")
    b.set_yscale("log")
    a.legend(fontsize=7)
    b.legend(fontsize=7)
    b.set_xscale("log")
    b.set_xlabel("Gvoxels (upsampled)")
    b.set_ylabel("seconds per Gvoxel")
    # Either file may be empty (count-only results without whole runs, or the reverse).
    first = (results or counts or [{}])[0]
    out = f" ({first['faces_target']} faces out)" if "faces_target" in first else ""
    b.set_title(f"time per Gvoxel{out}")
    fig.suptitle(f"isostream on {first.get('volume', 'a volume')} upsampled (2 cores)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--volume", type=Path, default=ROOT.parent / "shared/data/bonsai/bonsai.vti")
    p.add_argument("--iso", type=float, default=40.0)
    p.add_argument("--factors", default="1,2,4,8", help="comma-separated upsampling factors")
    p.add_argument("--faces", type=int, default=10000)
    p.add_argument("--threads", type=int, default=0, help="[pipeline] threads (0: all cores)")
    p.add_argument("--budget-mib", type=int, default=0,
                   help="[pipeline] memory_budget_mib of the whole runs (0: the default)")
    p.add_argument("--stages", type=int, default=0,
                   help="[pipeline] simplify_stages of the whole runs (0: the default's choice)")
    p.add_argument("--binary", type=Path, default=ROOT / "target/release/isostream")
    p.add_argument("--keep", type=Path, default=Path(tempfile.gettempdir()) / "isostream-scale")
    p.add_argument("--results", type=Path, default=ROOT / "docs/scale.jsonl")
    p.add_argument("--plot", type=Path, default=ROOT / "docs/scale.png")
    p.add_argument("--count-only", action="store_true", help="time only the first (counting) pass")
    p.add_argument("--count-results", type=Path, default=ROOT / "docs/scale_count.jsonl")
    p.add_argument("--from-summaries", action="store_true",
                   help="run nothing: record the runs already in --keep (their run summaries, "
                        "`<volume>_x<k>.smb.run.json`), e.g. runs made by hand with this tool's jobs")
    p.add_argument("--contended", action="store_true",
                   help="mark the results as run beside other work: plotted for memory, not time")
    a = p.parse_args()
    for k in [int(x) for x in a.factors.split(",") if x]:
        if a.count_only:
            r, to = count_only(a.binary, a.volume, a.iso, k, a.threads, a.keep), a.count_results
        elif a.from_summaries:
            output = a.keep / f"{a.volume.stem}_x{k}.smb"
            r, to = result(a.volume, k, a.faces, a.budget_mib, a.stages, output, None, None), a.results
        else:
            r, to = (run_one(a.binary, a.volume, a.iso, k, a.faces, a.threads, a.keep, a.budget_mib,
                             a.stages), a.results)
        if a.contended:
            r["contended"] = True
        print(json.dumps(r), flush=True)
        with to.open("a") as f:
            f.write(json.dumps(r) + "\n")
    def load(path: Path) -> list:
        return [json.loads(l) for l in path.read_text().splitlines() if l.strip()] if path.exists() else []

    plot(load(a.results), load(a.count_results), a.plot)
    print(f"plot: {a.plot}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
