#!/usr/bin/env bash
# Runs every cargo-fuzz target for a while (default 60 s each). Needs cargo-fuzz
# (`cargo install cargo-fuzz`); the machine's stable toolchain is used with RUSTC_BOOTSTRAP=1
# because libFuzzer's sanitizer flags are nightly-only. Seeds come from the test fixtures.
#   tools/fuzz.sh [seconds-per-target]
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
secs="${1:-60}"
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
export RUSTC_BOOTSTRAP=1
mkdir -p corpus/volume_formats corpus/mesh_formats
# Seed the mesh corpus with the golden fixtures (first byte selects the format).
for f in ../crates/smesh/tests/data/*.sma; do [ -f "$f" ] && { printf '\000'; cat "$f"; } > "corpus/mesh_formats/$(basename "$f")"; done
for f in ../crates/smesh/tests/data/*.smb; do [ -f "$f" ] && { printf '\001'; cat "$f"; } > "corpus/mesh_formats/$(basename "$f")"; done
for target in volume_formats mesh_formats; do
  echo "== fuzzing $target for ${secs}s"
  cargo fuzz run "$target" "corpus/$target" -- -max_total_time="$secs" -rss_limit_mb=2048 -max_len=65536
done
echo "fuzz: no crash found"
