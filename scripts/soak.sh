#!/usr/bin/env bash
# Soak: replays a recording at maximum speed, over and over, into a fusion engine and a viewer
# (in tmux) for SOAK_SECONDS (default 3600), and samples the resident memory of each process, the
# shared memory of the namespace and the fusion's counters every SOAK_SAMPLE seconds.
#
#   scripts/soak.sh [OUT_DIR]        # default: target/soak
#
# Writes OUT_DIR/memory.csv (one row per sample) and prints a summary (first, last, max RSS per
# process). The figures go in docs/reliability.md. Runs under `nice` so the machine stays usable.
set -euo pipefail
cd "$(dirname "$0")/.."

SECONDS_TOTAL=${SOAK_SECONDS:-3600}
SAMPLE=${SOAK_SAMPLE:-30}
READINGS=${SOAK_READINGS:-20000}
OUT=${1:-target/soak}
BIN=target/release
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

cargo build --release --bins --quiet
command -v tmux >/dev/null || { echo "soak: needs tmux for the viewer" >&2; exit 1; }

WORK=$(mktemp -d /tmp/sonar-soak.XXXXXX)
export SONAR_IOX_PREFIX="soak$$_"
export SONAR_IOX_ROOT="$WORK/iox"
export RUST_LOG=${RUST_LOG:-info}
TMUX_SOCKET="sonar-soak-$$"
PIDS=()

cleanup() {
  for pid in "${PIDS[@]}"; do kill "$pid" 2>/dev/null || true; done
  tmux -L "$TMUX_SOCKET" kill-server 2>/dev/null || true
  wait 2>/dev/null || true
  echo "soak: logs and recording in $WORK"
}
trap cleanup EXIT

# 1. A recording: the simulator at full speed through the driver, READINGS readings of the room.
"$BIN/sonar-sim" --scene room --speed max --link "$WORK/tty" >"$WORK/sim.out" 2>"$WORK/sim.log" &
PIDS+=($!)
for _ in $(seq 100); do [ -e "$WORK/tty" ] && break; sleep 0.1; done
"$BIN/sonar-driver" --port "$WORK/tty" >"$WORK/driver.log" 2>&1 &
PIDS+=($!)
echo "soak: recording $READINGS readings"
"$BIN/sonar-record" "$WORK/room.mcap" --max-readings "$READINGS" --progress-interval 60 2>"$WORK/record.log"
for pid in "${PIDS[@]}"; do kill "$pid" 2>/dev/null || true; done
wait 2>/dev/null || true
PIDS=()

# 2. The consumers: fusion (saving its map every 5 s) and the viewer in a detached tmux.
nice -n 10 "$BIN/sonar-fusion" --state-file "$WORK/map.state" 2>"$WORK/fusion.log" &
FUSION=$!
PIDS+=("$FUSION")
tmux -L "$TMUX_SOCKET" new-session -d -x 160 -y 50 \
  "env SONAR_IOX_PREFIX=$SONAR_IOX_PREFIX SONAR_IOX_ROOT=$SONAR_IOX_ROOT nice -n 10 $BIN/sonar-viewer --log-file $WORK/viewer.log"
sleep 2
VIEWER=$(pgrep -f "sonar-viewer --log-file $WORK/viewer.log" | head -1)

# 3. Replays back to back at maximum speed, without a rate ceiling, until the time is up.
(
  while true; do
    nice -n 10 "$BIN/sonar-replay" "$WORK/room.mcap" --speed max --max-message-rate 0 --readings-only \
      --linger 0 --no-progress 2>>"$WORK/replay.log" || true
  done
) &
REPLAYS=$!
PIDS+=("$REPLAYS")

rss_kib() { awk '/^VmRSS/ {print $2}' "/proc/$1/status" 2>/dev/null || echo 0; }
shm_kib() { du -sk /dev/shm 2>/dev/null | awk '{print $1}'; }

echo "elapsed_s,fusion_rss_kib,viewer_rss_kib,dev_shm_kib,replays" >"$OUT/memory.csv"
START=$(date +%s)
while true; do
  NOW=$(( $(date +%s) - START ))
  ROUNDS=$(grep -c "replay finished" "$WORK/replay.log" || true)
  echo "$NOW,$(rss_kib "$FUSION"),$(rss_kib "${VIEWER:-0}"),$(shm_kib),$ROUNDS" \
    >>"$OUT/memory.csv"
  kill -0 "$FUSION" 2>/dev/null || { echo "soak: the fusion died" >&2; exit 1; }
  [ "$NOW" -ge "$SECONDS_TOTAL" ] && break
  sleep "$SAMPLE"
done
kill "$REPLAYS"
pkill -P "$REPLAYS" sonar-replay 2>/dev/null || true
kill -TERM "$FUSION"
wait "$FUSION" || true
echo "soak: $(grep "fusion stopped" "$WORK/fusion.log" | tail -1 | sed 's/\x1b\[[0-9;]*m//g')"
awk -F, 'NR == 2 {f0 = $2; v0 = $3} NR > 1 {
  if ($2 > fm) fm = $2; if ($3 > vm) vm = $3; if ($4 > sm) sm = $4; f1 = $2; v1 = $3; n = $5; t = $1 }
  END { printf "soak: %d s, %d replays of the recording\n", t, n
        printf "  fusion RSS: first %d KiB, last %d KiB, max %d KiB\n", f0, f1, fm
        printf "  viewer RSS: first %d KiB, last %d KiB, max %d KiB\n", v0, v1, vm
        printf "  /dev/shm: max %d KiB\n", sm }' "$OUT/memory.csv"
