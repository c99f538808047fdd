#!/usr/bin/env bash
# The whole pipeline on the simulator, with the terminal viewer in front: sonar-sim on a
# pseudo-terminal, sonar-driver, sonar-fusion and sonar-viewer as separate processes, started and
# supervised by sonar-pipeline with examples/sonar.toml. `q` (or Ctrl-C) stops everything.
#
# Usage: scripts/demo.sh [sonar-pipeline flags]
#   scripts/demo.sh                                   # the small square room, real time
#   scripts/demo.sh --scene obstacle --scan=-45..45 --speed 5
#   scripts/demo.sh --preset paper                    # the paper's method exactly as written
#   scripts/demo.sh --config examples/corridor.toml   # another configuration instead of sonar.toml
#
# SONAR_DEMO_BIN_DIR=DIR runs the programs already built in DIR instead of building (the docs'
# command test runs the README's demo commands that way, against the debug build).
set -euo pipefail
cd "$(dirname "$0")/.."
bin_dir=${SONAR_DEMO_BIN_DIR:-}
if [ -z "$bin_dir" ]; then
  if ! command -v cargo >/dev/null; then
    echo "cargo not found: install Rust first (https://rustup.rs), then run this again" >&2
    exit 1
  fi
  echo "building (release; the first build takes a few minutes, longer on a small machine)…" >&2
  # cargo's own progress, so a long first build is seen to move.
  cargo build --release --workspace --bins
  bin_dir=target/release
fi
# examples/sonar.toml unless the flags name a configuration of their own.
config=(--config examples/sonar.toml)
for arg in "$@"; do
  case "$arg" in
    --config | --config=*) config=() ;;
  esac
done
exec "$bin_dir/sonar-pipeline" "${config[@]}" "$@"
