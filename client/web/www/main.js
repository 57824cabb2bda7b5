// Loads the viewer's wasm module and starts it on the canvas for the repository named by the
// page URL: ?repo=URL (a .cbdam file on a server with Range support, or a `cbdam serve`
// repository, http://host:port/v1/repos/NAME; relative URLs are resolved against the page), or
// else by the page's <meta name="cbdam-repo"> (set by `cbdam web-export --repo`),
// with ?colour=URL (or <meta name="cbdam-colour">) a colour repository draped over it.
// Shows window.cbdam (the viewer's status, client/web/src/status.rs) in the overlay, and drives
// the pixel-error slider.
// Two builds of the viewer (scripts/web-build.sh): cbdam_web.js draws through WebGPU only;
// cbdam_web_gl.js through WebGL2 only (wgpu's GL backend) and is about three times larger, so
// only a browser without a WebGPU adapter loads it (a bundle without it falls back to the first,
// which then says WebGPU is needed).
async function hasWebGpu() {
  try {
    return Boolean(navigator.gpu && (await navigator.gpu.requestAdapter()));
  } catch {
    return false;
  }
}
async function loadViewer() {
  if (!(await hasWebGpu())) {
    try {
      return await import("./cbdam_web_gl.js");
    } catch (e) {
      console.warn("cbdam: no WebGL2 build of the viewer (" + e + "), trying the WebGPU one");
    }
  }
  return await import("./cbdam_web.js");
}
let viewer = null;

const canvas = document.getElementById("view");
const overlay = document.getElementById("overlay");
const slider = document.getElementById("pixel-error");
const sliderValue = document.getElementById("pixel-error-value");

function fitCanvas() {
  const ratio = window.devicePixelRatio || 1;
  canvas.width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  canvas.height = Math.max(1, Math.round(canvas.clientHeight * ratio));
}

function fail(message) {
  window.cbdam = { phase: "failed", error: message, frames: 0, converged: false };
}

const fmt = (v, d = 0) => (v === undefined || v === null ? "-" : Number(v).toFixed(d));
const mib = (bytes) => fmt(bytes / 1048576, 1);
// The slider's last value until the viewer uses it (it applies it at its next frame).
let requested = null;
const pixels = (px) => (px >= 1 ? `${px}` : `1/${Math.round(1 / px)}`) + " px";

// Where the decoding runs: Web Workers (how many, diamonds decoded), or the page and why.
function decoding(w) {
  if (!w) return "decoding: -";
  const where = w.count > 0 ? `${w.count} workers, ${fmt(w.decoded)} diamonds` : "on the page";
  return `decoding: ${where}` + (w.onPage > 0 ? `, ${fmt(w.onPage)} on the page` : "") +
    (w.problem ? ` (${w.problem})` : "");
}

// A camera flight played by the page (?flight=URL): its progress, then its figures.
function flightLine(f) {
  if (!f) return "";
  if (f.error) return `\nflight: ${f.error}`;
  const how = f.stopped ? "stopped" : f.done ? "done" : "flying";
  const figures = f.refineMs
    ? ` · refine ms p50 ${fmt(f.refineMs[0], 2)} p99 ${fmt(f.refineMs[1], 2)}` +
      ` · frame ms p50 ${fmt(f.frameMs[0], 1)} p99 ${fmt(f.frameMs[1], 1)}`
    : "";
  return `\nflight: ${how}, frame ${fmt(f.frame)}/${fmt(f.frames)} at ${fmt(f.fps)} fps${figures}`;
}

