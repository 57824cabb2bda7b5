#!/usr/bin/env bash
# The synthetic Earth benchmark (issue 46): writes `cbdam synth --earth` tiles (the whole Earth,
# or a box of it), builds the planet over the bundled ETOPO5, verifies it against its inputs,
# and prints wall time, CPU, peak RSS, the disk used at the peak, input samples/s and bits per
# sample; the tiles, the temporaries and the output are deleted after (KEEP=1 keeps the output).
#
#   scripts/bench-earth.sh                        # the whole Earth: 13 167 tiles, 38 GB of .hgt
#   BBOX=5,40,25,50 scripts/bench-earth.sh        # 183 tiles of Europe (0.53 GB)
#   CELLS=1000 MEMORY_LIMIT=1G scripts/bench-earth.sh
#
# Environment: CBDAM (binary, default target/release/cbdam), BBOX (W,S,E,N) or CELLS (first N
# land cells), MAX_ERROR (default 16), MEMORY_LIMIT (default 256M), WORK (an empty directory
# for the tiles and the output, default a new one in /var/tmp; the build's temporaries go to
# WORK/tmp), VERIFY (0 skips `cbdam verify`). The disk used at the peak is the file system's
# used bytes sampled every second less those before the build, so it counts the build's
# unlinked temporaries too — and anything else writing to that disk meanwhile.
set -euo pipefail
CBDAM=${CBDAM:-target/release/cbdam}
MAX_ERROR=${MAX_ERROR:-16}
MEMORY_LIMIT=${MEMORY_LIMIT:-256M}
ETOPO=${ETOPO:-data/etopo5_global.tif}
[ -x "$CBDAM" ] || { echo "$0: no binary at $CBDAM (cargo build --release -p cbdam)" >&2; exit 2; }
[ -f "$ETOPO" ] || { echo "$0: no ETOPO5 at $ETOPO (run from the repository root)" >&2; exit 2; }
BOX=()
[ -n "${BBOX:-}" ] && BOX=(--bbox "$BBOX")
[ -n "${CELLS:-}" ] && BOX+=(--cells "$CELLS")
OWN_WORK=0
if [ -z "${WORK:-}" ]; then
  WORK=$(mktemp -d /var/tmp/cbdam-earth.XXXXXX)
  OWN_WORK=1
fi
TILES=$WORK/tiles
OUT=$WORK/earth.cbdam
mkdir -p "$WORK/tmp"
cleanup() {
  [ -n "${SAMPLER:-}" ] && kill "$SAMPLER" 2>/dev/null || true
  rm -rf "$TILES" "$WORK/tmp" "$OUT.journal"
  [ "${KEEP:-0}" = 1 ] || rm -f "$OUT"
  [ "$OWN_WORK" = 1 ] && [ "${KEEP:-0}" != 1 ] && rmdir "$WORK" 2>/dev/null || true
}
trap cleanup EXIT

# used_bytes: the bytes in use on WORK's file system.
used_bytes() { df -B1 --output=used "$WORK" | tail -1 | tr -d ' '; }

# How many tiles, and whether they fit: each is 1201² i16 (2 884 802 bytes).
cells=$("$CBDAM" synth --earth "$WORK/count" "${BOX[@]}" --dry-run 2>/dev/null | grep -oE '^[0-9]+' | head -1 || true)
free=$(df -B1 --output=avail "$WORK" | tail -1 | tr -d ' ')
if [ -n "$cells" ] && [ $((cells * 2884802 * 5 / 4)) -gt "$free" ]; then
  echo "$0: $cells tiles need about $((cells * 2884802 / 1000000000)) GB (and a quarter again for the build);" \
    "$((free / 1000000000)) GB free in $WORK — name a box (BBOX=…, CELLS=…) or another WORK" >&2
  exit 2
fi

echo "== generating the tiles in $TILES"
/usr/bin/time -f "synth: %e s wall, %U s user, %S s sys" "$CBDAM" synth --earth "$TILES" "${BOX[@]}"
tiles=$(find "$TILES" -name '*.hgt' | wc -l)
samples=$((tiles * 1201 * 1201))
tile_bytes=$(du -sb "$TILES" | cut -f1)
echo "$tiles tiles, $samples input samples, $((tile_bytes / 1000000)) MB"

before=$(used_bytes)
echo "$before" >"$WORK/peak"
(while sleep 1; do
  u=$(used_bytes)
  [ "$u" -gt "$(cat "$WORK/peak")" ] && echo "$u" >"$WORK/peak"
done) &
SAMPLER=$!

echo "== building (--max-error $MAX_ERROR --memory-limit $MEMORY_LIMIT)"
TMPDIR=$WORK/tmp /usr/bin/time -o "$WORK/build.time" -f "%e %U %S %M" \
  "$CBDAM" build "$TILES" "$ETOPO" --planet --max-error "$MAX_ERROR" \
  --memory-limit "$MEMORY_LIMIT" --timings -o "$OUT"
kill "$SAMPLER" 2>/dev/null || true
SAMPLER=
read -r wall user sys rss_kib <"$WORK/build.time"
peak=$(cat "$WORK/peak")
bytes=$(stat -c %s "$OUT")

verify_s=skipped
if [ "${VERIFY:-1}" != 0 ]; then
  echo "== verifying"
  TMPDIR=$WORK/tmp /usr/bin/time -o "$WORK/verify.time" -f "%e %U %S %M" \
    "$CBDAM" verify "$OUT" --against "$TILES" "$ETOPO" --memory-limit "$MEMORY_LIMIT"
  read -r vwall vuser vsys vrss <"$WORK/verify.time"
  verify_s="$vwall s wall, $(echo "$vuser + $vsys" | bc) CPU-s, $((vrss / 1024)) MiB peak"
fi

cpu=$(echo "$user + $sys" | bc)
echo "== the synthetic Earth: $tiles tiles, $samples input samples (ETOPO5 underneath)"
echo "build:     $wall s wall, $cpu CPU-s ($user user + $sys sys), peak RSS $((rss_kib / 1024)) MiB (limit $MEMORY_LIMIT)"
printf 'speed:     %.2f M input samples/s wall, %.2f M per CPU-second\n' \
  "$(echo "$samples / $wall / 1000000" | bc -l)" "$(echo "$samples / $cpu / 1000000" | bc -l)"
echo "disk:      $((tile_bytes / 1000000)) MB of tiles; at the peak $(((peak - before) / 1000000)) MB more (temporaries, journal, output)"
printf 'output:    %d bytes, %.4f bits per input sample\n' "$bytes" "$(echo "$bytes * 8 / $samples" | bc -l)"
echo "verify:    $verify_s"
