#!/usr/bin/env bash
# The benchmark suite (issue 13): builds the release binaries it needs, runs every section and
# writes each section's figures, with the date, machine, load and command, into its block of
# docs/benchmarks.md (between `<!-- bench.sh SECTION begin/end -->`).
#
#   scripts/bench.sh                     # every section, about 12 minutes on 2 cores after the build
#   scripts/bench.sh ipc latency         # only these sections (the others' blocks stay)
#   BENCH_NO_DOC=1 scripts/bench.sh ...  # print only, leave docs/benchmarks.md alone
#   FIXED_WORKLOAD=path scripts/bench.sh instructions   # instruction counts of another build
#
# Sections (`sonar-bench --help` and each subcommand's --help say more; the doc says what each
# figure means):
#   ipc           snapshot delivery 64 KiB–16 MiB, iceoryx2 against a Unix socket with bincode
#   latency       reading line on the serial line → snapshot visible, at 400², 1024², 2048²
#   throughput    lossless throughput and the fused rate at 2× and 4× that, per grid size, for a
#                 standing head and a moving robot
#   idle          CPU and wake-ups/s of every process of an idle pipeline over 60 s
#   memory        RSS and shared memory per grid size with 1 and 6 grid subscribers
#   instructions  callgrind instruction counts of fusing and snapshotting a fixed workload, at the
#                 head's pace and at replay pace (needs valgrind; stable on a loaded machine, so the
#                 figures to compare against)
#   mrpt          our engine against MRPT 2.5's COccupancyGridMap2D on the same readings, in one
#                 process, interleaved, per grid size (a standing head, three viewpoints, one, and a
#                 robot scanning while it drives): time per reading, instructions (valgrind),
#                 both maps scored against the scene. Installs Debian's libmrpt-dev (apt-get, as
#                 root) and builds bench/mrpt-peer/, a crate outside the workspace; not run by CI
#                 and not part of the default set (`scripts/bench.sh mrpt`)
set -euo pipefail
cd "$(dirname "$0")/.."

ALL=(ipc latency throughput idle memory instructions)
# Sections run only when named: they install system packages.
OPTIONAL=(mrpt)
SECTIONS=("$@")
[ ${#SECTIONS[@]} -eq 0 ] && SECTIONS=("${ALL[@]}")
for s in "${SECTIONS[@]}"; do
  [[ " ${ALL[*]} ${OPTIONAL[*]} " == *" $s "* ]] ||
    { echo "bench: unknown section '$s' (one of: ${ALL[*]} ${OPTIONAL[*]})" >&2; exit 2; }
done
wants() { [[ " ${SECTIONS[*]} " == *" $1 "* ]]; }

if wants instructions && [ -z "${FIXED_WORKLOAD:-}" ]; then
  command -v valgrind >/dev/null || { echo "bench: needs valgrind (apt-get install valgrind)" >&2; exit 1; }
fi
if wants mrpt; then
  command -v valgrind >/dev/null || { echo "bench: mrpt needs valgrind (apt-get install valgrind)" >&2; exit 1; }
  # MRPT 2.5 from Debian (bookworm). Its package has no pkg-config files: bench/mrpt-peer/build.rs
  # finds the headers in Debian's layout.
  if ! dpkg -s libmrpt-dev >/dev/null 2>&1; then
    [ "$(id -u)" = 0 ] || { echo "bench: mrpt needs root to apt-get install libmrpt-dev" >&2; exit 1; }
    echo "bench: installing libmrpt-dev" >&2
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libmrpt-dev >/dev/null
  fi
  echo "bench: building bench/mrpt-peer (release, into target/)" >&2
  (cd bench/mrpt-peer && cargo build --release --quiet)
fi
# The instruction counts need only the example, mrpt its own crate; every other section runs the
# pipeline's binaries.
needs_pipeline=false
for s in "${SECTIONS[@]}"; do
  case $s in mrpt | instructions) ;; *) needs_pipeline=true ;; esac
done
if $needs_pipeline; then
  echo "bench: building the release binaries (only the packages the suite runs)" >&2
  cargo build --release --quiet -p sonar-bench -p sonar-fusion -p sonar-driver -p sonar-sim -p sonar-viewer --bins
fi
if wants instructions && [ -z "${FIXED_WORKLOAD:-}" ]; then
  cargo build --release --quiet -p sonar-fusion --example fixed_workload
fi
BENCH=target/release/sonar-bench
OUT=$(mktemp -d /tmp/sonar-bench.XXXXXX)
trap 'rm -rf "$OUT"' EXIT

