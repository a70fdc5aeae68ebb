#!/usr/bin/env python3
"""End-to-end check of isostream's Zarr reader against zarr-python (an independent writer).

Converts the engine CT (../shared/data/engine/engine_256x256x128_uint8.raw) into OME-Zarr v0.5
stores written by zarr-python 3, runs the release binary `isostream run` on each and on the raw
twin with the same settings, and checks that the run summaries agree (faces extracted and
written, vertices written, dims) and that the output meshes are byte-identical after the SMB
header comments (which name the input path). The meshes must
match exactly: the reader hands the pipeline the same voxels in the same order, and everything
downstream is deterministic.

Stores (under --work, default /tmp/isostream-zarr-check):
  engine_sharded.ome.zarr  shards of 64x128x128, inner chunks 32x64x64, zstd, crc32c index
  engine_gzip.ome.zarr     plain 32x64x64 chunks, gzip
  engine_v2keys.zarr       a bare array (no OME group), v2 "." chunk keys, big-endian uint16
                           with a transpose codec, chunks of 16 slices

    pip install -r tools/requirements.txt     # zarr, numpy
    export CARGO_TARGET_DIR=/work/target-zarr; cargo build --release
    python3 tools/zarr_check.py [--binary PATH] [--work DIR] [--mode rate|none]

Exit status 0 when every store agrees with the raw twin, 1 otherwise.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import BytesCodec, Crc32cCodec, GzipCodec, TransposeCodec, ZstdCodec

ROOT = Path(__file__).resolve().parent.parent
RAW = ROOT.parent / "shared" / "data" / "engine" / "engine_256x256x128_uint8.raw"
DIMS = (256, 256, 128)  # x, y, z as in the job file
ISO = 70.0
SPACING = (1.0, 1.0, 1.0)


def volume() -> np.ndarray:
    """The engine as a Zarr-order (z, y, x) array."""
    data = np.fromfile(RAW, dtype=np.uint8)
    return data.reshape(DIMS[2], DIMS[1], DIMS[0])


def ome_group(path: Path, data: np.ndarray, **array_kwargs) -> None:
    """An OME-Zarr v0.5 image with one level "0" (axes c, z, y, x; c of size 1)."""
    root = zarr.open_group(str(path), mode="w", zarr_format=3)
    root.attrs["ome"] = {
        "version": "0.5",
        "multiscales": [
            {
                "name": "engine",
                "axes": [
                    {"name": "c", "type": "channel"},
                    {"name": "z", "type": "space"},
                    {"name": "y", "type": "space"},
                    {"name": "x", "type": "space"},
                ],
                "datasets": [
                    {
                        "path": "0",
                        "coordinateTransformations": [
                            {"type": "scale", "scale": [1.0, *SPACING[::-1]]}
                        ],
                    }
                ],
            }
        ],
    }
    arr = root.create_array(
        "0",
        shape=(1, *data.shape),
        dtype=data.dtype,
        dimension_names=["c", "z", "y", "x"],
        **array_kwargs,
    )
    arr[0] = data


def write_stores(work: Path, data: np.ndarray) -> dict:
    stores = {}
    p = work / "engine_sharded.ome.zarr"
    ome_group(
        p,
        data,
        shards=(1, 64, 128, 128),
        chunks=(1, 32, 64, 64),
        compressors=[ZstdCodec(level=3)],
    )
    stores["sharded+zstd (OME)"] = p
    p = work / "engine_gzip.ome.zarr"
    ome_group(p, data, chunks=(1, 32, 64, 64), compressors=[GzipCodec(level=5)])
    stores["gzip (OME)"] = p
    p = work / "engine_v2keys.zarr"
    arr = zarr.create_array(
        str(p),
        shape=data.shape,
        dtype=np.uint16,
        chunks=(16, 100, 100),
        chunk_key_encoding={"name": "v2", "separator": "."},
        filters=[TransposeCodec(order=(2, 0, 1))],
        serializer=BytesCodec(endian="big"),
        compressors=[ZstdCodec(level=1), Crc32cCodec()],
        fill_value=0,
    )
    arr[:] = data.astype(np.uint16)
    stores["bare array, v2 keys, transpose, big-endian u16 (zstd + crc32c)"] = p
    return stores


def job(work: Path, name: str, input_toml: str, mode: str) -> Path:
    out = work / f"{name}.smb"
    simplify = 'mode = "rate"\nrate = 0.2' if mode == "rate" else 'mode = "none"'
    text = f"""[input]
{input_toml}

[extract]
iso = {ISO}

[simplify]
{simplify}

[output]
path = "{out}"
"""
    path = work / f"{name}.toml"
    path.write_text(text)
    return path


def smb_body(data: bytes) -> bytes:
    """An SMB file without its comments (they name the input path): 4-byte magic, i32 comment
    count, (i32 length, bytes) per comment, then counts, box and elements (crates/smesh/FORMATS.md)."""
    count = int.from_bytes(data[4:8], "little")
    at = 8
    for _ in range(count):
        at += 4 + int.from_bytes(data[at : at + 4], "little")
    return data[at:]


def run(binary: Path, job_path: Path) -> dict:
    proc = subprocess.run(
        [str(binary), "run", str(job_path)],
        capture_output=True,
        text=True,
        env={**os.environ, "RUST_LOG": "warn"},
    )
    if proc.returncode != 0:
        raise RuntimeError(f"{job_path.name}: exit {proc.returncode}: {proc.stderr.strip()}")
    out = job_path.with_suffix(".smb")
    summary = json.loads(Path(str(out) + ".run.json").read_text())
    summary["_mesh"] = smb_body(out.read_bytes())
    return summary


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    ap.add_argument("--binary", type=Path, default=target / "release" / "isostream")
    ap.add_argument("--work", type=Path, default=Path("/tmp/isostream-zarr-check"))
    ap.add_argument("--mode", choices=["rate", "none"], default="rate")
    args = ap.parse_args()
    if not args.binary.is_file():
        sys.exit(f"{args.binary}: no release binary; run cargo build --release first")
    if not RAW.is_file():
        sys.exit(f"{RAW}: engine volume not found")
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)

    data = volume()
    stores = write_stores(args.work, data)
    raw_input = f'path = "{RAW}"\ndims = {list(DIMS)}\ndtype = "u8"'
    runs = {"raw twin": run(args.binary, job(args.work, "raw", raw_input, args.mode))}
    for i, (label, store) in enumerate(stores.items()):
        runs[label] = run(args.binary, job(args.work, f"zarr{i}", f'path = "{store}"', args.mode))

    keys = ["dims", "voxels", "faces_extracted", "faces_written", "vertices_written"]
    ref = runs["raw twin"]
    ok = True
    print(f"| input | {' | '.join(keys)} | peak RSS MiB | seconds | mesh |")
    print("|---" * (len(keys) + 4) + "|")
    for label, s in runs.items():
        same = all(s[k] == ref[k] for k in keys)
        mesh = "identical" if s["_mesh"] == ref["_mesh"] else "DIFFERENT"
        ok &= same and mesh == "identical"
        rss = (s.get("peak_rss_bytes") or 0) / 2**20
        values = " | ".join(str(s[k]) for k in keys)
        print(f"| {label} | {values} | {rss:.0f} | {s['seconds']:.2f} | {mesh} |")
    print("zarr check:", "all stores agree with the raw twin" if ok else "MISMATCH")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
