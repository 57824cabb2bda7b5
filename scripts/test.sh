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

cargo test --workspace --all-targets
