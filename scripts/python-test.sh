#!/usr/bin/env bash
# The Python package's tests (run by scripts/test.sh after the workspace's tests): sets up a venv
# under target/ with client/python/requirements-test.txt (maturin, NumPy, pytest, xarray,
# rioxarray, rasterio, Dask), installs the package from client/python with pip (maturin builds
# the extension, release profile, into target/), and runs pytest on client/python/tests against
# the sample DEMs and the cbdam binary ($CBDAM_BIN, else built here).
#
# Needs python3 with pip and venv (test.sh installs python3-pip python3-venv where it can). Where
# they are missing it says so and skips, except under CI (CI set, and not false or 0), where that
# fails.
set -euo pipefail
cd "$(dirname "$0")/.."

# Absolute: maturin runs cargo from client/python, where a relative target would be another one.
mkdir -p "${CARGO_TARGET_DIR:-target}"
target="$(cd "${CARGO_TARGET_DIR:-target}" && pwd)"
venv="$target/cbdam-python-venv"
if ! python3 -c 'import pip, venv, ensurepip' >/dev/null 2>&1; then
    case "${CI:-}" in
    "" | 0 | false | FALSE | False)
        echo "python-test.sh: SKIPPED: python3 lacks pip or venv (apt-get install python3-pip" \
            "python3-venv)" >&2
        exit 0
        ;;
    *)
        echo "python-test.sh: FAILED: python3 lacks pip or venv (apt-get install python3-pip" \
            "python3-venv); under CI a missing prerequisite fails the run" >&2
        exit 1
        ;;
    esac
fi
requirements=client/python/requirements-test.txt
# The venv is made once per target directory and refreshed when the requirements change.
if [ ! -x "$venv/bin/python" ] || ! cmp -s "$requirements" "$venv/requirements-test.txt"; then
    rm -rf "$venv"
    python3 -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$requirements"
    cp "$requirements" "$venv/requirements-test.txt"
fi
# The package as a user installs it: `pip install ./client/python` (maturin, a release build).
# The cargo target directory is the workspace's: rebuilt only when the Rust sources change. The
# venv's maturin is found on PATH (no build isolation: nothing is fetched for the build).
PATH="$venv/bin:$PATH" CARGO_TARGET_DIR="$target" "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    --no-build-isolation --force-reinstall --no-deps ./client/python
# The CLI the tests compare with: $CBDAM_BIN (test.sh passes the one `cargo test` built: building
# the binary alone would unify other features and rebuild much of the tree), else built here.
if [ -z "${CBDAM_BIN:-}" ]; then
    cargo build --quiet --bin cbdam
    CBDAM_BIN="$target/debug/cbdam"
fi
CBDAM_BIN="$CBDAM_BIN" "$venv/bin/python" -m pytest -q -p no:cacheprovider \
    client/python/tests "$@"
