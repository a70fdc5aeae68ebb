#!/usr/bin/env python3
"""Screenshot of the status page of `isostream serve`, as a browser shows it.

    python3 tools/screenshot.py [--bin target/release/isostream] [-o docs/status-page.png]

Starts the service on a free loopback port with a fresh state folder, submits two jobs (a
procedural torus and gyroid), waits until both are done, then has headless Chromium load
`/#plots=1` (every finished job's plots opened) and save a PNG. Stops the service at the end,
whatever happens. Needs Debian's `chromium` package (`apt-get install -y chromium`); as root,
Chromium only runs with `--no-sandbox`, which this script passes (the page is our own, from
loopback).
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request

JOBS = [
    "[input]\nshape = \"torus\"\nsize = [96, 96, 96]\n[extract]\niso = 0.0\n"
    "[simplify]\nrate = 0.2\n[output]\npath = \"torus.smb\"\n",
    "[input]\nshape = \"gyroid\"\nsize = [128, 128, 128]\n[extract]\niso = 0.0\n"
    "[simplify]\nrate = 0.1\n[output]\npath = \"gyroid.ply\"\n",
]


def fail(message):
    print(f"error: {message}", file=sys.stderr)
    sys.exit(1)


def request(base, path, body=None):
    data = body.encode() if body is not None else None
    with urllib.request.urlopen(urllib.request.Request(base + path, data=data), timeout=30) as r:
        return json.loads(r.read())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default="target/release/isostream")
    ap.add_argument("-o", "--output", default="docs/status-page.png")
    ap.add_argument("--size", default="1280x2000", help="browser window WIDTHxHEIGHT")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds for the jobs to finish")
    args = ap.parse_args()
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if not chromium:
        fail("no chromium: apt-get install -y chromium")
    if not os.path.isfile(args.bin):
        fail(f"{args.bin}: no such binary (cargo build --release, or pass --bin)")

    with tempfile.TemporaryDirectory() as tmp:
        log = open(os.path.join(tmp, "serve.log"), "w")
        serve = subprocess.Popen(
            [args.bin, "serve", "--state", os.path.join(tmp, "state"), "--listen", "127.0.0.1:0"],
            stdout=subprocess.PIPE, stderr=log, text=True)
        try:
            line = serve.stdout.readline()
            if "http://" not in line:
                fail(f"the service did not start: {line!r}")
            base = line.split()[-1]
            ids = [request(base, "/jobs", job)["id"] for job in JOBS]
            start = time.time()
            while True:
                states = [request(base, f"/jobs/{i}")["state"] for i in ids]
                if all(s in ("done", "failed", "cancelled") for s in states):
                    break
                if time.time() - start > args.timeout:
                    fail(f"jobs not finished after {args.timeout} s: {states}")
                time.sleep(0.5)
            if states != ["done", "done"]:
                fail(f"jobs ended {states}")
            width, height = args.size.split("x")
            shot = subprocess.run(
                [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                 f"--window-size={width},{height}", "--virtual-time-budget=10000",
                 f"--screenshot={os.path.abspath(args.output)}", base + "/#plots=1"],
                capture_output=True, text=True, timeout=120)
            if shot.returncode != 0 or not os.path.isfile(args.output):
                fail(f"chromium failed ({shot.returncode}): {shot.stderr.strip()[-500:]}")
            print(f"{args.output}: status page of 2 jobs ({', '.join(ids)}), {width}x{height}")
        finally:
            serve.terminate()
            serve.wait(timeout=30)


if __name__ == "__main__":
    main()
