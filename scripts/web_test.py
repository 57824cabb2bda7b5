#!/usr/bin/env python3
"""End-to-end test of the browser viewer in headless Chromium (run by scripts/web-test.sh).

Exports the viewer with `cbdam web-export DIR --bundle BUNDLE --repo FILE` (the bundle of
scripts/web-build.sh and the repository), serves DIR from a loopback static server that honours
Range requests, opens index.html (which opens the repository) in the system's Chromium driven
over the Chrome DevTools protocol (websocket-client), waits for the page's `window.cbdam` status
and checks the pixels of a screenshot, not only the page's word:

- WebGPU (the flags of docs/notes: SwiftShader through Vulkan): the page converges, and terrain
  (pixels that are not the sky colour) covers most of a 640x480 frame, in many colours; the
  overlay (HUD) shows the status's non-zero request and byte counts.
- A scripted drag and wheel move the camera, and the page converges to a new cut; the camera is
  in the URL's hash, and opening that URL restores the view (same camera, same cut), which is
  also the cut `cbdam render --camera` (native, from the file) converges to; the page's
  screenshot matches `cbdam render`'s image of that camera and cut (NATIVE_ALIKE of the pixels
  within NATIVE_TOLERANCE levels) and does not match its image of a camera turned 2°.
- Then, in the same page: W held moves the camera and `=` halves the pixel-error target (more
  diamonds); the slider sets it; the static server goes away (its port closed) while the page
  needs new records and comes back on the same port: requests fail meanwhile, the page keeps
  running and converges once it is back; a two-finger pinch (touch) from 100 to 260 pixels
  apart scales the orbit distance by 100/260, and a quarter-turn twist turns the view a quarter
  turn the other way about the same target.
- Record requests refused (503) and a record corrupted once by the server (its checksum
  fails) are retried: the same cut.
- The same page against `cbdam serve` (batched POSTs, cross-origin) converges to the same cut.
- Decoding runs in Web Workers (`window.cbdam.workers`): at least one started, and they decoded
  diamonds (WebGPU and WebGL2 pages, and with faults); with `?workers=0` the page decodes on its
  own thread and converges to the same cut.
- A camera flight (`?flight=URL`, descent.json's keyframes sped up) plays to its last frame, one
  frame of flight time per animation frame, and reports its refinement and frame times; it
  ends at a camera whose converged cut is the one `cbdam render --camera` gives for it; a drag
  ends a flight early; a flight that does not parse, or is not there, is named in the status
  with the reason.
- A colour repository draped over the terrain (`?colour=URL`, or written into the page by
  `cbdam web-export --colour`; built by `cbdam build IMAGE --colour --like`, red in the west and
  blue in the east): the same cut, and the terrain drawn red on the left and blue on the
  right, through WebGPU and WebGL2.
- No WebGPU flags (the browser offers only WebGL2): the page loads the bundle's WebGL2 module
  (a WebGPU browser loads only the small WebGPU one) and draws through WebGL2 (backend "webgl",
  the renderer's texture path), converges to the same cut, and terrain covers most of
  the frame (screenshot pixels), nearly the WebGPU screenshot's pixels; with WebGL off too it
  names both APIs; a repository URL that cannot be read gets "cannot read the repository".

Prints the times from navigation to the first frame and to the converged cut (both backends),
and the workers' decode throughput (diamonds per second of worker time).

Usage: web_test.py BUNDLE_DIR REPOSITORY.cbdam CBDAM_BINARY
       web_test.py --planet BUNDLE_DIR PLANET.cbdam CBDAM_BINARY
         (a planet: the page draws the whole globe, centred; see check_planet)
       web_test.py --measure WIDTHxHEIGHT BUNDLE_DIR REPOSITORY.cbdam CBDAM_BINARY [REPO_URL]
         (figures only; REPO_URL: open that instead of the exported file)
"""

import base64
import http.server
import io
import json
import math
import os
import re
import shutil
import socketserver
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib

from ortho_from_dem import write_png

import websocket  # websocket-client, pinned by scripts/web-test.sh

CHROMIUM = os.environ.get("CBDAM_CHROMIUM", "/usr/lib/chromium/chromium")
WEBGPU_FLAGS = [
    "--enable-unsafe-webgpu",
    "--enable-features=Vulkan",
    "--use-vulkan=swiftshader",
    "--use-angle=swiftshader",
]
COMMON_FLAGS = [
    "--headless=new",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--disable-component-update",
    "--disable-background-networking",
    "--no-first-run",
    "--remote-debugging-port=0",
    # Chromium 111 and later refuse DevTools WebSocket connections that send an Origin header
    # unless it is allowed; older and newer builds alike accept this flag.
    "--remote-allow-origins=*",
]
WIDTH, HEIGHT = 640, 480
# The renderer's clear colour (RenderOptions::default().background) and the page's background.
SKY = (158, 189, 219)
TIMEOUT_S = 90
# Share of the WebGL2 screenshot's pixels within 6 levels of the WebGPU one's (same view and
# cut, the same shader maths, SwiftShader under both). Measured 100.0 % (Chromium 156); the
# margin is for another SwiftShader rounding silhouettes differently, while a misread height
# pool or instance moves most of the terrain's pixels.
WEBGL2_ALIKE = 0.95
# The page's screenshot against `cbdam render`'s image of the same camera and cut: the same
# mesh, shader maths and colour map, drawn by two rasterizers (SwiftShader's WebGPU in the
# browser, the native renderer's adapter for `cbdam render`), so pixels differ only by float
# rounding of the shading and by which side of an edge a boundary pixel falls: at least
# NATIVE_ALIKE of the pixels must be within NATIVE_TOLERANCE levels in every channel (the same
# tolerance as WebGL2 against WebGPU). A camera turned by NATIVE_TURN_DEG about the eye must
# fall below NATIVE_ALIKE, or the comparison could not tell a wrong camera from the right one.
# Measured (scripts/web_native_check.py, Chromium 156, jacksboro): 99.99 % within 6 levels
# (99.98 % within 2); a camera turned 0.5° 65 %, 2° 51 % (the sky both share).
NATIVE_TOLERANCE = 6
NATIVE_ALIKE = 0.95
NATIVE_TURN_DEG = 2.0


class RangeHandler(http.server.SimpleHTTPRequestHandler):
    """Static files with single-range `Range: bytes=a-b` support (python's server has none).
    While `corrupt["armed"]`, the next range not starting at 0 (a record, not the head) is
    answered with its last byte flipped, once; while `refuse["left"]` > 0, record ranges are
    answered 503 (a server that is away for a while)."""

    corrupt = {"armed": False, "done": 0}
    refuse = {"left": 0, "done": 0}

    extensions_map = {
        **http.server.SimpleHTTPRequestHandler.extensions_map,
        ".wasm": "application/wasm",
        ".js": "text/javascript",
    }

    def log_message(self, *args):
        pass

    def send_head(self):
        header = self.headers.get("Range")
        path = self.translate_path(self.path)
        if header is None or not os.path.isfile(path):
            return super().send_head()
        m = re.fullmatch(r"bytes=(\d+)-(\d*)", header.strip())
        size = os.path.getsize(path)
        if not m or int(m.group(1)) >= size:
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        start = int(m.group(1))
        end = min(int(m.group(2)) if m.group(2) else size - 1, size - 1)
        if self.refuse["left"] > 0 and start > 0:
            self.refuse["left"] -= 1
            self.refuse["done"] += 1
            self.send_error(503, "away for a while")
            return None
        with open(path, "rb") as source:
            source.seek(start)
            data = bytearray(source.read(end - start + 1))
        if self.corrupt["armed"] and start > 0 and data:
            self.corrupt["armed"] = False
            self.corrupt["done"] += 1
            data[-1] ^= 0xFF
        self.send_response(206)
        self.send_header("Content-Type", self.guess_type(path))
        self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.send_header("Content-Length", str(end - start + 1))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()
        return io.BytesIO(bytes(data))


