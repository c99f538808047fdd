#!/usr/bin/env bash
# Runs the pipeline on the simulator: sonar-sim on a pseudo-terminal, sonar-driver reading it and
# publishing over iceoryx2 (printing each reading). Ctrl-C stops both.
# Usage: scripts/demo.sh [scene] [speed]     scene: room|corner|obstacle|two-obstacles|FILE
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-room}
speed=${2:-1}
cargo build --release --bins --quiet
bin=target/release

out=$(mktemp)
"$bin/sonar-sim" --scene "$scene" --speed "$speed" >"$out" &
sim=$!
trap 'kill $sim 2>/dev/null; wait $sim 2>/dev/null; rm -f "$out"' EXIT
for _ in $(seq 100); do
  grep -q '^PTY ' "$out" && break
  kill -0 $sim 2>/dev/null || { echo "simulator failed to start" >&2; exit 1; }
  sleep 0.05
done
pty=$(sed -n 's/^PTY //p' "$out" | head -n1)
[ -n "$pty" ] || { echo "simulator printed no PTY path" >&2; exit 1; }
echo "simulator ($scene, speed $speed) on $pty; driver starting — Ctrl-C to stop" >&2
"$bin/sonar-driver" --port "$pty" --print
