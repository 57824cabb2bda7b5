#!/usr/bin/env bash
# Builds the browser viewer (client/web) into a folder of static files: index.html, main.js,
# worker.js (the decode workers, which load the same module as the page), the
# wasm-bindgen glue and the .wasm, twice (WebGPU only; with WebGL2, loaded without WebGPU). Serve the folder with any static server and open
#   index.html?repo=URL
# where URL is a .cbdam file on a server that honours Range requests (relative URLs work), or a
# `cbdam serve` repository (http://host:port/v1/repos/NAME, which must allow the page's origin).
#
# Usage: scripts/web-build.sh [OUT_DIR]   (default target/web-bundle)
# Sets up what it needs: the wasm32 target (rustup) and wasm-bindgen-cli at exactly the version
# of the `wasm-bindgen` crate in Cargo.lock (the two must match). `cargo install --locked` is
# not used: a pinned dependency of the CLI is missing from some registry mirrors.
# Then shrinks both modules with binaryen's wasm-opt, pinned, from npm into target/ (runs on
# Node.js; Debian's binaryen 108 writes broken modules). Without npm, or with CBDAM_WASM_OPT=0,
# the modules are left as wasm-bindgen wrote them (about 9 % larger, 2 % gzipped) and it says so.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-target/web-bundle}"

if command -v rustup >/dev/null 2>&1 \
    && ! rustup target list --installed | grep -qx wasm32-unknown-unknown; then
    rustup target add wasm32-unknown-unknown
fi

version="$(awk '/^name = "wasm-bindgen"$/ { getline; gsub(/version = |"/, ""); print; exit }' Cargo.lock)"
[ -n "$version" ] || { echo "web-build.sh: no wasm-bindgen in Cargo.lock" >&2; exit 1; }
if ! wasm-bindgen --version 2>/dev/null | grep -qx "wasm-bindgen $version"; then
    echo "web-build.sh: installing wasm-bindgen-cli $version (a few minutes, once)" >&2
    cargo install wasm-bindgen-cli --version "$version"
fi

# binaryen's wasm-opt, pinned (npm's `binaryen` package: the tool compiled to wasm, run by node).
binaryen_version=132.0.0
binaryen_dir="${CARGO_TARGET_DIR:-target}/binaryen-$binaryen_version"
wasm_opt="$binaryen_dir/node_modules/.bin/wasm-opt"
if [ "${CBDAM_WASM_OPT:-1}" = 0 ]; then
    wasm_opt=""
    echo "web-build.sh: CBDAM_WASM_OPT=0: the modules are not shrunk by wasm-opt" >&2
elif [ ! -x "$wasm_opt" ]; then
    if command -v npm >/dev/null 2>&1 && command -v node >/dev/null 2>&1; then
        echo "web-build.sh: installing binaryen $binaryen_version (wasm-opt) from npm into $binaryen_dir" >&2
        mkdir -p "$binaryen_dir"
        npm install --prefix "$binaryen_dir" --no-audit --no-fund --loglevel=error \
            "binaryen@$binaryen_version" >&2 || true
    fi
    if [ ! -x "$wasm_opt" ]; then
        wasm_opt=""
        echo "web-build.sh: WARNING: no wasm-opt (binaryen $binaryen_version needs npm and node):" \
            "the modules are not shrunk (about 9 % larger: the WebGL2 one over 2.5 MB)" >&2
    fi
fi

# Two modules of the same viewer: cbdam_web (wgpu's WebGPU backend alone, small) and cbdam_web_gl
# (its WebGL2 backend alone, which brings wgpu-core and naga: about three times the bytes).
# main.js loads the second only in browsers without a WebGPU adapter, so WebGPU browsers never
# download it (and it needs no WebGPU backend). Names are left out of the modules (a panic's
# stack in the console shows function numbers): they were a quarter of the bytes.
mkdir -p "$out"
wasm_out="${CARGO_TARGET_DIR:-target}/wasm32-unknown-unknown/web/cbdam_web.wasm"
for variant in cbdam_web cbdam_web_gl; do
    if [ "$variant" = cbdam_web ]; then feature=webgpu; else feature=webgl; fi
    cargo build --target wasm32-unknown-unknown -p cbdam-web --profile web \
        --no-default-features --features "$feature"
    wasm-bindgen --target web --no-typescript --remove-name-section --out-dir "$out" \
        --out-name "$variant" "$wasm_out"
    if [ -n "$wasm_opt" ]; then
        # -Oz without binaryen's inlining: smaller both raw and gzipped than -Oz (which inlines
        # and so compresses worse: measured on the WebGL2 module, issue 22).
        "$wasm_opt" -Oz --skip-pass=inlining-optimizing "$out/${variant}_bg.wasm" \
            -o "$out/${variant}_bg.wasm"
    fi
done
cp client/web/www/index.html client/web/www/main.js client/web/www/worker.js "$out/"

for variant in cbdam_web cbdam_web_gl; do
    wasm="$out/${variant}_bg.wasm"
    raw=$(wc -c <"$wasm")
    gz=$(gzip -9 -c "$wasm" | wc -c)
    echo "web-build.sh: $(basename "$wasm") $raw bytes ($gz gzipped)"
done
# Each build must have written its own module (cargo copies a fresh artifact out again).
if cmp -s "$out/cbdam_web_bg.wasm" "$out/cbdam_web_gl_bg.wasm"; then
    echo "web-build.sh: the WebGPU and WebGL2 modules are the same file" >&2
    exit 1
fi
echo "web-build.sh: $out ready"
