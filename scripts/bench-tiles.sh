#!/usr/bin/env bash
# Benchmark of a tile mosaic build (issue 20): a synthetic grid of N × N int16 GeoTIFF tiles of
# (T+1)² samples sharing their edges, built with --timings under /usr/bin/time -v, against the
# same grid as one int16 GeoTIFF; the two repositories must be byte-identical. Prints samples/s,
# tiles/s and peak RSS of each build, then deletes everything it generated.
#
#   scripts/bench-tiles.sh                      # 16 × 16 tiles of 1025² (16385², 268 M samples)
#   N=8 T=512 LIMIT=1G scripts/bench-tiles.sh   # smaller, under --memory-limit 1G
#   LIMIT=512M scripts/bench-tiles.sh           # lattice (5-6 B a point) past the limit: mapped
#   N=16 T=4096 MIRRORED=1 LIMIT=2G scripts/bench-tiles.sh
#       # issue 20's 4.3 G-sample benchmark: 256 tiles of 4097², 8.6 GB, and about 26 GB of
#       # mapped lattice in TMPDIR; with MIRRORED=1 there is no single-file build to compare
#       # with (the grid would not fit in memory): the mosaic is built, inspected and verified.
#
# The tile build is then verified against its tiles (`cbdam verify --against`, block by block,
# under the same LIMIT), timed the same way.
#
# Environment: N, T (tile side between shared edges), LIMIT (--memory-limit, default: the
# build's own), DEFLATE=1 (Deflate-compressed tiles), MIRRORED=1 (`synth --mirrored`: every
# tile one terrain mirrored across its edges, generated tile by tile; no single-file build), CBDAM (binary, default
# target/release/cbdam: build it with `cargo build --release -p cbdam`), TMPDIR (where the
# tiles go: N·T² · 2 bytes twice, once tiled and once whole).
set -euo pipefail
N=${N:-16}
T=${T:-1024}
CBDAM=${CBDAM:-target/release/cbdam}
SIZE=$((N * T + 1))
SAMPLES=$((SIZE * SIZE))
COMPRESSION=plain
[ "${DEFLATE:-0}" = 1 ] && COMPRESSION=deflate
DIR=$(mktemp -d)
trap 'rm -rf "$DIR"' EXIT

MIRRORED=${MIRRORED:-0}
if [ "$MIRRORED" = 1 ]; then
    "$CBDAM" synth --size "$SIZE" --tiff "$COMPRESSION" --int16 --tiles "$N" --mirrored \
        -o "$DIR/tiles"
    echo "grid ${SIZE}² = $SAMPLES samples; $((N * N)) mirrored tiles of $((T + 1))²," \
        "$COMPRESSION; tiles $(du -sm "$DIR/tiles" | cut -f1) MB"
else
    "$CBDAM" synth --size "$SIZE" --tiff "$COMPRESSION" --int16 -o "$DIR/whole.tif"
    "$CBDAM" synth --size "$SIZE" --tiff "$COMPRESSION" --int16 --tiles "$N" -o "$DIR/tiles"
    echo "grid ${SIZE}² = $SAMPLES samples; $((N * N)) tiles of $((T + 1))², $COMPRESSION;" \
        "tiles $(du -sm "$DIR/tiles" | cut -f1) MB, whole $(du -sm "$DIR/whole.tif" | cut -f1) MB"
fi

run() { # name input
    local limit=()
    [ -n "${LIMIT:-}" ] && limit=(--memory-limit "$LIMIT")
    /usr/bin/time -v "$CBDAM" build "$DIR/$2" -o "$DIR/$1.cbdam" --max-error 1 --timings \
        "${limit[@]}" >"$DIR/$1.out" 2>"$DIR/$1.err"
    local wall rss
    wall=$(grep 'Elapsed (wall clock)' "$DIR/$1.err" | awk '{print $NF}' |
        awk -F: '{ if (NF == 3) print $1 * 3600 + $2 * 60 + $3; else print $1 * 60 + $2 }')
    rss=$(grep 'Maximum resident' "$DIR/$1.err" | awk '{print $NF}')
    echo "== $1: wall ${wall} s, peak RSS $((rss / 1024)) MiB," \
        "$(awk -v s="$SAMPLES" -v w="$wall" 'BEGIN { printf "%.2f M samples/s", s / w / 1e6 }')" \
        "$([ "$1" = tiles ] && awk -v n=$((N * N)) -v w="$wall" 'BEGIN { printf ", %.1f tiles/s", n / w }')"
    grep -h '^timings:' "$DIR/$1.err" || true
}
verify_tiles() {
    local limit=()
    [ -n "${LIMIT:-}" ] && limit=(--memory-limit "$LIMIT")
    local status=OK
    /usr/bin/time -v "$CBDAM" verify "$DIR/tiles.cbdam" --against "$DIR/tiles" "${limit[@]}" \
        >"$DIR/verify.out" 2>"$DIR/verify.err" || status=FAILED
    local wall rss
    wall=$(grep 'Elapsed (wall clock)' "$DIR/verify.err" | awk '{print $NF}' |
        awk -F: '{ if (NF == 3) print $1 * 3600 + $2 * 60 + $3; else print $1 * 60 + $2 }')
    rss=$(grep 'Maximum resident' "$DIR/verify.err" | awk '{print $NF}')
    echo "== verify: $status, wall ${wall} s, peak RSS $((rss / 1024)) MiB," \
        "$(awk -v s="$SAMPLES" -v w="$wall" 'BEGIN { printf "%.2f M samples/s", s / w / 1e6 }')"
    grep -h '^decoded in\|^nodata mask\|^cbdam: error' "$DIR/verify.out" "$DIR/verify.err" || true
    awk '/^ *[0-9]+ +[0-9]+ +[0-9]+ +[0-9]+ /' "$DIR/verify.out" | tail -n 1
    [ "$status" = OK ]
}
if [ "$MIRRORED" = 1 ]; then
    run tiles tiles
    "$CBDAM" inspect "$DIR/tiles.cbdam" | head -n 5
    verify_tiles
    exit 0
fi
run whole whole.tif
run tiles tiles
if cmp -s "$DIR/whole.cbdam" "$DIR/tiles.cbdam"; then
    echo "repositories byte-identical ($(stat -c %s "$DIR/tiles.cbdam") bytes)"
else
    echo "repositories DIFFER" >&2
    exit 1
fi
verify_tiles