class Server(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True

    def handle_error(self, request, client_address):
        # A browser closed while a response was being written: not the server's failure.
        if not isinstance(sys.exc_info()[1], (BrokenPipeError, ConnectionResetError)):
            super().handle_error(request, client_address)


def serve(root, port=0, handler_class=None):
    handler_class = handler_class or RangeHandler
    handler = lambda *a, **k: handler_class(*a, directory=root, **k)  # noqa: E731
    server = Server(("127.0.0.1", port), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def decode_png(data):
    """RGB(A) 8-bit non-interlaced PNG -> (width, height, channels, rows of bytes)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
    width, height, depth, colour, _, _, interlace = header
    assert depth == 8 and colour in (2, 6) and interlace == 0, f"unsupported PNG {header}"
    channels = 3 if colour == 2 else 4
    raw = zlib.decompress(idat)
    stride = width * channels
    rows, prev, i = [], bytearray(stride), 0
    for _ in range(height):
        kind, line = raw[i], bytearray(raw[i + 1 : i + 1 + stride])
        i += 1 + stride
        for x in range(stride):
            a = line[x - channels] if x >= channels else 0
            b = prev[x]
            c = prev[x - channels] if x >= channels else 0
            if kind == 1:
                line[x] = (line[x] + a) & 255
            elif kind == 2:
                line[x] = (line[x] + b) & 255
            elif kind == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[x] = (line[x] + pred) & 255
        rows.append(bytes(line))
        prev = line
    return width, height, channels, rows


def save_screenshot(png, name):
    """Keeps a screenshot in $CBDAM_WEB_SHOTS, when set (for a look at what was checked)."""
    folder = os.environ.get("CBDAM_WEB_SHOTS")
    if folder:
        os.makedirs(folder, exist_ok=True)
        with open(os.path.join(folder, name), "wb") as f:
            f.write(png)


def same_pixels(png_a, png_b, tolerance=6):
    """Share of pixels whose channels all differ by at most `tolerance` between two
    screenshots of one size."""
    wa, ha, ca, ra = decode_png(png_a)
    wb, hb, cb, rb = decode_png(png_b)
    if (wa, ha) != (wb, hb):
        return 0.0
    same = 0
    for row_a, row_b in zip(ra, rb):
        for x in range(wa):
            pa, pb = row_a[x * ca : x * ca + 3], row_b[x * cb : x * cb + 3]
            same += all(abs(a - b) <= tolerance for a, b in zip(pa, pb))
    return same / (wa * ha)


def turned(camera, degrees):
    """The camera `EX,EY,EZ,TX,TY,TZ` (a URL hash's values) turned by `degrees` about the
    vertical through the eye."""
    ex, ey, ez, tx, ty, tz = (float(v) for v in camera.split(","))
    a = math.radians(degrees)
    dx, dy = tx - ex, ty - ey
    target = (ex + dx * math.cos(a) - dy * math.sin(a), ey + dx * math.sin(a) + dy * math.cos(a), tz)
    return ",".join(f"{v:.2f}" for v in (ex, ey, ez) + target)


def render_native(cbdam, repository, camera, png, cut_file=None):
    """`cbdam render` of `repository` from `camera` into `png` (and its cut into `cut_file`)."""
    args = [cbdam, "render", repository, "-o", png, "--size", f"{WIDTH}x{HEIGHT}", "--camera", camera]
    if cut_file:
        args += ["--cut-out", cut_file]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    with open(png, "rb") as f:
        return f.read()


def check_native_image(root, repository, cbdam, camera, shot, native, failures):
    """The page's screenshot `shot` against `native`, `cbdam render`'s image of the same camera
    and cut, and against its image of the camera turned by NATIVE_TURN_DEG: alike, and not."""
    alike = same_pixels(shot, native, NATIVE_TOLERANCE)
    other_png = render_native(cbdam, repository, turned(camera, NATIVE_TURN_DEG),
                              os.path.join(root, "native-turned.png"))
    other = same_pixels(shot, other_png, NATIVE_TOLERANCE)
    print(
        f"render: {alike:.1%} of the page's pixels within {NATIVE_TOLERANCE} levels of cbdam "
        f"render's image of the same camera and cut; {other:.1%} of a camera turned "
        f"{NATIVE_TURN_DEG}° (at least {NATIVE_ALIKE:.0%}, and below it)"
    )
    if alike < NATIVE_ALIKE:
        failures.append(f"render: only {alike:.1%} of the page's pixels match cbdam render's image")
    if other >= NATIVE_ALIKE:
        failures.append(
            f"render: {other:.1%} of the page's pixels match a camera turned {NATIVE_TURN_DEG}°: "
            "the comparison cannot tell a wrong camera from the right one"
        )


def terrain_share(png):
    """Share of pixels that are not the sky colour, and how many distinct such colours."""
    width, height, channels, rows = decode_png(png)
    terrain, colours = 0, set()
    for row in rows:
        for x in range(0, width * channels, channels):
            r, g, b = row[x], row[x + 1], row[x + 2]
            if abs(r - SKY[0]) + abs(g - SKY[1]) + abs(b - SKY[2]) > 12:
                terrain += 1
                colours.add((r >> 2, g >> 2, b >> 2))
    return terrain / (width * height), len(colours), (width, height)


class Browser:
    """One headless Chromium with one page, driven over the DevTools protocol."""

    def __init__(self, flags):
        self.profile = tempfile.mkdtemp(prefix="cbdam-chromium-")
        self.log = open(os.path.join(self.profile, "stderr.txt"), "w+")
        self.proc = subprocess.Popen(
            [CHROMIUM, *COMMON_FLAGS, *flags, f"--user-data-dir={self.profile}", "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=self.log,
        )
        port_file = os.path.join(self.profile, "DevToolsActivePort")
        deadline = time.time() + 30
        while not os.path.exists(port_file) or os.path.getsize(port_file) == 0:
            if self.proc.poll() is not None or time.time() > deadline:
                raise RuntimeError("Chromium did not start: " + self.stderr())
            time.sleep(0.05)
        time.sleep(0.05)
        port, path = open(port_file).read().split("\n")[:2]
        self.ws = websocket.create_connection(f"ws://127.0.0.1:{port}{path}", timeout=60)
        self.next_id = 0
        self.events = []
        self.console = []
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)[
            "sessionId"
        ]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", session=True)
        self.call(
            "Emulation.setDeviceMetricsOverride",
            session=True,
            width=WIDTH,
            height=HEIGHT,
            deviceScaleFactor=1,
            mobile=False,
        )

    def stderr(self):
        self.log.flush()
        self.log.seek(0)
        return self.log.read()[-3000:]

    def call(self, method, session=False, **params):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        while True:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.note(reply)

    def note(self, event):
        method = event.get("method", "")
        if method == "Runtime.consoleAPICalled":
            args = event["params"].get("args", [])
            self.console.append(" ".join(str(a.get("value", a.get("description", ""))) for a in args))
        elif method == "Log.entryAdded":
            self.console.append(event["params"]["entry"].get("text", ""))
        self.events.append(method)

    def wait_event(self, name, timeout):
        deadline = time.time() + timeout
        while name not in self.events:
            if time.time() > deadline:
                raise RuntimeError(f"no {name} within {timeout} s")
            self.ws.settimeout(max(0.1, deadline - time.time()))
            self.note(json.loads(self.ws.recv()))

    def evaluate(self, expression):
        r = self.call("Runtime.evaluate", session=True, expression=expression, returnByValue=True)
        return r.get("result", {}).get("value")

    def close(self):
        try:
            self.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
            shutil.rmtree(self.profile, ignore_errors=True)


def wait_status(browser, until, timeout=TIMEOUT_S):
    """Polls window.cbdam until `until(status)` or a failure or `timeout`; returns the status."""
    deadline = time.time() + timeout
    status = None
    while time.time() < deadline:
        status = json.loads(browser.evaluate("JSON.stringify(window.cbdam || null)") or "null")
        if status and (status.get("phase") == "failed" or until(status)):
            break
        time.sleep(0.1)
    return status


HIDE = "for (const id of ['overlay', 'panel']) document.getElementById(id).style.display = '{}'"


def screenshot(browser):
    """A PNG of the page with the overlay and the control panel hidden."""
    browser.evaluate(HIDE.format("none"))
    # Two animation frames so the canvas shows the last state without the overlay.
    browser.call(
        "Runtime.evaluate",
        session=True,
        expression="new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))",
        awaitPromise=True,
    )
    shot = base64.b64decode(browser.call("Page.captureScreenshot", session=True, format="png")["data"])
    browser.evaluate(HIDE.format(""))
    return shot


def drag_and_zoom(browser):
    """A left-button drag across the canvas (rotates the orbit camera), then the wheel towards
    the terrain (zooms in)."""
    def mouse(kind, x, y, **extra):
        browser.call("Input.dispatchMouseEvent", session=True, type=kind, x=x, y=y, **extra)

    mouse("mousePressed", 320, 240, button="left", clickCount=1)
    for step in range(1, 11):
        mouse("mouseMoved", 320 + 12 * step, 240 + 4 * step, button="left", buttons=1)
    mouse("mouseReleased", 440, 280, button="left", clickCount=1)
    mouse("mouseWheel", 320, 240, deltaX=0, deltaY=-300)


converged = lambda s: s.get("converged") and s.get("cut") is not None  # noqa: E731


def key(browser, code, text, down_s=0.0):
    """Presses and releases a key (`KeyboardEvent.code` and `key`), held `down_s` seconds."""
    for kind in ("keyDown", "keyUp"):
        browser.call("Input.dispatchKeyEvent", session=True, type=kind, code=code, key=text)
        if kind == "keyDown" and down_s:
            time.sleep(down_s)


def distance(camera):
    return sum((a - b) ** 2 for a, b in zip(camera[:3], camera[3:])) ** 0.5


def keys_slider_away_touch(browser, status, server):
    """After the drag: held W and `=` (finer), the pixel-error slider, the static server going
    away and coming back, and a two-finger pinch. Returns failures and printed lines."""
    failures, lines = [], []
    # W held moves the orbit target forward; `=` halves the pixel-error target: a new camera
    # and a finer cut.
    key(browser, "KeyW", "w", down_s=0.4)
    key(browser, "Equal", "=")
    keyed = wait_status(
        browser,
        lambda s: s.get("camera") != status["camera"] and s.get("pixelError") == 0.5 and converged(s),
    )
    if not keyed or keyed.get("pixelError") != 0.5 or keyed.get("camera") == status["camera"]:
        failures.append(f"keys: W and = did not move the camera and halve the pixel error: {keyed}")
        return failures, lines
    lines.append(
        f"keys: W moved the target from {status['camera'][3:5]} to {keyed['camera'][3:5]}; "
        f"= halved the pixel error: {len(keyed['cut'])} diamonds (from {len(status['cut'])})"
    )
    if len(keyed["cut"]) <= len(status["cut"]):
        failures.append("keys: a finer target did not refine more diamonds")
    # The slider sets the target (2 px), through the page's `input` event as a user's drag does.
    browser.evaluate(
        "const e = document.getElementById('pixel-error'); e.value = '1';"
        "e.dispatchEvent(new Event('input'))"
    )
    slid = wait_status(browser, lambda s: s.get("pixelError") == 2 and converged(s))
    if not slid or slid.get("pixelError") != 2:
        failures.append(f"slider: the pixel error is not 2 px: {slid}")
        return failures, lines

    # The server goes away (its port refuses connections) while the page needs new records
    # (the slider at 1/4 px, finer than any cut so far), then comes back on the same port: the
    # page keeps running and converges.
    port = server["server"].server_address[1]
    server["server"].shutdown()
    server["server"].server_close()
    before = slid
    browser.evaluate(
        "const f = document.getElementById('pixel-error'); f.value = '-2';"
        "f.dispatchEvent(new Event('input'))"
    )
    # Until a request has failed (a loaded machine may draw only a few frames a second).
    away = wait_status(
        browser, lambda s: (s.get("fetchErrors") or 0) > (before.get("fetchErrors") or 0), timeout=30
    )
    server["server"] = serve(server["root"], port)
    back = wait_status(browser, lambda s: s.get("pixelError") == 0.25 and converged(s))
    lines.append(
        f"away: {away and away.get('fetchErrors')} failed requests while the server was away "
        f"(converged: {away and away.get('converged')}); back: converged "
        f"{back and back.get('converged')}, {back and len(back.get('cut') or [])} diamonds"
    )
    if not away or away.get("phase") != "running" or away.get("converged"):
        failures.append(f"away: the page should keep running and not converge: {away}")
    elif (away.get("fetchErrors") or 0) <= (before.get("fetchErrors") or 0):
        failures.append("away: no request failed while the server was away (the test did not test)")
    elif not back or not converged(back) or back.get("pixelError") != 0.25:
        failures.append(f"away: no convergence once the server came back: {back}")
    if failures:
        return failures, lines

    # Two fingers spreading from 100 to 260 pixels apart: the orbit distance shrinks by 2.6.
    browser.call("Emulation.setTouchEmulationEnabled", session=True, enabled=True, maxTouchPoints=5)

    def touch(kind, points):
        browser.call("Input.dispatchTouchEvent", session=True, type=kind,
                     touchPoints=[{"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)])

    touch("touchStart", [(270, 240), (370, 240)])
    for k in range(1, 11):
        touch("touchMove", [(270 - 8 * k, 240), (370 + 8 * k, 240)])
    touch("touchEnd", [])
    pinched = wait_status(browser, lambda s: s.get("camera") != back["camera"] and converged(s))
    ratio = pinched and distance(pinched["camera"]) / distance(back["camera"])
    lines.append(f"touch: the pinch scaled the orbit distance by {ratio}")
    if not ratio or abs(ratio - 100 / 260) > 0.02:
        failures.append(f"touch: a pinch 100 -> 260 px should scale the distance by 0.385, not {ratio}")
        return failures, lines

    # Two fingers turning a quarter turn clockwise about the centre: the terrain follows them,
    # the view's azimuth turns a quarter turn anticlockwise, the target stays.
    def azimuth(camera):
        return math.atan2(camera[3] - camera[0], camera[4] - camera[1])

    def at(angle):
        c, s = math.cos(angle), math.sin(angle)
        return [(320 - 80 * c, 240 - 80 * s), (320 + 80 * c, 240 + 80 * s)]

    touch("touchStart", at(0))
    for k in range(1, 11):
        touch("touchMove", at(math.pi / 2 * k / 10))
    touch("touchEnd", [])
    turned = wait_status(browser, lambda s: s.get("camera") != pinched["camera"] and converged(s))
    turn = turned and (azimuth(turned["camera"]) - azimuth(pinched["camera"]) + math.pi) % math.tau - math.pi
    moved = turned and max(abs(a - b) for a, b in zip(turned["camera"][3:5], pinched["camera"][3:5]))
    lines.append(f"touch: the twist turned the azimuth by {turn} rad, the target moved {moved} m")
    # The midpoint stays put when both fingers move in one frame; a frame between their moves
    # pans a little there and back (at another azimuth): allow 2 % of the orbit distance.
    if turn is None or abs(turn + math.pi / 2) > 0.02 or moved > 0.02 * distance(pinched["camera"]):
        failures.append(f"touch: a quarter-turn twist should turn the view by -pi/2, not {turn} (target moved {moved} m)")
    return failures, lines


def hud_network(text):
    """(requests, KiB) from the overlay's network line, or None."""
    m = re.search(r"network: (\d+) requests, ([\d.]+) KiB", text or "")
    return (int(m.group(1)), float(m.group(2))) if m else None


def open_viewer(flags, url, until, interact=None):
    """Opens `url` and waits for `until(status)`; returns the status, a screenshot (PNG bytes),
    the browser's console lines and stderr, and with `interact` (the static server) the status
    after a scripted drag and wheel once it converged again, with the further checks of
    `keys_slider_away_touch` in it."""
    browser = Browser(flags)
    try:
        browser.call("Page.navigate", session=True, url=url)
        browser.wait_event("Page.loadEventFired", 30)
        status = wait_status(browser, until)
        if status:
            # Which of the bundle's two modules the page fetched (main.js picks one).
            status["wasm"] = browser.evaluate(
                "performance.getEntriesByType('resource').map(e => e.name.split('/').pop())"
                ".filter(n => n.endsWith('.wasm'))"
            )
            status["hash"] = browser.evaluate("location.hash")
        shot = screenshot(browser)
        after = None
        if interact and status and converged(status):
            # Frame rate with the cut converged (refining nothing, drawing every frame).
            count = "[window.cbdam.frames, performance.now()]"
            (f0, t0), _ = browser.evaluate(count), time.sleep(2)
            f1, t1 = browser.evaluate(count)
            status["measuredFps"] = (f1 - f0) * 1000 / (t1 - t0)
            status["hud"] = browser.evaluate("document.getElementById('overlay').textContent")
            drag_and_zoom(browser)
            before = status["camera"]
            after = wait_status(
                browser, lambda s: s.get("camera") != before and converged(s) and s["cut"] != status["cut"]
            )
            if after:
                after["hash"] = browser.evaluate("location.hash")
                if converged(after):
                    after["failures"], after["lines"] = keys_slider_away_touch(
                        browser, after, interact
                    )
        return status, shot, browser.console, browser.stderr(), after
    finally:
        browser.close()


def check_workers(name, status, failures):
    """The page decoded in Web Workers: some started, none failed, and they decoded diamonds.
    Prints their throughput (diamonds per second of worker time)."""
    w = (status or {}).get("workers") or {}
    busy = w.get("busyMs") or 0
    rate = w.get("decoded", 0) * 1000 / busy if busy > 0 else 0
    print(
        f"{name}: {w.get('count')} decode workers ({w.get('ready')} ready) decoded "
        f"{w.get('decoded')} diamonds in {busy:.1f} ms of worker time ({rate:.0f} diamonds/s), "
        f"{w.get('onPage')} on the page{'; ' + w['problem'] if w.get('problem') else ''}"
    )
    if not w.get("count") or not w.get("decoded") or w.get("problem") or w.get("onPage"):
        failures.append(f"{name}: the page did not decode in its workers: {w}")


# The flight the page plays in the test: data/flights/descent.json's cameras, 15 times faster
# (about 1.1 s of flight, 34 frames at 30 fps), so it takes seconds on SwiftShader.
FLIGHT_SPEED_UP = 15


def write_flight(root, name, speed_up=FLIGHT_SPEED_UP):
    """Writes data/flights/descent.json into `root` as `name`, its times divided by `speed_up`;
    returns the flight's duration, s."""
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "..", "data", "flights", "descent.json")) as f:
        flight = json.load(f)
    for k in flight["keyframes"]:
        k["t"] /= speed_up
    with open(os.path.join(root, name), "w") as f:
        json.dump(flight, f)
    return flight["keyframes"][-1]["t"]


def check_flight(url, root, repository, cbdam, failures):
    """The page plays a flight to its end, reports its figures, and ends at a camera whose
    converged cut equals `cbdam render`'s for that camera; bad flights are named."""
    duration = write_flight(root, "flight.json")
    frames = math.ceil(duration * 30) + 1
    done = lambda s: (s.get("flight") or {}).get("done") and converged(s)  # noqa: E731
    status, _, console, _, _ = open_viewer(WEBGPU_FLAGS, url + "?flight=flight.json", done)
    f = (status or {}).get("flight") or {}
    print(f"flight: {json.dumps(f)}")
    if not status or not done(status):
        failures.append(f"flight: not played to its end and converged: {f} {status and status.get('error')}")
        print("console:\n  " + "\n  ".join(console[-20:]))
        return
    refine, frame = f.get("refineMs") or [], f.get("frameMs") or []
    if f.get("frames") != frames or f.get("frame") != frames or f.get("stopped"):
        failures.append(f"flight: {f.get('frame')} of {f.get('frames')} frames flown, not {frames}")
    elif len(refine) != 3 or not 0 < refine[0] <= refine[1] <= refine[2]:
        failures.append(f"flight: refinement times are not a median <= p99 <= largest: {refine}")
    elif len(frame) != 3 or not 0 < frame[0] <= frame[1] <= frame[2]:
        failures.append(f"flight: frame times are not a median <= p99 <= largest: {frame}")
    elif not 0 < f.get("seconds", 0) < TIMEOUT_S:
        failures.append(f"flight: took {f.get('seconds')} s")
    # Where it ended: the flight's last camera (written into the hash too), whose cut the
    # native renderer converges to as well.
    hash_camera = [float(v) for v in status.get("hash", "").split("=")[-1].split(",") if v]
    cut_file = os.path.join(root, "flight-cut.txt")
    subprocess.run(
        [cbdam, "render", repository, "-o", os.path.join(root, "flight-end.png"),
         "--size", f"{WIDTH}x{HEIGHT}", "--camera", ",".join(repr(v) for v in status["camera"]),
         "--cut-out", cut_file],
        check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    native = open(cut_file).read().split()
    print(f"flight: ended at {status['camera'][:3]}; the page's cut {len(status['cut'])} diamonds, "
          f"cbdam render's {len(native)}")
    if native != status["cut"]:
        failures.append(f"flight: the page's cut at the flight's end differs from cbdam render's "
                        f"({len(status['cut'])} vs {len(native)} diamonds)")
    if len(hash_camera) != 6 or max(abs(a - b) for a, b in zip(hash_camera, status["camera"])) > 0.01:
        failures.append(f"flight: the hash {status.get('hash')!r} is not the last camera {status['camera']}")
    # A drag and the wheel during a flight (at its own speed: 451 frames) end it there.
    write_flight(root, "slow-flight.json", speed_up=1)
    browser = Browser(WEBGPU_FLAGS)
    try:
        browser.call("Page.navigate", session=True, url=url + "?flight=slow-flight.json")
        browser.wait_event("Page.loadEventFired", 30)
        flying = wait_status(browser, lambda s: (s.get("flight") or {}).get("frame", 0) >= 3)
        drag_and_zoom(browser)
        stopped = wait_status(browser, lambda s: (s.get("flight") or {}).get("stopped"))
    finally:
        browser.close()
    f = (stopped or {}).get("flight") or {}
    print(f"flight stopped by a drag: {f.get('frame')} of {f.get('frames')} frames flown")
    if not flying or not f.get("stopped") or f.get("done") or not f.get("refineMs"):
        failures.append(f"flight: a drag did not end the flight with its figures: {f}")
    # A flight whose times go backwards, and one that is not there: named, with the reason.
    with open(os.path.join(root, "bad-flight.json"), "w") as out:
        json.dump({"keyframes": [{"t": 1, "eye": [0, 0, 1], "target": [1, 1, 0]},
                                 {"t": 0, "eye": [1, 0, 1], "target": [1, 1, 0]}]}, out)
    for name, reason in [("bad-flight.json", "times must increase"), ("missing.json", "HTTP 404")]:
        # The viewer runs on (the error may come before it has connected).
        has_error = lambda s: (s.get("flight") or {}).get("error") and s.get("phase") == "running"  # noqa: E731
        status, _, _, _, _ = open_viewer(WEBGPU_FLAGS, url + "?flight=" + name, has_error)
        error = ((status or {}).get("flight") or {}).get("error", "")
        print(f"flight {name}: {error!r}")
        if name not in error or reason not in error or (status or {}).get("phase") != "running":
            failures.append(f"flight {name}: expected an error naming it and {reason!r}, got {status}")


def red_and_blue(png):
    """(pixels, mean x) of the clearly red and of the clearly blue pixels of a screenshot."""
    width, _, channels, rows = decode_png(png)
    red, blue = [0, 0.0], [0, 0.0]
    for row in rows:
        for x in range(width):
            r, g, b = row[x * channels : x * channels + 3]
            if r > 2 * g and r > 2 * b:
                red[0], red[1] = red[0] + 1, red[1] + x
            elif b > 2 * r and b > 1.5 * g:
                blue[0], blue[1] = blue[0] + 1, blue[1] + x
    return [(n, total / max(n, 1)) for n, total in (red, blue)]


def check_colour(url, root, bundle, repository, cbdam, static_cut, plain_shot, failures):
    """A colour repository draped over the terrain: red in the west, blue in the east of the
    screenshot, through WebGPU and WebGL2, with the cut of the plain terrain (the elevation
    alone drives refinement)."""
    width, height = (int(v) for v in re.findall(
        r"(\d+)×(\d+) samples",
        subprocess.run([cbdam, "inspect", repository], check=True, capture_output=True, text=True).stdout,
    )[0])
    image = os.path.join(root, "colour.png")
    # Red west, blue east (PNG rows: a filter byte, then RGB).
    row = b"\0" + bytes((200, 30, 30)) * (width // 2) + bytes((30, 60, 200)) * (width - width // 2)
    write_png(image, width, height, [row] * height)
    subprocess.run([cbdam, "build", image, "--colour", "--like", repository, "-o",
                    os.path.join(root, "colour.cbdam"), "--max-error", "2", "--quiet"], check=True)
    # The same export with the colour written into the page (`web-export --colour`): drawn
    # without ?colour=.
    meta_root = os.path.join(root, "draped")
    subprocess.run([cbdam, "web-export", meta_root, "--bundle", bundle,
                    "--repo", repository, "--colour", os.path.join(root, "colour.cbdam")],
                   check=True, stdout=subprocess.DEVNULL)
    runs = [("colour webgpu", WEBGPU_FLAGS, url + "?colour=colour.cbdam"),
            ("colour webgl2", [], url + "?colour=colour.cbdam"),
            ("colour web-export", WEBGPU_FLAGS, url.replace("/index.html", "/draped/index.html"))]
    for name, flags, page in runs:
        status, shot, console, _, _ = open_viewer(flags, page, converged)
        save_screenshot(shot, name.replace(" ", "-") + ".png")
        (reds, red_x), (blues, blue_x) = red_and_blue(shot)
        print(f"{name}: backend {status and status.get('backend')}, draped {status and status.get('draped')}; "
              f"{reds} red pixels at mean x {red_x:.0f}, {blues} blue at {blue_x:.0f}")
        if not status or not converged(status) or not status.get("draped"):
            failures.append(f"{name}: no draped convergence: {status}")
            print("console:\n  " + "\n  ".join(console[-20:]))
        elif status["cut"] != static_cut:
            failures.append(f"{name}: the draped cut differs from the plain one")
        # Measured: 95 523 red and 95 446 blue pixels of the 640x480 frame (Jacksboro's first
        # view), both APIs; the plain terrain has none.
        elif min(reds, blues) < 0.1 * WIDTH * HEIGHT or not red_x < WIDTH / 2 < blue_x:
            failures.append(f"{name}: not red in the west and blue in the east: {reds} at {red_x:.0f}, "
                            f"{blues} at {blue_x:.0f}")
    # Without the colour, the height ramp: hardly any pure red or blue.
    (reds, _), (blues, _) = red_and_blue(plain_shot)
    if reds + blues > 0.01 * WIDTH * HEIGHT:
        failures.append(f"colour: the plain terrain has {reds} red and {blues} blue pixels (the test cannot tell)")


def start_server(cbdam, repository):
    """`cbdam serve REPOSITORY` on a free loopback port, any origin allowed; returns the process
    and its base URL."""
    proc = subprocess.Popen(
        [cbdam, "serve", repository, "--addr", "127.0.0.1:0", "--cors-origin", "*"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 30
    while time.time() < deadline:
        line = proc.stderr.readline()
        m = re.search(r"listening on (http://127\.0\.0\.1:\d+)", line)
        if m:
            threading.Thread(target=proc.stderr.read, daemon=True).start()
            return proc, m.group(1)
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("cbdam serve did not start")


def main():
    bundle, repository, cbdam = sys.argv[1], sys.argv[2], sys.argv[3]
    root = tempfile.mkdtemp(prefix="cbdam-web-")
    try:
        # The static site as `cbdam web-export` writes it: the bundle, and the repository the
        # page opens without ?repo= (so the plain URL of index.html is the viewer on it).
        subprocess.run(
            [cbdam, "web-export", root, "--bundle", bundle, "--repo", repository],
            check=True, stdout=subprocess.DEVNULL,
        )
        # Held in a dict: the interaction test stops it and starts another on the same port.
        static = {"server": serve(root), "root": root}
        url = f"http://127.0.0.1:{static['server'].server_address[1]}/index.html"
        failures = []

        t = time.time()
        status, shot, console, stderr, moved = open_viewer(WEBGPU_FLAGS, url, converged, interact=static)
        wall = time.time() - t
        save_screenshot(shot, "webgpu.png")
        webgpu_shot = shot
        share, colours, size = terrain_share(shot)
        print(f"webgpu: status {json.dumps({k: v for k, v in (status or {}).items() if k not in ('cut', 'hud')})}")
        print(
            f"webgpu: first frame {status and status.get('firstFrameMs')} ms, converged "
            f"{status and status.get('convergedMs')} ms after navigation; terrain covers "
            f"{share:.1%} of the {size[0]}x{size[1]} screenshot in {colours} colours; "
            f"{status and status.get('measuredFps', 0):.1f} frames/s once converged "
            f"(the page's median frame: {status and status.get('frameMs')} ms); "
            f"{wall:.1f} s with the browser"
        )
        if not status or status.get("phase") != "running":
            failures.append(f"webgpu: page did not run: {status}")
        elif status.get("backend") != "webgpu":
            failures.append(f"webgpu: backend is {status.get('backend')}, not webgpu")
        elif status.get("wasm") != ["cbdam_web_bg.wasm"]:
            failures.append(f"webgpu: fetched {status.get('wasm')}, not the WebGPU module alone")
        elif not status.get("converged"):
            failures.append(f"webgpu: no convergence within {TIMEOUT_S} s")
        if size != (WIDTH, HEIGHT):
            failures.append(f"webgpu: screenshot is {size}, not {(WIDTH, HEIGHT)}")
        # Measured: 62 % in about 1 100 colours (the framed first view of jacksboro_mpl).
        if share < 0.5 or colours < 50:
            failures.append(f"webgpu: terrain covers {share:.1%} in {colours} colours")
        # The overlay shows the network counters the status has, and they are not zero.
        shown = hud_network((status or {}).get("hud"))
        print(f"hud: {(status or {}).get('hud')!r}")
        if not shown or shown[0] == 0 or shown[1] == 0:
            failures.append(f"hud: no non-zero requests and bytes in the overlay: {shown}")
        elif status and (shown[0] != status.get("recordsRequested")
                         or abs(shown[1] - status.get("bytes", 0) / 1024) > 0.1):
            failures.append(f"hud: the overlay shows {shown}, the status {status.get('recordsRequested')} "
                            f"requests and {status.get('bytes')} bytes")
        check_workers("webgpu", status, failures)
        if failures:
            print("console:\n  " + "\n  ".join(console[-20:]) + "\nstderr:\n" + stderr)

        # Decoding on the page's own thread (no workers): the same cut.
        status_page, _, _, _, _ = open_viewer(WEBGPU_FLAGS, url + "?workers=0", converged)
        w = (status_page or {}).get("workers") or {}
        print(
            f"page decoding: converged {status_page and status_page.get('convergedMs')} ms after "
            f"navigation (first frame {status_page and status_page.get('firstFrameMs')} ms), "
            f"{w.get('onPage')} diamonds decoded on the page, {w.get('count')} workers"
        )
        if not status_page or not converged(status_page) or status_page["cut"] != (status or {}).get("cut"):
            failures.append(f"page decoding: no convergence to the workers' cut: {status_page}")
        elif w.get("count") != 0 or not w.get("onPage"):
            failures.append(f"page decoding: ?workers=0 still decoded in workers: {w}")

        t = time.time()
        static_cut = (status or {}).get("cut")
        if not moved or not converged(moved):
            failures.append(f"input: no new converged cut after a drag and the wheel: {moved}")
        else:
            print(
                f"input: the drag and wheel moved the eye from {status['camera'][:3]} to "
                f"{moved['camera'][:3]}; new cut of {len(moved['cut'])} diamonds"
            )
            for line in moved.get("lines", []):
                print(line)
            failures += moved.get("failures", ["keys: not run"])

        if moved and converged(moved):
            # The URL with the hash the page wrote restores the view: the same camera (to the
            # hash's centimetres) and the same converged cut.
            restored, restored_shot, _, _, _ = open_viewer(WEBGPU_FLAGS, url + moved["hash"], converged)
            print(f"hash: {moved['hash']} restored {restored and restored.get('camera')}")
            if not restored or not converged(restored):
                failures.append(f"hash: the page did not converge from {moved['hash']}: {restored}")
            elif max(abs(a - b) for a, b in zip(restored["camera"], moved["camera"])) > 0.01:
                failures.append(f"hash: camera {restored['camera']} is not {moved['camera']}")
            elif restored["cut"] != moved["cut"]:
                failures.append("hash: the restored view converged to another cut")
            else:
                # The same camera on the command line: `cbdam render` converges to the same
                # diamonds (native refinement over the memory-mapped file, unlimited budget).
                cut_file = os.path.join(root, "native-cut.txt")
                camera = moved["hash"][len("#camera="):]
                native_png = render_native(cbdam, repository, camera,
                                           os.path.join(root, "native.png"), cut_file)
                native = open(cut_file).read().split()
                print(f"render: cbdam render's cut for that camera has {len(native)} diamonds")
                if native != restored["cut"]:
                    failures.append(
                        f"render: the page's cut ({len(restored['cut'])} diamonds) differs from "
                        f"cbdam render's ({len(native)}): only page {sorted(set(restored['cut']) - set(native))[:5]}, "
                        f"only native {sorted(set(native) - set(restored['cut']))[:5]}"
                    )
                else:
                    save_screenshot(restored_shot, "restored.png")
                    save_screenshot(native_png, "native.png")
                    check_native_image(root, repository, cbdam, camera, restored_shot,
                                       native_png, failures)

        check_flight(url, root, repository, cbdam, failures)
        check_colour(url, root, bundle, repository, cbdam, static_cut, webgpu_shot, failures)

        # Three record requests refused (503), then a corrupt record (its checksum fails): each
        # is retried, and the page still converges to the same cut.
        RangeHandler.refuse["left"] = 3
        RangeHandler.corrupt["armed"] = True
        status, _, _, _, _ = open_viewer(WEBGPU_FLAGS, url, converged)
        print(
            f"faults: {RangeHandler.refuse['done']} requests refused, "
            f"{RangeHandler.corrupt['done']} record corrupted; converged "
            f"{status and status.get('converged')}, {status and status.get('fetchErrors')} fetch errors"
        )
        if RangeHandler.corrupt["done"] != 1 or RangeHandler.refuse["done"] != 3:
            failures.append("faults: not every fault was served (the test did not test)")
        elif not status or not converged(status) or status["cut"] != static_cut:
            failures.append(f"faults: no convergence to the clean run's cut: {status}")
        elif (status.get("fetchErrors") or 0) < 4:
            failures.append(f"faults: {status.get('fetchErrors')} fetch errors counted, not 4")
        check_workers("faults", status, failures)

        proc, base = start_server(cbdam, repository)
        try:
            name = os.path.splitext(os.path.basename(repository))[0]
            served = f"{url.split('?')[0]}?repo={base}/v1/repos/{name}"
            status, shot, console, stderr, _ = open_viewer(WEBGPU_FLAGS, served, converged)
        finally:
            proc.terminate()
            proc.wait(10)
        share, colours, _ = terrain_share(shot)
        print(
            f"serve: converged {status and status.get('converged')} at "
            f"{status and status.get('convergedMs')} ms, {status and status.get('recordsRequested')} "
            f"records requested; terrain covers {share:.1%}"
        )
        if not status or not converged(status):
            failures.append(f"serve: the page did not converge against cbdam serve: {status}")
            print("console:\n  " + "\n  ".join(console[-20:]))
        elif status["cut"] != static_cut:
            failures.append(
                f"serve: the cut differs from the static file's: {len(status['cut'])} vs "
                f"{len(static_cut or [])} diamonds"
            )
        if share < 0.5:
            failures.append(f"serve: terrain covers {share:.1%}")

        # No WebGPU flags: the browser offers WebGL2 only (ANGLE on SwiftShader), and the page
        # draws through it (the renderer's texture path): the same first view and cut.
        t = time.time()
        status, shot, console, stderr, _ = open_viewer([], url, converged)
        wall = time.time() - t
        save_screenshot(shot, "webgl2.png")
        share, colours, _ = terrain_share(shot)
        alike = same_pixels(shot, webgpu_shot)
        print(
            f"webgl2: backend {status and status.get('backend')}, vertex fetch "
            f"{status and status.get('vertexFetch')}, adapter {status and status.get('adapter')!r}; "
            f"first frame {status and status.get('firstFrameMs')} ms, converged "
            f"{status and status.get('convergedMs')} ms after navigation; terrain covers "
            f"{share:.1%} in {colours} colours; {alike:.1%} of pixels within 6 levels of the "
            f"WebGPU screenshot; {wall:.1f} s with the browser"
        )
        if not status or status.get("phase") != "running":
            failures.append(f"webgl2: page did not run: {status}")
        elif status.get("webgpu") is not False or status.get("webgl2") is not True:
            failures.append(f"webgl2: the browser should offer WebGL2 and no WebGPU: {status}")
        elif status.get("wasm") != ["cbdam_web_gl_bg.wasm"]:
            failures.append(f"webgl2: fetched {status.get('wasm')}, not the WebGL2 module alone")
        elif status.get("backend") != "webgl" or status.get("vertexFetch") != "texture":
            failures.append(f"webgl2: drew through {status.get('backend')}/{status.get('vertexFetch')}")
        elif not converged(status):
            failures.append(f"webgl2: no convergence within {TIMEOUT_S} s")
        elif status["cut"] != static_cut:
            failures.append("webgl2: the page converged to another cut than with WebGPU")
        if share < 0.5 or colours < 50:
            failures.append(f"webgl2: terrain covers {share:.1%} in {colours} colours")
        check_workers("webgl2", status, failures)
        # Same cut, same shader maths, both on SwiftShader: nearly the same pixels.
        if alike < WEBGL2_ALIKE:
            failures.append(f"webgl2: only {alike:.1%} of pixels match the WebGPU screenshot")
        if failures and status and status.get("phase") != "running":
            print("console:\n  " + "\n  ".join(console[-20:]) + "\nstderr:\n" + stderr)

        # Neither WebGPU nor WebGL2; then a repository that cannot be read: clear messages.
        status, _, _, _, _ = open_viewer(["--disable-webgl"], url, lambda s: False)
        print(f"neither: {status and status.get('error')}")
        if not status or status.get("webgl2") is not False or "neither WebGPU nor WebGL2" not in status.get("error", ""):
            failures.append(f"neither: expected a message that names both APIs, got {status}")
        status, _, _, _, _ = open_viewer(WEBGPU_FLAGS, url + "?repo=missing.cbdam", lambda s: False)
        print(f"unreadable: {status and status.get('error')}")
        if not status or status.get("phase") != "failed" or "cannot read the repository" not in status.get("error", ""):
            failures.append(f"unreadable: expected 'cannot read the repository', got {status}")

        static["server"].shutdown()
        for f in failures:
            print("FAILED " + f, file=sys.stderr)
        return 1 if failures else 0
    finally:
        shutil.rmtree(root, ignore_errors=True)


def measure(size, bundle, repository, cbdam, repo_url=None, runs=int(os.environ.get("CBDAM_MEASURE_RUNS", "3"))):
    """`--measure WxH`: no checks, figures only; the page opens the exported repository, or
    `repo_url` (e.g. `cbdam serve` behind `cbdam link`). For each of `runs` fresh browsers: navigation
    to the first frame and to the converged cut, then the page's median frame interval and the
    frame rate over 3 s with the cut converged (drawing every frame, refining nothing); for
    WebGPU, then for WebGL2. With CBDAM_MEASURE_FLIGHT=FLIGHT.json the page plays that flight
    (CBDAM_MEASURE_FPS frames of flight time a second, default 30, as `cbdam render --path
    --fps`) and the figures of its frames are printed too (refinement step and frame interval: median, p99, largest)."""
    global WIDTH, HEIGHT
    WIDTH, HEIGHT = (int(v) for v in size.split("x"))
    root = tempfile.mkdtemp(prefix="cbdam-web-")
    try:
        subprocess.run([cbdam, "web-export", root, "--bundle", bundle, "--repo", repository],
                       check=True, stdout=subprocess.DEVNULL)
        server = serve(root)
        base = f"http://127.0.0.1:{server.server_address[1]}/index.html?"
        if repo_url:
            base += "repo=" + repo_url + "&"
        flight = os.environ.get("CBDAM_MEASURE_FLIGHT")
        if flight:
            shutil.copy(flight, os.path.join(root, "flight.json"))
            base += f"flight=flight.json&fps={os.environ.get('CBDAM_MEASURE_FPS', '30')}&"
        until = (lambda s: (s.get("flight") or {}).get("done") and converged(s)) if flight else converged
        # WebGPU, then WebGL2 (no WebGPU flags); decoding in workers, then on the page
        # (CBDAM_MEASURE_PAGE=1 adds the page runs), alternated.
        modes = ["workers"] + (["page"] if os.environ.get("CBDAM_MEASURE_PAGE") == "1" else [])
        plan = [(f, m) for f in [WEBGPU_FLAGS, []] for _ in range(runs) for m in modes]
        for run, (flags, mode) in enumerate(plan):
            run = (run // len(modes)) % runs
            url = base + ("workers=0" if mode == "page" else "")
            browser = Browser(flags)
            try:
                browser.call("Page.navigate", session=True, url=url)
                browser.wait_event("Page.loadEventFired", 30)
                # A flight's frames on SwiftShader at 1280x720 take a second or more each.
                s = wait_status(browser, until, timeout=600 if flight else TIMEOUT_S)
                count = "[window.cbdam.frames, performance.now()]"
                f0, t0 = browser.evaluate(count)
                time.sleep(3)
                f1, t1 = browser.evaluate(count)
                s2 = wait_status(browser, lambda s: True)
                w = s.get("workers") or {}
                busy = w.get("busyMs") or 0
                print(
                    f"measure {size} {s.get('backend')} {mode} run {run + 1}: "
                    f"{w.get('count')} workers decoded {w.get('decoded')} diamonds in {busy:.1f} ms "
                    f"({w.get('decoded', 0) * 1000 / busy if busy else 0:.0f}/s), {w.get('onPage')} on the page; "
                    f"decode time {s.get('decodeMs', 0):.1f} ms for {s.get('decoded')} diamonds "
                    f"({s.get('decoded', 0) * 1000 / max(s.get('decodeMs', 0), 1e-9):.0f}/s); page refinement "
                    f"{s.get('refineMs', [0, 0])[0]:.0f} ms in all, {s.get('refineMs', [0, 0])[1]:.1f} ms at most; first frame {s.get('firstFrameMs'):.0f} ms, "
                    f"converged {s.get('convergedMs'):.0f} ms after navigation "
                    f"({s.get('refined')} diamonds, {s.get('triangles')} triangles, "
                    f"{s.get('bytes')} bytes in {s.get('recordsRequested')} requests); converged: "
                    f"{(f1 - f0) * 1000 / (t1 - t0):.2f} frames/s, median frame "
                    f"{s2.get('frameMs'):.1f} ms"
                )
                if flight:
                    f = s.get("flight") or {}
                    print(
                        f"measure {size} {s.get('backend')} {mode} run {run + 1} flight: {f.get('frame')} of "
                        f"{f.get('frames')} frames in {f.get('seconds', 0):.1f} s; refinement ms per frame "
                        f"median/p99/max {f.get('refineMs')}; frame interval ms {f.get('frameMs')}; "
                        f"{f.get('overBudget')} frames whose refinement step overran its budget "
                        f"(frames {[i for i, v in enumerate(f.get('refineMsPerFrame') or []) if v > 8][:12]}); "
                        f"largest error {f.get('maxErrorPx', 0):.2f} px"
                    )
            finally:
                browser.close()
        server.shutdown()
    finally:
        shutil.rmtree(root, ignore_errors=True)


def check_planet(bundle, repository, cbdam, name="planet", flags=None):
    """`--planet`: a planet (cube-sphere repository) exported and opened like a plane; the page
    converges and draws the whole globe, centred: the screenshot's non-sky pixels form a disc
    about 90 % of the frame's height (`Camera::globe`) around the frame's centre, filled with
    terrain in many colours, and the sky is left around it. `flags`: the browser's (WebGPU's by
    default; `[]` for WebGL2). Returns the failures."""
    flags = WEBGPU_FLAGS if flags is None else flags
    root = tempfile.mkdtemp(prefix="cbdam-web-planet-")
    try:
        subprocess.run([cbdam, "web-export", root, "--bundle", bundle, "--repo", repository],
                       check=True, stdout=subprocess.DEVNULL)
        server = serve(root)
        url = f"http://127.0.0.1:{server.server_address[1]}/index.html"
        t = time.time()
        status, shot, console, _, _ = open_viewer(flags, url, converged)
        wall = time.time() - t
        server.shutdown()
    finally:
        shutil.rmtree(root, ignore_errors=True)
    save_screenshot(shot, f"{name}.png")
    width, height, channels, rows = decode_png(shot)
    points, colours = [], set()
    for y, row in enumerate(rows):
        for x in range(width):
            r, g, b = row[x * channels : x * channels + 3]
            if abs(r - SKY[0]) + abs(g - SKY[1]) + abs(b - SKY[2]) > 12:
                points.append((x, y))
                colours.add((r >> 2, g >> 2, b >> 2))
    failures = []
    if not status or not converged(status):
        print("console:\n  " + "\n  ".join(console[-20:]))
        return [f"{name}: the page did not converge: {status}"]
    backend = "webgpu" if flags else "webgl"
    if status.get("backend") != backend:
        failures.append(f"{name}: drew through {status.get('backend')}, not {backend}")
    if not points:
        return [f"{name}: nothing but sky in the screenshot"]
    # The disc: centred where the non-sky pixels' box is, of the radius their area gives.
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    cx, cy = (min(xs) + max(xs) + 1) / 2, (min(ys) + max(ys) + 1) / 2
    radius = math.sqrt(len(points) / math.pi)
    inside = sum(1 for y in range(height) for x in range(width)
                 if math.hypot(x + 0.5 - cx, y + 0.5 - cy) < radius - 2)
    inner = sum(1 for x, y in points if math.hypot(x + 0.5 - cx, y + 0.5 - cy) < radius - 2)
    outer = sum(1 for x, y in points if math.hypot(x + 0.5 - cx, y + 0.5 - cy) > radius + 2)
    print(
        f"{name}: first frame {status.get('firstFrameMs')} ms, converged {status.get('convergedMs')} ms "
        f"after navigation ({status.get('refined')} diamonds, {status.get('triangles')} triangles); "
        f"disc centred at {cx:.1f}, {cy:.1f} of {width}x{height}, radius {radius:.1f} px "
        f"(box {max(xs) - min(xs) + 1}x{max(ys) - min(ys) + 1}), {len(colours)} colours; "
        f"{inside - inner} sky pixels inside it, {outer} terrain pixels outside; {wall:.1f} s"
    )
    # Measured: centred to a pixel, radius 216 px (0.9 of 480 / 2), no sky inside.
    if abs(cx - width / 2) > 3 or abs(cy - height / 2) > 3:
        failures.append(f"{name}: the globe is centred at {cx:.1f}, {cy:.1f}, not the frame's centre")
    if abs(2 * radius - 0.9 * min(width, height)) > 10:
        failures.append(f"{name}: the disc is {2 * radius:.1f} px across, not 90 % of {min(width, height)}")
    if inside - inner > 0.001 * inside or outer > 0.001 * inside:
        failures.append(f"{name}: not a disc: {inside - inner} sky pixels inside, {outer} terrain outside")
    if len(colours) < 50:
        failures.append(f"{name}: only {len(colours)} colours: no terrain drawn on the globe")
    return failures


def check_digests(bundle, cbdam, repositories):
    """wasm32 decodes what native decodes, bit for bit: the page's module (the WebGPU build, as
    the workers run it) digests each repository's whole decoded surface (every diamond of every
    level: `decoded_digest`, client/web/src/digest.rs) and each digest must equal `cbdam inspect
    --digest` of the same file. Repositories of one surface coded by different coders must give
    one digest too: every repository but the last two holds one surface (the caller passes the
    default coder's, fast-rice's, adaptive-grid's and adaptive-inband's, then an RMS build with
    a quantizer per level and the planet, each a surface of its own). Returns failures."""
    failures = []
    root = tempfile.mkdtemp(prefix="cbdam-digest-")
    try:
        subprocess.run(
            [cbdam, "web-export", root, "--bundle", bundle, "--repo", repositories[0]],
            check=True, stdout=subprocess.DEVNULL,
        )
        names = []
        for i, repo in enumerate(repositories):
            name = f"digest-{i}.cbdam"
            shutil.copyfile(repo, os.path.join(root, name))
            names.append(name)
        server = serve(root)
        url = f"http://127.0.0.1:{server.server_address[1]}/index.html?repo={names[0]}"
        browser = Browser(WEBGPU_FLAGS)
        try:
            browser.call("Page.navigate", session=True, url=url)
            browser.wait_event("Page.loadEventFired", 30)
            deadline = time.time() + TIMEOUT_S
            while not browser.evaluate("typeof window.cbdamDecodedDigest === 'function'"):
                if time.time() > deadline:
                    return [f"digest: the page never offered cbdamDecodedDigest: {browser.console[-5:]}"]
                time.sleep(0.2)
            digests = {}
            for i, (repo, name) in enumerate(zip(repositories, names)):
                t = time.time()
                r = browser.call(
                    "Runtime.evaluate", session=True, awaitPromise=True, returnByValue=True,
                    expression=f"window.cbdamDecodedDigest({json.dumps(name)})",
                )
                wasm_s = time.time() - t
                page = r.get("result", {}).get("value")
                if "exceptionDetails" in r or not isinstance(page, str):
                    why = r.get("exceptionDetails", {}).get("exception", {}).get("description")
                    failures.append(f"digest: {repo}: the page could not decode it: {why or r}")
                    continue
                meta = json.loads(subprocess.run(
                    [cbdam, "inspect", "--json", "--digest", repo],
                    check=True, capture_output=True, text=True,
                ).stdout)
                d = meta["decoded_digest"]
                native = f"{d['fnv1a64']} {d['diamonds']} {d['samples']}"
                print(f"digest: {os.path.basename(repo)} ({meta.get('coder', '?')}): wasm32 {page} "
                      f"in {wasm_s:.2f} s, native {native}")
                if page != native:
                    failures.append(f"digest: {repo}: wasm32 decodes {page}, native {native}")
                digests[i] = page
            surface = {digests[i] for i in range(len(repositories) - 2) if i in digests}
            if len(surface) > 1:
                failures.append(f"digest: one surface, several coders, {len(surface)} digests: "
                                f"{sorted(surface)}")
        finally:
            browser.close()
            server.shutdown()
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return failures


if __name__ == "__main__":
    if sys.argv[1] == "--digest":
        # BUNDLE CBDAM REPO...: all repositories but the last hold one surface in several coders.
        digest_failures = check_digests(sys.argv[2], sys.argv[3], sys.argv[4:])
        for f in digest_failures:
            print("FAILED " + f, file=sys.stderr)
        sys.exit(1 if digest_failures else 0)
    if sys.argv[1] == "--measure":
        sys.exit(measure(*sys.argv[2:7]))
    if sys.argv[1] == "--planet":
        # The globe through WebGPU, then through WebGL2 (no WebGPU flags).
        planet_failures = check_planet(*sys.argv[2:5])
        planet_failures += check_planet(*sys.argv[2:5], name="planet-webgl2", flags=[])
        for f in planet_failures:
            print("FAILED " + f, file=sys.stderr)
        sys.exit(1 if planet_failures else 0)
    sys.exit(main())