# --- instruction counts (valgrind's callgrind) -------------------------------------------------
# Inclusive instructions of the function whose name matches $2 in profile $1 (0 if absent).
inclusive() {
  callgrind_annotate --inclusive=yes --threshold=100 "$1" 2>/dev/null |
    awk -v pat="$2" '$0 ~ pat && $0 !~ /=>/ { gsub(",", "", $1); print $1; found = 1; exit }
                     END { if (!found) print 0 }'
}
total() { callgrind_annotate "$1" 2>/dev/null | awk '/PROGRAM TOTALS/ { gsub(",", "", $1); print $1; exit }'; }
# Thousands separators, for the table.
human() { echo "$1" | sed ':a;s/\B[0-9]\{3\}\>/,&/;ta'; }
callgrind_case() { # label cells resolution readings pace [extra fixed_workload flags]
  local label=$1 cells=$2 resolution=$3 readings=$4 pace=$5 snapshots fuse snap
  shift 5
  local out="$OUT/cg.$cells.$readings.$pace.out" bin=${FIXED_WORKLOAD:-target/release/examples/fixed_workload}
  valgrind --tool=callgrind --callgrind-out-file="$out" "$bin" --cells "$cells" --resolution "$resolution" \
    --readings "$readings" --pace "$pace" "$@" >"$OUT/log" 2>&1 || { cat "$OUT/log" >&2; exit 1; }
  snapshots=$(grep -o '[0-9]* grid snapshots' "$OUT/log" | cut -d' ' -f1)
  fuse=$(inclusive "$out" 'fixed_workload::fuse')
  snap=$(inclusive "$out" 'fixed_workload::snapshot')
  # The stencil column: filling a parked sensor's stencil (`Stencil::extend`, the cells a reading
  # from there visits first; before issue 29's kernel change, `ConeCache::prepared_for`, the whole
  # stencil at once).
  # Per reading fused and per grid snapshot, and their ratio (at the head's pace a snapshot per
  # reading: issue 29 asks that it cost no more than the fuse).
  local per_reading=$((fuse / readings)) per_snapshot=$((snapshots > 0 ? snap / snapshots : 0))
  echo "| $label | $pace | $readings | $snapshots | $(human "$(total "$out")") | $(human "$fuse") | $(human "$snap") | $(human "$(inclusive "$out" 'fixed_workload::follow')") | $(human "$(inclusive "$out" 'fixed_workload::features_snapshot')") | $(human $per_reading) | $(human $per_snapshot) | $(awk -v s=$per_snapshot -v f=$per_reading 'BEGIN { printf "%.2f", (f > 0 ? s / f : 0) }') | $(human "$(inclusive "$out" 'kernel::Spans::new')") | $(human "$(inclusive "$out" 'kernel::Stencil::extend')") |"
}

# --- the sections -------------------------------------------------------------------------------
GRIDS=("400 0.02" "1024 0.01" "2048 0.01")
section_ipc() { "$BENCH" ipc; }
section_latency() {
  local header=--header
  for g in "${GRIDS[@]}"; do set -- $g; "$BENCH" latency --cells "$1" --resolution "$2" $header; header=; done
}
section_throughput() {
  local header=--header start head
  # A standing head (its sweeps repeat) and a moving robot (none does).
  for head in "" --moving; do
    for g in "${GRIDS[@]}"; do
      set -- $g
      case $1 in 400) start=2000 ;; *) start=500 ;; esac
      "$BENCH" throughput --cells "$1" --resolution "$2" --start-rate "$start" $head $header; header=
    done
  done
}
section_idle() { "$BENCH" idle --seconds 60; }
section_memory() {
  local header=--header
  for g in "${GRIDS[@]}"; do
    set -- $g
    for n in 1 6; do "$BENCH" memory --cells "$1" --resolution "$2" --subscribers "$n" $header; header=; done
  done
}
section_instructions() {
  echo "| case | pace | readings | grid snapshots | total | fuse | grid snapshots | features: follow | features snapshots | fuse per reading | grid snapshot each | snapshot ÷ fuse | row spans | stencil |"
  echo "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"
  for pace in replay head; do
    callgrind_case "400² × 2 cm" 400 0.02 500 $pace
    callgrind_case "1024² × 1 cm" 1024 0.01 500 $pace
    callgrind_case "2048² × 1 cm" 2048 0.01 250 $pace
  done
  callgrind_case "cold start, 1024² × 1 cm (no features)" 1024 0.01 50 replay --no-features --snapshot-every 1000
  echo
  echo "valgrind $(valgrind --version | sed 's/valgrind-//'), binary ${FIXED_WORKLOAD:-target/release/examples/fixed_workload}."
}