function showStatus() {
  const s = window.cbdam;
  if (!s) return;
  if (s.phase === "failed") {
    overlay.className = "failed";
    overlay.textContent = "cbdam: " + s.error;
    return;
  }
  const cpu = s.cpuCache || [];
  const gpu = s.gpuCache || [];
  const state = s.frozen ? "FROZEN" : s.converged ? "converged" : "refining";
  overlay.textContent =
    `${s.phase} · ${s.backend || "-"}${s.vertexFetch === "texture" ? " (texture path)" : ""} · ` +
    `${s.mode || "orbit"}${s.draped ? " · colour draped" : ""} · ${s.adapter || ""}\n` +
    `fps ${fmt(s.fps, 1)} (${fmt(s.frameMs, 1)} ms) · triangles ${fmt(s.triangles)}\n` +
    `cut ${fmt(s.refined)} diamonds, ${fmt(s.drawnHalves)} half-patches · ${state}\n` +
    `pixel error ${s.pixelError ? pixels(s.pixelError) : "-"} target, ${fmt(s.maxErrorPx, 2)} px max\n` +
    `cache: records ${mib(cpu[0])}/${mib(cpu[1])} MiB, decoded ${mib(cpu[2])}/${mib(cpu[3])} MiB, ` +
    `GPU ${fmt(gpu[0])}/${fmt(gpu[1])} slots\n` +
    `network: ${fmt(s.recordsRequested)} requests, ${fmt((s.bytes || 0) / 1024, 1)} KiB, ` +
    `${fmt(s.inFlight)} in flight, ${fmt(s.fetchErrors)} errors\n` +
    decoding(s.workers) +
    flightLine(s.flight) +
    (s.notice ? `\n${s.notice}` : "");
  // The slider follows the target (keys change it too) unless it is being used.
  if (requested !== null && s.pixelError !== requested) return;
  requested = null;
  if (s.pixelError && document.activeElement !== slider) {
    slider.value = String(Math.round(Math.log2(s.pixelError)));
    sliderValue.textContent = pixels(s.pixelError);
  }
}

fitCanvas();
window.addEventListener("resize", fitCanvas);
setInterval(showStatus, 250);
slider.addEventListener("input", () => {
  const px = 2 ** Number(slider.value);
  sliderValue.textContent = pixels(px);
  requested = px;
  viewer?.set_pixel_error(px);
});
// The slider keeps keyboard focus after a drag; give it back to the view for the keys.
slider.addEventListener("change", () => slider.blur());

// ?flight=URL[&fps=N]: plays a camera flight (the JSON of `cbdam render --path`), one frame of
// flight time (1/N s, default 30) per animation frame; the overlay and window.cbdam.flight
// show its progress and, at its end, its refinement and frame times.
async function playFlight(module, url, fps) {
  try {
    const response = await fetch(new URL(url, location.href));
    if (!response.ok) throw new Error(`HTTP ${response.status} for ${url}`);
    module.play_flight(await response.text(), fps);
  } catch (e) {
    if (window.cbdam) window.cbdam.flight = { error: `cannot play the flight ${url}: ${e.message || e}` };
  }
}

const repo =
  new URLSearchParams(location.search).get("repo") ||
  document.querySelector('meta[name="cbdam-repo"]')?.content;
if (!repo) {
  fail("no repository: open this page with ?repo=URL (a .cbdam file or a cbdam serve repository)");
  showStatus();
} else {
  try {
    const module = await loadViewer();
    await module.default();
    viewer = module;
    // The digest of a whole repository's decoded surface, decoded here in wasm32 (the browser
    // test compares it with `cbdam inspect --digest`): "fnv1a64 diamonds samples".
    window.cbdamDecodedDigest = async (url) => {
      const response = await fetch(new URL(url, location.href));
      if (!response.ok) throw new Error(`HTTP ${response.status} for ${url}`);
      return module.decoded_digest(new Uint8Array(await response.arrayBuffer()));
    };
    // Decoding runs in Web Workers (worker.js, next to this file) that load the same module;
    // ?workers=0 decodes on the page instead (for comparisons).
    const workers = new URLSearchParams(location.search).get("workers") !== "0";
    const script = workers ? new URL("./worker.js", import.meta.url).href : undefined;
    const params = new URLSearchParams(location.search);
    // ?colour=URL drapes a colour repository (`cbdam build IMAGE --colour --like REPO`).
    const colour = params.get("colour") ||
      document.querySelector('meta[name="cbdam-colour"]')?.content;
    module.start(canvas, new URL(repo, location.href).href, script,
      colour ? new URL(colour, location.href).href : undefined);
    if (params.get("flight")) playFlight(module, params.get("flight"), Number(params.get("fps") || 30));
  } catch (e) {
    fail("cannot load the viewer: " + e);
    showStatus();
  }
}
