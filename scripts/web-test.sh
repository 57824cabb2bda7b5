#!/usr/bin/env bash
# The browser viewer's end-to-end test (run by scripts/test.sh after the workspace's tests):
# builds the web bundle (scripts/web-build.sh), builds a small repository with the cbdam binary,
# exports the viewer with `cbdam web-export` and drives headless Chromium against a loopback
# static server with Range support and `cbdam serve` (scripts/web_test.py): WebGPU on SwiftShader
# must converge and draw terrain over most of the frame (screenshot pixels checked), the same cut
# from both servers and as `cbdam render`; drag, wheel, keys, slider and pinch move the camera or
# the target, the URL hash restores the view, the server may go away and come back; without
# WebGPU flags the page must draw the same view through WebGL2 (the renderer's texture path), and
# with WebGL off too say that neither is there; decoding runs in Web Workers (and on the page with
# ?workers=0, to the same cut); the page's wasm32 decodes whole repositories (both coders, a
# planet) to the digest the native decoder gives; a camera flight (?flight=) plays to its end, at the cut
# `cbdam render` gives for its last camera, and a drag ends one early; a colour repository
# (?colour=) drapes red and blue over the same cut through both APIs; a small planet draws as a whole globe, centred, through WebGPU and
# through WebGL2.
# About 55 s once built on a loaded 2-core machine.
#
# Sets up what it needs like test.sh sets up lavapipe: Debian's chromium (apt) and
# websocket-client (pip, pinned). Where Chromium cannot be installed (no apt-get, no root/sudo),
# it says so and skips, except under CI (CI set, and not false or 0), where that fails.
set -euo pipefail
cd "$(dirname "$0")/.."

chromium="${CBDAM_CHROMIUM:-/usr/lib/chromium/chromium}"
if [ ! -x "$chromium" ] && command -v apt-get >/dev/null 2>&1; then
    sudo=""
    [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && sudo="sudo -n"
    if [ "$(id -u)" -eq 0 ] || [ -n "$sudo" ]; then
        echo "web-test.sh: installing Debian's chromium for the browser test" >&2
        $sudo apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
            chromium >/dev/null
    fi
fi
if [ ! -x "$chromium" ]; then
    case "${CI:-}" in
    "" | 0 | false | FALSE | False) ;;
    *)
        echo "web-test.sh: FAILED: no Chromium at $chromium and none could be installed" \
            "(apt-get install chromium, or set CBDAM_CHROMIUM); under CI a missing" \
            "prerequisite fails the run" >&2
        exit 1
        ;;
    esac
    echo "web-test.sh: SKIPPED: no Chromium at $chromium and none could be installed" \
        "(apt-get install chromium, or set CBDAM_CHROMIUM)" >&2
    exit 0
fi
if ! python3 -c 'import websocket' 2>/dev/null; then
    python3 -m pip install --quiet websocket-client==1.9.2
fi

scripts/web-build.sh target/web-bundle

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cargo run --quiet --bin cbdam -- build data/jacksboro_mpl.tif -o "$work/jacksboro.cbdam" \
    --max-error 1 --quiet
python3 scripts/web_test.py target/web-bundle "$work/jacksboro.cbdam" \
    "${CARGO_TARGET_DIR:-target}/debug/cbdam"
# A planet (ETOPO5 on a coarse lattice, K = 3: 1.6 M points, built in about 2 s): the
# page draws the whole globe, centred, through WebGPU and through WebGL2.
cargo run --quiet --bin cbdam -- build data/etopo5_global.tif --planet --planet-level 3 \
    -o "$work/earth.cbdam" --max-error 16 --quiet
python3 scripts/web_test.py --planet target/web-bundle "$work/earth.cbdam" \
    "${CARGO_TARGET_DIR:-target}/debug/cbdam"
# wasm32 decodes what native decodes, bit for bit: the page digests whole repositories (the
# default coder's, the same surface coded by fast-rice, adaptive-grid and adaptive-inband; an
# RMS build with a quantizer per level (header flag bit 5: Jacksboro at RMS 1 m chooses steps
# 13 and 18); the planet) against `cbdam inspect --digest`.
cargo run --quiet --bin cbdam -- build data/jacksboro_mpl.tif -o "$work/jacksboro-rice.cbdam" \
    --max-error 1 --coder fast-rice --quiet
cargo run --quiet --bin cbdam -- build data/jacksboro_mpl.tif -o "$work/jacksboro-grid.cbdam" \
    --max-error 1 --coder adaptive-grid --quiet
cargo run --quiet --bin cbdam -- build data/jacksboro_mpl.tif -o "$work/jacksboro-inband.cbdam" \
    --max-error 1 --coder adaptive-inband --quiet
cargo run --quiet --bin cbdam -- build data/jacksboro_mpl.tif -o "$work/jacksboro-rms.cbdam" \
    --rms-error 1 --quiet
python3 scripts/web_test.py --digest target/web-bundle "${CARGO_TARGET_DIR:-target}/debug/cbdam" \
    "$work/jacksboro.cbdam" "$work/jacksboro-rice.cbdam" "$work/jacksboro-grid.cbdam" \
    "$work/jacksboro-inband.cbdam" "$work/jacksboro-rms.cbdam" "$work/earth.cbdam"
