#!/usr/bin/env python3
"""Where a run's resident memory lies, over time: RSS by kind of mapping, from /proc/PID/smaps.

Runs one command (an `isostream run JOB` usually) and samples its smaps every `--every`
seconds, summing the resident kilobytes of each kind of mapping:

  * `arena`: glibc's per-thread malloc arenas (anonymous mappings aligned to 64 MiB): the small
    allocations of every thread but the main one;
  * `mmap`: other anonymous mappings: allocations past the mmap threshold (128 KiB, set in
    `src/main.rs`), i.e. the large `Vec`s, and thread stacks;
  * `[heap]`: the main thread's malloc heap;
  * `input`: mapped files whose name ends in one of `--inputs` (the volume being read);
  * `bin` and `lib`: the executable's and the shared libraries' pages.

A kind that grows along a run at a constant resident surface is where a creep is: that is how
the forty-eighth session found that a compressed VTI's pages stayed resident to the end of the
run (docs/performance.md). Linux only.

    python3 tools/rss_parts.py -- target/release/isostream run job.toml
    python3 tools/rss_parts.py --every 1 --inputs .vti,.nii.gz -- target/release/isostream run job.toml
"""

import argparse
import re
import subprocess
import sys
import time

HEADER = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) \S+ \S+ \S+ \S+\s*(.*)$")
ARENA_ALIGN = 64 << 20


def kind(start, name, binary, inputs):
    """The kind of a mapping starting at `start` named `name` (see the module documentation)."""
    if not name:
        return "arena" if start % ARENA_ALIGN == 0 else "mmap"
    if name.startswith("["):
        return name
    if any(name.endswith(s) for s in inputs):
        return "input"
    if binary and name.endswith(binary):
        return "bin"
    return "lib"


def sample(pid, binary, inputs):
    """Resident KiB by kind of mapping of process `pid`, or None once it is gone."""
    try:
        with open(f"/proc/{pid}/smaps") as f:
            text = f.read()
    except OSError:
        return None
    parts, current = {}, None
    for line in text.splitlines():
        m = HEADER.match(line)
        if m:
            current = kind(int(m.group(1), 16), m.group(3), binary, inputs)
        elif current and line.startswith("Rss:"):
            parts[current] = parts.get(current, 0) + int(line.split()[1])
    return parts


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=float, default=0.5, help="seconds between samples")
    ap.add_argument("--inputs", default=".vti,.nii,.nii.gz,.nrrd,.raw,.tif,.tiff,.vtk",
                    help="comma-separated name endings of the input files to count apart")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="the command to run (after --)")
    args = ap.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        ap.error("give the command to run after --")
    inputs = [s for s in args.inputs.split(",") if s]
    binary = command[0].rsplit("/", 1)[-1]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0, rows = time.time(), []
    while proc.poll() is None:
        parts = sample(proc.pid, binary, inputs)
        if parts:
            rows.append((time.time() - t0, parts))
        time.sleep(args.every)
    if proc.returncode:
        print(f"error: {' '.join(command)} exited with {proc.returncode}", file=sys.stderr)
    kinds = ["arena", "mmap", "[heap]", "input", "bin", "lib", "[stack]"]
    print("| s | total MiB | " + " | ".join(kinds) + " |")
    print("|---" * (len(kinds) + 2) + "|")
    for t, parts in rows:
        total = sum(parts.values())
        cells = " | ".join(f"{parts.get(k, 0) / 1024:.1f}" for k in kinds)
        print(f"| {t:.1f} | {total / 1024:.1f} | {cells} |")
    if rows:
        t, peak = max(rows, key=lambda r: sum(r[1].values()))
        print(f"peak {sum(peak.values()) / 1024:.1f} MiB at {t:.1f} s")
    sys.exit(proc.returncode)


if __name__ == "__main__":
    main()
