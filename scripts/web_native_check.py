#!/usr/bin/env python3
"""The browser page against `cbdam render`, alone (a minute, where scripts/web-test.sh takes half
an hour on two cores): the check `check_native_image` of scripts/web_test.py on jacksboro_mpl at
a camera of its own, 20° from the page's first view, with the share of matching pixels at
several tolerances and for cameras turned 0.5°, 1° and 2°, printed.

    python3 scripts/web_native_check.py target/web-bundle target/release/cbdam

Needs Chromium and websocket-client, as web_test.py does; exits 1 when the check fails.
"""
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import web_test as W  # noqa: E402


def main():
    bundle, cbdam = sys.argv[1], sys.argv[2]
    dem = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "data", "jacksboro_mpl.tif")
    root = tempfile.mkdtemp(prefix="cbdam-native-")
    repo = os.path.join(root, "jacksboro.cbdam")
    subprocess.run([cbdam, "build", dem, "-o", repo, "--max-error", "1", "--quiet"], check=True)
    site = os.path.join(root, "site")
    subprocess.run([cbdam, "web-export", site, "--bundle", bundle, "--repo", repo],
                   check=True, stdout=subprocess.DEVNULL)
    server = W.serve(site)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/index.html"
        status, _, _, _, _ = W.open_viewer(W.WEBGPU_FLAGS, url, W.converged)
        camera = W.turned(",".join(f"{v:.2f}" for v in status["camera"][:6]), 20.0)
        page, shot, _, _, _ = W.open_viewer(W.WEBGPU_FLAGS, url + "#camera=" + camera, W.converged)
        cut_file = os.path.join(root, "native-cut.txt")
        native_png = W.render_native(cbdam, repo, camera, os.path.join(root, "native.png"), cut_file)
        native = open(cut_file).read().split()
        print(f"camera {camera}: page cut {len(page['cut'])} diamonds, cbdam render's {len(native)}, "
              f"the same: {native == page['cut']}; terrain {W.terrain_share(shot)[0]:.1%} of the page")
        for tolerance in (2, 4, 6, 8, 12):
            print(f"within {tolerance} levels: {W.same_pixels(shot, native_png, tolerance):.4%}")
        for degrees in (0.5, 1.0, 2.0):
            other = W.render_native(cbdam, repo, W.turned(camera, degrees),
                                    os.path.join(root, f"turned-{degrees}.png"))
            print(f"camera turned {degrees}°: {W.same_pixels(shot, other, W.NATIVE_TOLERANCE):.1%} "
                  f"within {W.NATIVE_TOLERANCE} levels")
        failures = [] if native == page["cut"] else ["the page's cut is not cbdam render's"]
        W.check_native_image(root, repo, cbdam, camera, shot, native_png, failures)
    finally:
        server.shutdown()
    print("\n".join(failures) or "ok")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
