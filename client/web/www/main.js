// Loads the viewer's wasm module and starts it on the canvas for the repository named by the
// page URL: ?repo=URL (a .cbdam file on a server with Range support, or a `cbdam serve`
// repository, http://host:port/v1/repos/NAME; relative URLs are resolved against the page), or
// else by the page's <meta name="cbdam-repo"> (set by `cbdam web-export --repo`).
import init, { start } from "./cbdam_web.js";

const canvas = document.getElementById("view");
const overlay = document.getElementById("overlay");

function fitCanvas() {
  const ratio = window.devicePixelRatio || 1;
  canvas.width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  canvas.height = Math.max(1, Math.round(canvas.clientHeight * ratio));
}

function fail(message) {
  window.cbdam = { phase: "failed", error: message, frames: 0, converged: false };
}

function showStatus() {
  const s = window.cbdam;
  if (!s) return;
  if (s.phase === "failed") {
    overlay.className = "failed";
    overlay.textContent = "cbdam: " + s.error;
    return;
  }
  const fmt = (v, d = 0) => (v === undefined ? "-" : Number(v).toFixed(d));
  overlay.textContent =
    `${s.phase} · ${s.backend || "-"} · ${s.adapter || ""}\n` +
    `frames ${fmt(s.frames)} · refined ${fmt(s.refined)} · halves ${fmt(s.drawnHalves)} · ` +
    `triangles ${fmt(s.triangles)}\n` +
    `max error ${fmt(s.maxErrorPx, 2)} px · ${s.converged ? "converged" : "refining"}\n` +
    `records requested ${fmt(s.recordsRequested)} · ${fmt((s.bytes || 0) / 1024)} KiB · errors ${fmt(s.fetchErrors)}`;
}

fitCanvas();
window.addEventListener("resize", fitCanvas);
setInterval(showStatus, 250);

const repo =
  new URLSearchParams(location.search).get("repo") ||
  document.querySelector('meta[name="cbdam-repo"]')?.content;
if (!repo) {
  fail("no repository: open this page with ?repo=URL (a .cbdam file or a cbdam serve repository)");
  showStatus();
} else {
  try {
    await init();
    start(canvas, new URL(repo, location.href).href);
  } catch (e) {
    fail("cannot load the viewer: " + e);
    showStatus();
  }
}
