#!/usr/bin/env bash
# The real web-map clients against `cbdam serve` (run by scripts/test.sh after the browser
# viewer's test): CesiumJS on the quantized-mesh tiles and MapLibre GL JS on the terrarium tiles,
# offline in headless Chromium (scripts/web_maps_check.py says what is checked).
#
# Sets up what it needs like web-test.sh: Debian's chromium and npm (apt), websocket-client
# (pip, pinned) and the clients' npm packages (versions locked in scripts/web-maps/
# package-lock.json, installed once into target/web-maps-node). Where one cannot be set up it
# says so and skips, except under CI (CI set, and not false or 0), where that fails.
set -euo pipefail
cd "$(dirname "$0")/.."

under_ci() {
    case "${CI:-}" in
    "" | 0 | false | FALSE | False) return 1 ;;
    *) return 0 ;;
    esac
}
missing() {
    if under_ci; then
        echo "web-maps-test.sh: FAILED: $1; under CI a missing prerequisite fails the run" >&2
        exit 1
    fi
    echo "web-maps-test.sh: SKIPPED: $1" >&2
    exit 0
}

# PMTiles: `cbdam tiles -o OUT.pmtiles` read back by an independent reader, the `pmtiles`
# Python package (pip, pinned, installed once into target/web-maps-python), tile for tile
# against the directory export (scripts/web-maps/pmtiles_check.py). Needs no browser.
pm_py="${CARGO_TARGET_DIR:-target}/web-maps-python"
if [ -d "$pm_py/pmtiles" ] || python3 -m pip install --quiet --target "$pm_py" pmtiles==3.8.1; then
    pm_work="$(mktemp -d)"
    cargo build --quiet --bin cbdam
    cbdam="${CARGO_TARGET_DIR:-target}/debug/cbdam"
    "$cbdam" build data/jacksboro_mpl.tif -o "$pm_work/j.cbdam" --max-error 1 --quiet
    for format in "terrarium --image png" "terrain-rgb --image webp"; do
        # shellcheck disable=SC2086 # the format and its image flag, split on purpose
        "$cbdam" tiles "$pm_work/j.cbdam" --format $format -o "$pm_work/dir" --quiet
        # shellcheck disable=SC2086
        "$cbdam" tiles "$pm_work/j.cbdam" --format $format -o "$pm_work/j.pmtiles" --quiet
        PYTHONPATH="$pm_py" python3 scripts/web-maps/pmtiles_check.py "$pm_work/j.pmtiles" "$pm_work/dir"
        rm -rf "$pm_work/dir" "$pm_work/j.pmtiles"
    done
    # Leaf directories: an archive of every tile of levels 0…8 (87 381 entries, too many for
    # the root directory) written by cbdam's writer, read back tile for tile.
    cargo run --quiet -p cbdam-tiles --example pmtiles_many_tiles -- "$pm_work/many.pmtiles" 8
    PYTHONPATH="$pm_py" python3 scripts/web-maps/pmtiles_leaves_check.py "$pm_work/many.pmtiles" 8
    rm -rf "$pm_work"
elif under_ci; then
    echo "web-maps-test.sh: FAILED: pip install pmtiles==3.8.1 failed; under CI that fails the run" >&2
    exit 1
else
    echo "web-maps-test.sh: SKIPPED the PMTiles check: pip install pmtiles==3.8.1 failed" >&2
fi

chromium="${CBDAM_CHROMIUM:-/usr/lib/chromium/chromium}"
needs=()
[ -x "$chromium" ] || needs+=(chromium)
command -v npm >/dev/null 2>&1 || needs+=(npm)
if [ ${#needs[@]} -gt 0 ] && command -v apt-get >/dev/null 2>&1; then
    sudo=""
    [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && sudo="sudo -n"
    if [ "$(id -u)" -eq 0 ] || [ -n "$sudo" ]; then
        echo "web-maps-test.sh: installing ${needs[*]} for the web-map clients' test" >&2
        $sudo apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
            "${needs[@]}" >/dev/null
    fi
fi
[ -x "$chromium" ] || missing "no Chromium at $chromium (apt-get install chromium, or set CBDAM_CHROMIUM)"
command -v npm >/dev/null 2>&1 || missing "no npm to install cesium and maplibre-gl (apt-get install npm)"
if ! python3 -c 'import websocket' 2>/dev/null; then
    python3 -m pip install --quiet websocket-client==1.9.2
fi

# The clients, as locked; installed again only when the lock changes.
node_dir="${CARGO_TARGET_DIR:-target}/web-maps-node"
if ! cmp -s scripts/web-maps/package-lock.json "$node_dir/package-lock.json" \
    || [ ! -d "$node_dir/node_modules/cesium" ] || [ ! -d "$node_dir/node_modules/maplibre-gl" ] \
    || [ ! -d "$node_dir/node_modules/pmtiles" ]; then
    rm -rf "$node_dir"
    mkdir -p "$node_dir"
    cp scripts/web-maps/package.json scripts/web-maps/package-lock.json "$node_dir/"
    (cd "$node_dir" && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error) \
        || missing "npm ci of scripts/web-maps/package-lock.json failed (no registry?)"
fi

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
# The same leaf directories read by the npm `pmtiles` package (MapLibre's protocol's reader).
cargo run --quiet -p cbdam-tiles --example pmtiles_many_tiles -- "$work/many.pmtiles" 8
node scripts/web-maps/pmtiles_leaves_check.mjs "$node_dir/node_modules" "$work/many.pmtiles" 8
cargo run --quiet --bin cbdam -- build data/jacksboro_mpl.tif -o "$work/jacksboro.cbdam" \
    --max-error 1 --quiet
started=$(date +%s)
python3 scripts/web_maps_check.py "$work/jacksboro.cbdam" \
    "${CARGO_TARGET_DIR:-target}/debug/cbdam" "$node_dir"
echo "web-maps-test.sh: the clients' checks took $(($(date +%s) - started)) s" >&2
