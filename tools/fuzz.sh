#!/usr/bin/env bash
# Runs every cargo-fuzz target for a while (default 60 s each). Needs cargo-fuzz
# (`cargo install cargo-fuzz`); the machine's stable toolchain is used with RUSTC_BOOTSTRAP=1
# because libFuzzer's sanitizer flags are nightly-only. Seeds come from the test fixtures.
#   tools/fuzz.sh [seconds-per-target]
set -euo pipefail
usage="usage: tools/fuzz.sh [seconds-per-target] (a whole number of seconds, 60 by default)"
# Arguments first, before anything is installed or built: `--help` ran `cargo install
# cargo-fuzz` and was then handed to libFuzzer as the seconds.
case "${1:-}" in
  -h|--help)
    echo "$usage"
    echo "Runs every cargo-fuzz target in fuzz/ for that long (installs cargo-fuzz if missing)."
    exit 0 ;;
esac
if [ $# -gt 1 ]; then
  echo "tools/fuzz.sh: at most one argument; $usage" >&2
  exit 2
fi
secs="${1-60}"
if ! [[ "$secs" =~ ^[0-9]+$ ]] || [ "$((10#$secs))" -eq 0 ]; then
  echo "tools/fuzz.sh: '$secs' is not a positive whole number of seconds; $usage" >&2
  exit 2
fi
secs="$((10#$secs))"
cd "$(dirname "$0")/../fuzz"
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
