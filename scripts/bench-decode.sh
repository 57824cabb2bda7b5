#!/usr/bin/env bash
# Whole-file decode speed (issue 47): `cbdam extract` of a repository to a float32 GeoTIFF on
# tmpfs, two binaries alternated, on one core (taskset -c 0) and on every core with
# RAYON_NUM_THREADS=1 and =all; prints the medians of the CPU time (perf's task-clock), the wall
# time and the page faults, and M samples/s; the outputs of the two binaries must be
# byte-identical (SHA-256), or the script fails.
#
#   OLD=/tmp/cbdam-main NEW=target/release/cbdam scripts/bench-decode.sh REPO.cbdam…
#   RUNS=9 OLD=… NEW=… scripts/bench-decode.sh etopo1.cbdam s.cbdam
#
# Make the repositories with e.g. `cbdam build data/etopo5_global.tif -o etopo1.cbdam
# --max-error 1`, or the 8193² synthetic: `cbdam synth --size 8193 -o s.f32 && cbdam build s.f32
# --size 8193x8193 -o s.cbdam --max-error 1`. On a loaded machine only the CPU times compare;
# the 1-vs-all-threads wall ratio (the parallel speed-up) needs an idle one.
#
# Environment: OLD, NEW (binaries; NEW defaults to target/release/cbdam), RUNS (default 7),
# OUT (output directory, default /dev/shm: a disk's fsync would be timed too).
set -euo pipefail
NEW=${NEW:-target/release/cbdam}
OLD=${OLD:?set OLD to the binary to compare with}
RUNS=${RUNS:-7}
OUT=${OUT:-/dev/shm}
CORES=$(nproc)
[ $# -ge 1 ] || { echo "usage: OLD=… NEW=… $0 REPO.cbdam…" >&2; exit 2; }
command -v perf >/dev/null || { echo "$0: needs perf (perf stat -e task-clock)" >&2; exit 2; }
TMP=$(mktemp -d)
trap 'rm -rf "$TMP" "$OUT"/bench-decode-$$-*' EXIT

# run LABEL BIN REPO CPUS THREADS: one extract; appends "cpu_ms wall_s faults" to $TMP/LABEL.
run() {
  local label=$1 bin=$2 repo=$3 cpus=$4 threads=$5 out="$OUT/bench-decode-$$-$1.tif"
  local t0 t1
  t0=$(date +%s.%N)
  RAYON_NUM_THREADS=$threads perf stat -x, -e task-clock,page-faults -o "$TMP/ps" \
    taskset -c "$cpus" "$bin" extract "$repo" -o "$out" --quiet
  t1=$(date +%s.%N)
  local cpu faults
  cpu=$(grep task-clock "$TMP/ps" | cut -d, -f1)
  faults=$(grep page-faults "$TMP/ps" | cut -d, -f1)
  echo "$cpu $(echo "$t1 - $t0" | bc -l) $faults" >>"$TMP/$label"
  sha256sum <"$out" | cut -d' ' -f1 >"$TMP/$label.sha"
}

# median COLUMN FILE
median() { cut -d' ' -f"$1" "$2" | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }

for repo in "$@"; do
  # inspect's whole output first: `grep -m1` stops reading early, and under pipefail the
  # writer's SIGPIPE would end the script (a large repository's output).
  info=$("$NEW" inspect "$repo")
  samples=$(grep -m1 -oE '[0-9]+ ?× ?[0-9]+' <<<"$info" | tr -d ' ' | awk -F× '{print $1*$2}')
  echo "== $repo ($samples samples; $RUNS runs each, alternated; $CORES cores)"
  printf '%-4s %-10s %10s %10s %12s %10s\n' bin setting "cpu s" "wall s" "M samples/s" faults
  for setting in one-core:0:1 threads-1:0-$((CORES - 1)):1 threads-all:0-$((CORES - 1)):$CORES; do
    IFS=: read -r name cpus threads <<<"$setting"
    rm -f "$TMP"/old-* "$TMP"/new-*
    for _ in $(seq "$RUNS"); do
      run "old-$name" "$OLD" "$repo" "$cpus" "$threads"
      run "new-$name" "$NEW" "$repo" "$cpus" "$threads"
    done
    cmp -s "$TMP/old-$name.sha" "$TMP/new-$name.sha" ||
      { echo "$repo: the two binaries' outputs differ" >&2; exit 1; }
    for b in old new; do
      f="$TMP/$b-$name"
      cpu=$(median 1 "$f")
      wall=$(median 2 "$f")
      printf '%-4s %-10s %10.3f %10.3f %12.1f %10s\n' "$b" "$name" "$(echo "$cpu / 1000" | bc -l)" \
        "$wall" "$(echo "$samples / $wall / 1000000" | bc -l)" "$(median 3 "$f")"
    done
  done
  echo "(outputs identical: $(cat "$TMP/new-threads-all.sha"))"
done
