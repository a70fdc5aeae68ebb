#!/usr/bin/env python3
"""Instructions executed by each simplifier stage, by callgrind: the deterministic speed measure.

Wall time on a shared 2-core VM moves by 10-40 % between runs of one binary (docs/performance.md,
"Forty-first session"), which hides any change below that; the instructions each thread
executes repeat within 0.1 %. This runs each job once under `valgrind --tool=callgrind
--separate-threads=yes` (about 10-40x slower than a plain run: bonsai at R = 0.2 takes about
two minutes), finds the simplifier threads by their symbols (`SimplifyStep` is the first or only
stage, `SecondStep` the second of a cascade), and prints their instructions, the contractions
and guard queries from the run summary, and whether each build wrote the first build's bytes.

    python3 tools/instructions.py --bins target/release/isostream --volumes engine,bonsai --rates 0.2,0.01
    python3 tools/instructions.py --bins OLD,NEW --volumes bonsai --rates 0.2   # compare two builds

Needs valgrind (`apt-get install valgrind`) and `../shared/data`. Jobs are the default
pipeline at the given rate (two stages where the default chooses them); `--pipeline` and
`--simplify` add keys to those sections, as in tools/quality_grid.py.
"""

import argparse
import filecmp
import json
import shutil
import subprocess
import sys
from pathlib import Path

from quality_grid import DATA, VOLUMES

# Symbols that name a simplifier thread's stage in its callgrind file.
STAGES = (("SecondStep", "second"), ("SimplifyStep", "first"))


def thread_counts(prefix):
    """Instructions of each thread file `prefix.*-NN` written by callgrind, keyed by the stage
    its symbols name (`first`, `second`) or `other` (summed)."""
    counts = {"first": 0, "second": 0, "other": 0}
    for f in sorted(prefix.parent.glob(prefix.name + ".*-*")):
        text = f.read_text(errors="replace")
        total = next((int(line.split()[1]) for line in text.splitlines()
                      if line.startswith(("summary:", "totals:"))), 0)
        stage = next((name for symbol, name in STAGES if symbol in text), "other")
        counts[stage] += total
    return counts


def run(binary, work, volume, rate, simplify_extra, pipeline_extra, tag):
    """One job under callgrind: the per-stage instructions, the run summary and the output."""
    inp, iso = VOLUMES[volume]
    job, out = work / f"{tag}.toml", work / f"{tag}.smb"
    job.write_text(
        f"[input]\n{inp.format(d=DATA)}\n[extract]\niso = {iso}\n[simplify]\nmode = \"rate\"\n"
        f"rate = {rate}\n{simplify_extra}\n[output]\npath = \"{out}\"\n[pipeline]\n{pipeline_extra}\n"
        f"[log]\nlevel = \"warn\"\n")
    prefix = work / f"{tag}.cg"
    for old in work.glob(prefix.name + ".*"):
        old.unlink()
    subprocess.run(["valgrind", "--tool=callgrind", "--separate-threads=yes",
                    f"--callgrind-out-file={prefix}.%p", str(binary), "run", str(job)],
                   check=True, capture_output=True)
    summary = json.loads((work / f"{tag}.smb.run.json").read_text())
    return thread_counts(prefix), summary, out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bins", required=True, help="comma-separated isostream binaries (the first is the reference)")
    ap.add_argument("--volumes", default="engine,bonsai")
    ap.add_argument("--rates", default="0.2,0.01")
    ap.add_argument("--simplify", default="", help="extra [simplify] lines")
    ap.add_argument("--pipeline", default="", help="extra [pipeline] lines ('; ' separates them)")
    ap.add_argument("--work", default="/tmp/isostream-instructions")
    args = ap.parse_args()
    if shutil.which("valgrind") is None:
        sys.exit("valgrind not found: install it (Debian/Ubuntu: apt-get install valgrind)")
    bins = [Path(b).resolve() for b in args.bins.split(",")]
    for b in bins:
        if not b.exists():
            sys.exit(f"{b}: no such binary; build it with `cargo build --release`")
    unknown = [v for v in args.volumes.split(",") if v not in VOLUMES]
    if unknown:
        sys.exit(f"unknown volume {', '.join(unknown)}: use {', '.join(VOLUMES)}")
    if not DATA.is_dir():
        sys.exit(f"{DATA}: not found; the real volumes live in ../shared/data")
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    pipeline = args.pipeline.replace("; ", "\n")
    print("| volume | R | build | first stage, G | second stage, G | other threads, G | contractions | "
          "guard queries | instructions a contraction (both stages) | bytes as the first build |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for volume in args.volumes.split(","):
        for rate in (float(r) for r in args.rates.split(",")):
            reference = None
            for i, binary in enumerate(bins):
                tag = f"{volume}_{rate}_{i}"
                counts, summary, out = run(binary, work, volume, rate, args.simplify, pipeline, tag)
                reference = reference or out
                s = summary["simplify"]
                simplified = counts["first"] + counts["second"]
                per = simplified / max(s["contractions"], 1)
                same = "yes" if filecmp.cmp(reference, out, shallow=False) else "no"
                print(f"| {volume} | {rate} | {binary} | {counts['first'] / 1e9:.2f} | "
                      f"{counts['second'] / 1e9:.2f} | {counts['other'] / 1e9:.2f} | {s['contractions']} | "
                      f"{s['guard']['queries']} | {per / 1e3:.1f} k | {same} |", flush=True)


if __name__ == "__main__":
    main()
