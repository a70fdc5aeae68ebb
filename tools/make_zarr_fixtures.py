#!/usr/bin/env python3
"""Writes the Blosc frames and Zarr v2 / OME-Zarr v0.4 stores that isostream-volume's tests read.

The Rust tests only read the committed output (crates/volume/tests/data/zarr/); they never run
Python. Run this again only to change the fixtures, then commit what it writes:

    python3 -m venv /tmp/zv && /tmp/zv/bin/pip install "zarr<3" numcodecs numpy
    /tmp/zv/bin/python tools/make_zarr_fixtures.py

Made with zarr-python 2.18 and numcodecs 0.15 (c-blosc 1.21), the writer of most OME-Zarr v0.4
data. The values are deterministic (fixed seeds) but not every byte: gzip headers hold the time,
and c-blosc's threads store the blocks of a large frame in the order they finish (offsets that
do not increase, which the committed lz4_bitshuffle_t1_blocks and zstd_noshuffle_t8_blocks
have), so a re-run rewrites a few files with other bytes that decode to the same values.

blosc/   data_t{1,2,4,8}.raw   the uncompressed bytes (uint8, uint16, float32, float64: 4000 bytes)
         {cname}_{shuffle}_t{ts}.blosc        numcodecs.Blosc frames of those bytes, for every
                                              cname x shuffle x typesize (one block each)
         {cname}_{shuffle}_t{ts}_blocks.blosc frames of several blocks, the last one shorter:
                                              zstd (never split) of the same bytes, blocksize
                                              1024; blosclz, lz4, lz4hc and zlib (which enlarge
                                              split blocks) of 270000 bytes of block_data(),
                                              typesize 1 and 2
         memcpyed_t{ts}.blosc                 clevel 0: stored uncompressed (the memcpyed flag)
         random.raw, random.blosc             incompressible bytes: memcpyed by the compressor
stores/  ome_v04.zarr   OME-Zarr v0.4 image: uint16, two levels (s0 10x12x14, s1 10x6x7),
                        chunks 4x5x6, Blosc(lz4, byte shuffle) (numcodecs' default), "/" keys,
                        scale z 2.0 y 0.5 x 0.5 on s0 (s1: 2.0, 1.0, 1.0, translation 0 0.25 0.25);
                        the chunk (1, 0, 0) of s0 is all zero, so it is not written
         v2_*.zarr      bare arrays with other types, compressors, orders and key separators
                        (see ARRAYS below); values are value() below, a chunk with the fill value
                        left out where noted
"""

import json
import os
import shutil
import sys

import numcodecs
import numpy as np
import zarr
from numcodecs import Blosc

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "crates", "volume", "tests",
                   "data", "zarr")

SHUFFLES = {"noshuffle": Blosc.NOSHUFFLE, "shuffle": Blosc.SHUFFLE, "bitshuffle": Blosc.BITSHUFFLE}
CNAMES = ["blosclz", "lz4", "lz4hc", "zlib", "zstd"]
TYPES = {1: np.uint8, 2: np.uint16, 4: np.float32, 8: np.float64}


def frame_data(ts):
    """4000 bytes of smooth values plus a little noise: matches and literals for every codec."""
    rng = np.random.default_rng(ts)
    n = 4000 // ts
    i = np.arange(n)
    v = np.round(1000 * np.sin(i / 17.0)) + 2000 + rng.integers(0, 3, n)
    if ts == 1:
        v = v % 256
    return v.astype(TYPES[ts])


