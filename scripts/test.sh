#!/usr/bin/env bash
# The test command of the README: sets up what the tests need on a machine that has only the
# Rust toolchain, then runs every test of the workspace.
set -euo pipefail
cd "$(dirname "$0")/.."

# rustfmt and clippy are part of CI; install them if this toolchain lacks them.
if command -v rustup >/dev/null 2>&1; then
    missing=()
    cargo fmt --version >/dev/null 2>&1 || missing+=(rustfmt)
    cargo clippy --version >/dev/null 2>&1 || missing+=(clippy)
    if [ ${#missing[@]} -gt 0 ]; then
        rustup component add "${missing[@]}"
    fi
fi

# Tests read the sample DEMs in data/; say so clearly if a checkout lost them.
for f in data/srtm3_demcompare.tif data/lidar1m_mn.tif; do
    [ -s "$f" ] || { echo "missing sample data $f (is this a full checkout?)" >&2; exit 1; }
done

# The renderer's tests draw for real, on Mesa's software Vulkan driver (lavapipe) where there is
# no GPU. Install it when no Vulkan driver (ICD) is registered. Where that is impossible (no
# apt-get, no root or sudo), say so and go on: the GPU tests then fail, each with a message
# naming the packages to install — they never pass without rendering.
has_vulkan_icd() {
    for d in /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/share/vulkan/icd.d; do
        compgen -G "$d/*.json" >/dev/null && return 0
    done
    [ -n "${VK_ICD_FILENAMES:-}${VK_DRIVER_FILES:-}" ]
}
has_vulkan_loader() {
    ! command -v ldconfig >/dev/null 2>&1 || ldconfig -p | grep -q 'libvulkan\.so\.1'
}
if ! has_vulkan_icd || ! has_vulkan_loader; then
    if command -v apt-get >/dev/null 2>&1; then
        sudo=""
        [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && sudo="sudo -n"
        if [ "$(id -u)" -eq 0 ] || [ -n "$sudo" ]; then
            echo "test.sh: no Vulkan driver found; installing Mesa's lavapipe (mesa-vulkan-drivers libvulkan1)" >&2
            $sudo apt-get update -qq
            DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
        else
            echo "test.sh: no Vulkan driver and no root/sudo to install one: GPU tests will fail." >&2
            echo "test.sh: install with: apt-get install mesa-vulkan-drivers libvulkan1" >&2
        fi
    else
        echo "test.sh: no Vulkan driver and no apt-get: GPU tests will fail." >&2
        echo "test.sh: install Mesa's Vulkan drivers (lavapipe) and the Vulkan loader." >&2
    fi
fi
# The viewer's tests (tests/cli/view.rs) open a real window: on a machine without a display they
# need Xvfb (and the X client libraries winit loads at run time), xdotool to press keys and
# drag the mouse, and xwd (x11-apps) to read the window back. Install them when missing, like
# lavapipe above; without them those tests print SKIPPED and pass, except under CI (CI set),
# where a missing prerequisite fails the test.
if ! command -v Xvfb >/dev/null 2>&1 || ! command -v xdotool >/dev/null 2>&1 \
    || ! command -v xwd >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1; then
        sudo=""
        [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && sudo="sudo -n"
        if [ "$(id -u)" -eq 0 ] || [ -n "$sudo" ]; then
            echo "test.sh: no Xvfb, xdotool or xwd found; installing them for the viewer's tests" >&2
            $sudo apt-get update -qq
            DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
                xvfb xdotool x11-apps libxkbcommon-x11-0 libx11-xcb1 libxcursor1 libxrandr2 \
                libxi6 >/dev/null
        else
            echo "test.sh: no Xvfb/xdotool/xwd and no root/sudo to install them: the viewer's tests are skipped." >&2
        fi
    fi
fi
# The Dask tests (tests/cli/shard.rs) install codec/builder/dask/requirements.txt into a venv,
# and scripts/python-test.sh client/python/requirements-test.txt into another: they need pip and venv (Debian splits them out of python3). Installed when missing, like the
# above; without them those tests are skipped, except under CI, where they fail.
if ! python3 -c 'import pip' >/dev/null 2>&1 || ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
    if command -v apt-get >/dev/null 2>&1; then
        sudo=""
        [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && sudo="sudo -n"
        if [ "$(id -u)" -eq 0 ] || [ -n "$sudo" ]; then
            echo "test.sh: no pip or venv for python3; installing python3-pip python3-venv for the Dask tests" >&2
            $sudo apt-get update -qq
            DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends \
                python3-pip python3-venv >/dev/null
        fi
    fi
fi
# What could not be set up, named once before the run (under CI the tests needing it fail).
missing=()
has_vulkan_icd && has_vulkan_loader || missing+=("a Vulkan driver (mesa-vulkan-drivers libvulkan1)")
for tool in Xvfb xdotool xwd; do
    command -v "$tool" >/dev/null 2>&1 || missing+=("$tool")
done
python3 -c 'import pip' >/dev/null 2>&1 || missing+=("python3-pip")
python3 -c 'import venv, ensurepip' >/dev/null 2>&1 || missing+=("python3-venv")
if [ ${#missing[@]} -gt 0 ]; then
    echo "test.sh: could not set up: ${missing[*]}; the tests that need them fail under CI and are skipped otherwise" >&2
fi
cleanup=()
trap 'for c in "${cleanup[@]}"; do eval "$c"; done' EXIT
# Without a display, start Xvfb on a free display number for the test run.
if [ -z "${DISPLAY:-}" ] && command -v Xvfb >/dev/null 2>&1; then
    for n in $(seq 99 149); do
        [ -e "/tmp/.X11-unix/X$n" ] || [ -e "/tmp/.X$n-lock" ] && continue
        Xvfb ":$n" -screen 0 1280x1024x24 -nolisten tcp >/dev/null 2>&1 &
        xvfb_pid=$!
        for _ in $(seq 100); do
            [ -e "/tmp/.X11-unix/X$n" ] && break
            kill -0 "$xvfb_pid" 2>/dev/null || break
            sleep 0.05
        done
        if [ -e "/tmp/.X11-unix/X$n" ]; then
            export DISPLAY=":$n"
            cleanup+=("kill $xvfb_pid 2>/dev/null")
            break
        fi
        kill "$xvfb_pid" 2>/dev/null || true
    done
fi
# Mesa warns on every device creation when XDG_RUNTIME_DIR is unset or unusable.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "$XDG_RUNTIME_DIR" ] || [ ! -O "$XDG_RUNTIME_DIR" ]; then
    XDG_RUNTIME_DIR="$(mktemp -d)"
    chmod 700 "$XDG_RUNTIME_DIR"
    export XDG_RUNTIME_DIR
    cleanup+=("rm -rf '$XDG_RUNTIME_DIR'")
fi

# The client core must stay portable: it builds for the browser (no threads, no sockets, no
# memory maps). The browser test below builds it for wasm32 (and CI lints it there); add the
# target when it is missing.
if command -v rustup >/dev/null 2>&1 \
    && ! rustup target list --installed | grep -qx wasm32-unknown-unknown; then
    rustup target add wasm32-unknown-unknown
fi

cargo test --workspace --all-targets

# The Python package (client/python): built into a venv with maturin, its pytest suite against
# the CLI (sets up its venv; needs pip and venv, installed above).
CBDAM_BIN="${CARGO_TARGET_DIR:-target}/debug/cbdam" scripts/python-test.sh

# The browser viewer, end to end in headless Chromium (builds the web bundle; sets up Chromium).
scripts/web-test.sh

# The web-map clients (CesiumJS, MapLibre GL JS) on cbdam serve's tiles, in headless Chromium
# (sets up Chromium, npm and the clients' packages; docs/WEB-MAPS.md).
scripts/web-maps-test.sh