# Our engine against MRPT: timed rows per grid size, then callgrind's instructions per reading
# (one measured pass of the room's readings; the unmeasured warm-up pass is not counted, since
# only the measured calls go through measured_ours / measured_mrpt).
PEER=target/release/sonar-mrpt-peer
section_mrpt() {
  local header=--header
  for g in "${GRIDS[@]}"; do
    set -- $g
    "$PEER" --cells "$1" --resolution "$2" --passes 50 $header; header=
    # The generated scene from its first viewpoint alone: no move between the readings.
    "$PEER" --cells "$1" --resolution "$2" --passes 50 --scenes generated --views 1
    # The room scanned while the robot drives: every reading from a new position.
    "$PEER" --cells "$1" --resolution "$2" --passes 50 --scenes tour
  done
  echo
  echo "Instructions per reading (valgrind's callgrind, one measured pass after the unmeasured one; the room from its centre, and toured):"
  echo
  echo "| grid | scene | readings | ours | MRPT | MRPT ÷ ours |"
  echo "|---|---|--:|--:|--:|--:|"
  local out readings ours mrpt scene
  for scene in room tour; do
    for g in "${GRIDS[@]}"; do
      set -- $g
      out="$OUT/peer.$1.$scene.cg"
      valgrind --tool=callgrind --callgrind-out-file="$out" "$PEER" --cells "$1" --resolution "$2" \
        --passes 1 --scenes "$scene" >"$OUT/peer.log" 2>&1 || { cat "$OUT/peer.log" >&2; exit 1; }
      readings=$(grep -o '^| [^|]*| [^|]*| [0-9]* ×' "$OUT/peer.log" | grep -o '[0-9]* ×$' | cut -d' ' -f1)
      ours=$(inclusive "$out" 'sonar_mrpt_peer::measured_ours')
      mrpt=$(inclusive "$out" 'sonar_mrpt_peer::measured_mrpt')
      echo "| $1² × $(awk -v r="$2" 'BEGIN { print r * 100 }') cm | $scene | $readings | $(human $((ours / readings))) | $(human $((mrpt / readings))) | $(awk -v a="$mrpt" -v b="$ours" 'BEGIN { printf "%.2f×", a / b }') |"
    done
  done
  echo
  echo "MRPT $(dpkg-query -W -f='${Version}' libmrpt-dev), valgrind $(valgrind --version | sed 's/valgrind-//')."
}

MACHINE="$(nproc) CPUs ($(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')), Linux $(uname -r), $(rustc --version | cut -d' ' -f1-2), release profile"
COMMIT=$(git rev-parse --short HEAD)$(git diff --quiet HEAD -- . ':!docs' || echo "+changes")

# Replaces the block of section $1 in docs/benchmarks.md by file $2.
splice() {
  local begin="<!-- bench.sh $1 begin -->" end="<!-- bench.sh $1 end -->" doc=docs/benchmarks.md
  if ! grep -qxF "$begin" "$doc" || ! grep -qxF "$end" "$doc"; then
    echo "bench: $doc has no '$begin'/'$end' block; figures of $1 not written" >&2
    return
  fi
  awk -v b="$begin" -v e="$end" -v f="$2" '
    $0 == b { print; while ((getline line < f) > 0) print line; skip = 1; next }
    $0 == e { skip = 0 }
    !skip { print }' "$doc" >"$OUT/doc" && cat "$OUT/doc" >"$doc"
}

for s in "${SECTIONS[@]}"; do
  echo "bench: $s (load average $(cut -d' ' -f1-3 /proc/loadavg), $(date -u +%H:%M) UTC)" >&2
  if ! {
    echo
    echo "Measured $(date -u '+%Y-%m-%d %H:%M') UTC by \`scripts/bench.sh $s\` at $COMMIT on $MACHINE; load average at the start $(cut -d' ' -f1-3 /proc/loadavg)."
    echo
    "section_$s"
    echo
  } | tee "$OUT/$s.md"; then
    echo "bench: section $s failed; docs/benchmarks.md keeps its earlier figures" >&2
    exit 1
  fi
  [ -n "${BENCH_NO_DOC:-}" ] || splice "$s" "$OUT/$s.md"
done
