#!/usr/bin/env python3
"""Bounded load check of `isostream serve` on loopback (standard library only).

Starts the service on a free port with a fresh state folder, then 20 client threads send 200 job
submissions and 2,000 status requests in total (each client: 10 submissions, 100 GET
/jobs/{id} or GET /jobs), waits until every job is finished, prints latency percentiles and
throughput, and stops the service. Nothing runs for longer than --timeout seconds.

    python3 tools/load_check.py --bin target/release/isostream
"""

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request

JOB = """[input]
shape = "sphere"
size = [{n}, {n}, {n}]

[extract]
iso = 0.0

[output]
path = "sphere.smb"
"""


def request(base, method, path, body=None):
    """Returns (status, seconds, parsed JSON or None)."""
    req = urllib.request.Request(base + path, data=body, method=method)
    start = time.perf_counter()
    try:
        with urllib.request.urlopen(req, timeout=30) as res:
            data = res.read()
            status = res.status
    except urllib.error.HTTPError as e:
        data, status = e.read(), e.code
    elapsed = time.perf_counter() - start
    try:
        return status, elapsed, json.loads(data)
    except ValueError:
        return status, elapsed, None


def pct(values, p):
    values = sorted(values)
    return values[min(len(values) - 1, int(p / 100 * len(values)))] * 1000


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bin", default="target/release/isostream")
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--submissions", type=int, default=200)
    ap.add_argument("--status-requests", type=int, default=2000)
    ap.add_argument("--size", type=int, default=24, help="sphere grid size of each job")
    ap.add_argument("--parallel-jobs", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=300)
    args = ap.parse_args()

    state = tempfile.mkdtemp(prefix="isostream-load-")
    log = open(os.path.join(state, "serve.log"), "w")
    server = subprocess.Popen(
        [args.bin, "serve", "--state", os.path.join(state, "state"), "--listen", "127.0.0.1:0",
         "--max-parallel-jobs", str(args.parallel_jobs)],
        stdout=subprocess.PIPE, stderr=log, text=True, env={**os.environ, "RUST_LOG": "warn"})
    try:
        line = server.stdout.readline()
        base = line.strip().rsplit(" ", 1)[-1]
        if not base.startswith("http://"):
            sys.exit(f"the service did not start: {line!r}, see {log.name}")
        run(base, args)
    finally:
        server.terminate()
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()


def run(base, args):
    deadline = time.monotonic() + args.timeout
    body = JOB.format(n=args.size).encode()
    ids, submit_lat, status_lat, errors = [], [], [], []
    lock = threading.Lock()
    subs = args.submissions // args.clients
    stats = args.status_requests // args.clients

    def client(k):
        rng = random.Random(k)
        mine = []
        for i in range(subs + stats):
            if time.monotonic() > deadline:
                return
            # Interleave: a submission every (subs + stats) / subs requests.
            if len(mine) < subs and i % ((subs + stats) // subs) == 0:
                status, t, reply = request(base, "POST", "/jobs", body)
                with lock:
                    submit_lat.append(t)
                    if status == 201:
                        mine.append(reply["id"])
                        ids.append(reply["id"])
                    else:
                        errors.append((status, reply))
            else:
                path = f"/jobs/{rng.choice(mine)}" if mine and rng.random() < 0.9 else "/jobs"
                status, t, reply = request(base, "GET", path)
                with lock:
                    status_lat.append(t)
                    if status != 200:
                        errors.append((status, reply))

    start = time.perf_counter()
    threads = [threading.Thread(target=client, args=(k,)) for k in range(args.clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    requests_done = time.perf_counter() - start

    pending = set(ids)
    while pending and time.monotonic() < deadline:
        _, _, reply = request(base, "GET", "/jobs")
        pending = {j["id"] for j in reply["jobs"] if j["state"] in ("queued", "running")}
        time.sleep(0.2)
    all_done = time.perf_counter() - start
    _, _, reply = request(base, "GET", "/jobs")
    states = {}
    for j in reply["jobs"]:
        states[j["state"]] = states.get(j["state"], 0) + 1
    with urllib.request.urlopen(base + "/metrics", timeout=30) as res:
        metrics = res.read().decode()
    rss = next((float(l.split()[-1]) for l in metrics.splitlines()
                if l.startswith("isostream_peak_rss_bytes")), float("nan"))

    n = len(submit_lat) + len(status_lat)
    print(f"clients {args.clients}, submissions {len(submit_lat)} (accepted {len(ids)}), "
          f"status requests {len(status_lat)}, errors {len(errors)}")
    print(f"requests: {requests_done:.2f} s, {n / requests_done:.0f} requests/s")
    for name, lat in (("POST /jobs", submit_lat), ("GET status", status_lat)):
        if lat:
            print(f"{name}: p50 {pct(lat, 50):.1f} ms, p95 {pct(lat, 95):.1f} ms, "
                  f"p99 {pct(lat, 99):.1f} ms, max {max(lat) * 1000:.1f} ms, "
                  f"mean {statistics.mean(lat) * 1000:.1f} ms")
    print(f"all jobs finished after {all_done:.2f} s: {states}; "
          f"service peak RSS {rss / 2**20:.1f} MiB")
    if errors:
        print("first errors:", errors[:3])
    if errors or pending or len(ids) != args.submissions:
        sys.exit(1)


if __name__ == "__main__":
    main()
