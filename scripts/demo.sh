#!/usr/bin/env bash
# The whole pipeline on the simulator, with the terminal viewer in front: sonar-sim on a
# pseudo-terminal, sonar-driver, sonar-fusion and sonar-viewer as separate processes, started and
# supervised by sonar-pipeline with examples/sonar.toml. `q` (or Ctrl-C) stops everything.
#
# Usage: scripts/demo.sh [sonar-pipeline flags]
#   scripts/demo.sh                                   # the small square room, real time
#   scripts/demo.sh --scene obstacle --scan=-45..45 --speed 5
#   scripts/demo.sh --preset paper                    # the paper's method exactly as written
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v cargo >/dev/null; then
  echo "cargo not found: install Rust first (https://rustup.rs), then run this again" >&2
  exit 1
fi
echo "building (release; the first build takes a few minutes)…" >&2
cargo build --release --workspace --bins --quiet
exec target/release/sonar-pipeline --config examples/sonar.toml "$@"