def block_data(ts):
    """270000 bytes, more than one block whatever the codec: value i is (i / 3) % 200 + i % 7
    (the Rust test computes the same)."""
    i = np.arange(270000 // ts)
    return ((i // 3) % 200 + i % 7).astype(TYPES[ts])


def blosc_frames():
    d = os.path.join(OUT, "blosc")
    os.makedirs(d)
    for ts in TYPES:
        data = frame_data(ts)
        with open(os.path.join(d, f"data_t{ts}.raw"), "wb") as f:
            f.write(data.tobytes())
        for cname in CNAMES:
            for sname, shuffle in SHUFFLES.items():
                variants = [("", data, 0, 5)]
                if cname == "zstd":
                    # Not split, so blosc keeps a forced block size: 3 blocks and a leftover.
                    variants.append(("_blocks", data, 1024, 5))
                elif ts <= 2:
                    # Split codecs enlarge blocks to 64 KiB x typesize at least, "HCR" codecs
                    # (lz4hc, zlib) twice more above level 1: more data, and level 1 for those.
                    hcr = cname in ("lz4hc", "zlib")
                    variants.append(("_blocks", block_data(ts), 0, 1 if hcr else 5))
                for suffix, values, blocksize, clevel in variants:
                    codec = Blosc(cname=cname, clevel=clevel, shuffle=shuffle, blocksize=blocksize)
                    frame = codec.encode(values)
                    nbytes, bsize = int.from_bytes(frame[4:8], "little"), int.from_bytes(frame[8:12], "little")
                    assert suffix == "" or nbytes > bsize, (cname, ts, "one block")
                    assert np.array_equal(np.frombuffer(codec.decode(frame), values.dtype), values)
                    with open(os.path.join(d, f"{cname}_{sname}_t{ts}{suffix}.blosc"), "wb") as f:
                        f.write(frame)
        with open(os.path.join(d, f"memcpyed_t{ts}.blosc"), "wb") as f:
            f.write(Blosc(cname="lz4", clevel=0, shuffle=Blosc.SHUFFLE).encode(data))
    noise = np.random.default_rng(99).integers(0, 256, 3000).astype(np.uint8)
    frame = Blosc(cname="lz4", clevel=9, shuffle=Blosc.NOSHUFFLE).encode(noise)
    assert frame[2] & 0x2, "incompressible data should be stored memcpyed"
    with open(os.path.join(d, "random.raw"), "wb") as f:
        f.write(noise.tobytes())
    with open(os.path.join(d, "random.blosc"), "wb") as f:
        f.write(frame)


def value(z, y, x, signed):
    """The stores' voxel values; the Rust tests compute the same."""
    v = (z * 31 + y * 7 + x * 3) % 101
    return v - 50 if signed else v


def volume(shape, dtype):
    z, y, x = np.indices(shape[-3:])
    signed = np.dtype(dtype).kind in "if"
    return value(z, y, x, signed).astype(dtype).reshape(shape)


def ome_v04():
    path = os.path.join(OUT, "stores", "ome_v04.zarr")
    store = zarr.DirectoryStore(path, dimension_separator="/")
    root = zarr.group(store=store)
    s0 = (volume((10, 12, 14), np.uint16) * 600).astype(np.uint16)
    s0[4:8, 0:5, 0:6] = 0  # chunk (1, 0, 0): left out (write_empty_chunks=False)
    s1 = s0[:, ::2, ::2]
    for name, data in (("s0", s0), ("s1", s1)):
        root.create_dataset(name, data=data, chunks=(4, 5, 6), compressor=Blosc(),
                            write_empty_chunks=False, dimension_separator="/")
    axes = [{"name": n, "type": "space", "unit": "micrometer"} for n in "zyx"]
    root.attrs["multiscales"] = [{
        "version": "0.4",
        "name": "fixture",
        "axes": axes,
        "datasets": [
            {"path": "s0", "coordinateTransformations": [{"type": "scale", "scale": [2.0, 0.5, 0.5]}]},
            {"path": "s1", "coordinateTransformations": [
                {"type": "scale", "scale": [2.0, 1.0, 1.0]},
                {"type": "translation", "translation": [0.0, 0.25, 0.25]}]},
        ],
        "type": "stride",
    }]
    assert not os.path.exists(os.path.join(path, "s0", "1", "0", "0"))


# name: (shape, chunks, numpy dtype, compressor, order, separator, fill_value, chunk left out)
ARRAYS = {
    "v2_zlib_be_f4": ((6, 7, 8), (3, 4, 5), ">f4", numcodecs.Zlib(level=3), "C", ".", "NaN",
                      (0, 1, 0)),
    "v2_gzip_order_f_i2": ((6, 7, 8), (3, 4, 5), "<i2", numcodecs.GZip(level=5), "F", ".", 0, None),
    "v2_zstd_u1": ((5, 6, 7), (2, 3, 4), "|u1", numcodecs.Zstd(level=3), "C", "/", 7, (1, 1, 1)),
    "v2_lz4_u8": ((5, 6, 7), (2, 3, 4), "<u8", numcodecs.LZ4(), "C", ".", 0, None),
    "v2_raw_i4_4d": ((1, 5, 6, 7), (1, 2, 3, 4), "<i4", None, "C", ".", None, None),
    "v2_blosc_zstd_bitshuffle_f8": ((5, 6, 7), (2, 3, 4), "<f8",
                                    Blosc(cname="zstd", clevel=3, shuffle=Blosc.BITSHUFFLE), "C",
                                    "/", -1.5, (0, 0, 1)),
    "v2_blosc_blosclz_shuffle_be_u2": ((5, 6, 7), (2, 3, 4), ">u2",
                                       Blosc(cname="blosclz", clevel=5, shuffle=Blosc.SHUFFLE),
                                       "C", ".", 0, None),
}


def bare_arrays():
    for name, (shape, chunks, dtype, comp, order, sep, fill, missing) in ARRAYS.items():
        path = os.path.join(OUT, "stores", name + ".zarr")
        data = volume(shape, np.dtype(dtype))
        if missing is not None:
            sl = tuple(slice(i * c, (i + 1) * c) for i, c in zip(missing, chunks[-3:]))
            data[(Ellipsis,) + sl] = np.nan if fill == "NaN" else fill
        store = zarr.DirectoryStore(path, dimension_separator=sep)
        a = zarr.create(shape=shape, chunks=chunks, dtype=dtype, compressor=comp, order=order,
                        store=store, fill_value=np.nan if fill == "NaN" else fill,
                        write_empty_chunks=False, dimension_separator=sep)
        a[...] = data
        meta = json.load(open(os.path.join(path, ".zarray")))
        assert meta["order"] == order and meta["dtype"] == dtype, meta
        if missing is not None:
            key = sep.join(str(i) for i in ((0,) * (len(shape) - 3) + missing))
            assert not os.path.exists(os.path.join(path, key)), key


def main():
    if os.path.exists(OUT):
        shutil.rmtree(OUT)
    blosc_frames()
    ome_v04()
    bare_arrays()
    print(f"zarr {zarr.__version__}, numcodecs {numcodecs.__version__}: wrote {os.path.normpath(OUT)}",
          file=sys.stderr)


if __name__ == "__main__":
    main()
