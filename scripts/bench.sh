#!/usr/bin/env bash
# Instruction counts of the fusion engine on a fixed input (valgrind's callgrind): stable on a
# loaded machine, so a change compares against the figures recorded in docs/benchmarks.md.
#
#   scripts/bench.sh [BINARY]    # default: builds and uses fusion's `fixed_workload` example
#
# BINARY lets an older build be measured the same way (copy the example of another commit aside
# and pass it). Prints a Markdown table: per grid size, the instructions of the whole run, of
# fusing (the kernel and keeping the snapshot encoding up to date), of the snapshots (copying the
# cells out), of working out the cone's row spans and of building the stencil; and the cold start
# (a new engine and its first sweep at 1024² × 1 cm). Takes a few minutes (callgrind runs the code
# about 50× slower).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v valgrind >/dev/null || { echo "bench: needs valgrind (apt-get install valgrind)" >&2; exit 1; }

BIN=${1:-}
if [ -z "$BIN" ]; then
  cargo build --release --quiet -p sonar-fusion --example fixed_workload
  BIN=target/release/examples/fixed_workload
fi
OUT=$(mktemp -d /tmp/sonar-bench.XXXXXX)
trap 'rm -rf "$OUT"' EXIT

# Inclusive instructions of the function whose name matches $2 in profile $1 (0 if absent).
inclusive() {
  callgrind_annotate --inclusive=yes "$1" 2>/dev/null |
    awk -v pat="$2" '$0 ~ pat && $0 !~ /=>/ { gsub(",", "", $1); print $1; found = 1; exit }
                     END { if (!found) print 0 }'
}
total() { callgrind_annotate "$1" 2>/dev/null | awk '/PROGRAM TOTALS/ { gsub(",", "", $1); print $1; exit }'; }
# Thousands separators, for the table.
human() { echo "$1" | sed ':a;s/\B[0-9]\{3\}\>/,&/;ta'; }

echo "| case | readings | snapshots | total | fuse | snapshot | row spans | stencil |"
echo "|---|--:|--:|--:|--:|--:|--:|--:|"
run() { # label cells resolution readings snapshot_every
  local label=$1 out="$OUT/cg.$2.$4.out"
  valgrind --tool=callgrind --callgrind-out-file="$out" "$BIN" --cells "$2" --resolution "$3" \
    --readings "$4" --snapshot-every "$5" >"$OUT/log" 2>&1 || { cat "$OUT/log" >&2; exit 1; }
  echo "| $label | $4 | $(( $4 / $5 )) | $(human "$(total "$out")") | $(human "$(inclusive "$out" 'fixed_workload::fuse')") | $(human "$(inclusive "$out" 'fixed_workload::snapshot')") | $(human "$(inclusive "$out" 'kernel::Spans::new')") | $(human "$(inclusive "$out" 'ConeCache::prepared_for')") |"
}
run "400² × 2 cm" 400 0.02 500 5
run "1024² × 1 cm" 1024 0.01 500 5
run "2048² × 1 cm" 2048 0.01 250 5
run "cold start, 1024² × 1 cm" 1024 0.01 50 1000
