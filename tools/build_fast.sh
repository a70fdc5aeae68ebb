#!/usr/bin/env bash
# The fastest isostream binary for this machine: profile-guided optimisation (PGO) trained on
# three jobs on the bundled data, optionally for this CPU. The output bytes are those of `cargo
# build --release` (no fast-math anywhere; PGO and the target CPU change code layout and
# instruction choice, not floating-point results): the script checks that on the training jobs.
#
#   tools/build_fast.sh                 # PGO, portable x86-64: target/fast/release/isostream
#   tools/build_fast.sh --native        # PGO and -C target-cpu=native (runs on this CPU type only)
#
# Needs the toolchain's llvm-profdata (`rustup component add llvm-tools`, which the script runs)
# and ../shared/data (engine and bonsai) for training. Measured gains: docs/performance.md,
# "Thirteenth session".
set -euo pipefail
cd "$(dirname "$0")/.."

cpu_flags=""
if [[ "${1:-}" == "--native" ]]; then
    cpu_flags="-C target-cpu=native"
elif [[ -n "${1:-}" ]]; then
    echo "usage: tools/build_fast.sh [--native]" >&2
    exit 2
fi

data=../shared/data
for f in "$data/engine/engine_256x256x128_uint8.raw" "$data/bonsai/bonsai.vti"; do
    [[ -f "$f" ]] || { echo "error: training data $f is missing (clone ../shared beside the repository)" >&2; exit 1; }
done

rustup component add llvm-tools >/dev/null
sysroot=$(rustc --print sysroot)
profdata=$(find "$sysroot" -name llvm-profdata -type f | head -n 1)
[[ -x "$profdata" ]] || { echo "error: llvm-profdata not found under $sysroot (rustup component add llvm-tools)" >&2; exit 1; }

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/profiles"

echo "0/4 plain release build (the reference for the output bytes)" >&2
cargo build --release --bin isostream --target-dir target

echo "1/4 instrumented build" >&2
RUSTFLAGS="$cpu_flags -Cprofile-generate=$work/profiles" \
    cargo build --release --bin isostream --target-dir target/pgo-gen

echo "2/4 training: engine R = 0.2 and 0.01, bonsai R = 0.2 (two stages)" >&2
engine=$(realpath "$data/engine/engine_256x256x128_uint8.raw")
bonsai=$(realpath "$data/bonsai/bonsai.vti")
job() { # name input-toml-lines rate
    cat >"$work/$1.toml" <<EOF
[input]
$2
[extract]
iso = $3
[simplify]
mode = "rate"
rate = $4
[output]
path = "$work/$1.smb"
[log]
level = "warn"
EOF
}
job engine "path = \"$engine\"
dims = [256, 256, 128]
dtype = \"u8\"" 70.0 0.2
job engine_low "path = \"$engine\"
dims = [256, 256, 128]
dtype = \"u8\"" 70.0 0.01
job bonsai "path = \"$bonsai\"" 40.0 0.2
# Only the simplifier's runs count: the build scripts wrote profiles too.
rm -f "$work"/profiles/*
for j in engine engine_low bonsai; do
    target/pgo-gen/release/isostream run "$work/$j.toml" >&2
done

echo "3/4 merging profiles" >&2
"$profdata" merge -o "$work/isostream.profdata" "$work"/profiles/*.profraw

echo "4/4 optimised build" >&2
RUSTFLAGS="$cpu_flags -Cprofile-use=$work/isostream.profdata -Cllvm-args=-pgo-warn-missing-function=false" \
    cargo build --release --bin isostream --target-dir target/fast

for j in engine engine_low bonsai; do
    target/release/isostream run "$work/$j.toml" >/dev/null 2>&1
    mv "$work/$j.smb" "$work/$j.reference.smb"
    target/fast/release/isostream run "$work/$j.toml" >/dev/null 2>&1
    cmp -s "$work/$j.smb" "$work/$j.reference.smb" ||
        { echo "error: the fast build wrote other bytes than cargo build --release on $j" >&2; exit 1; }
done
echo "target/fast/release/isostream (same output bytes as target/release/isostream on the training jobs)" >&2
