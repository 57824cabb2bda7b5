// A decode worker: instantiates the same wasm module as the page (the name comes in the first
// message: cbdam_web or cbdam_web_gl), sets up its decoder from the repository head's bytes,
// then answers each job message (a decode job as bytes, client/src/refine/wire.rs) with its
// results, transferring the buffer back. Started by client/web/src/workers.rs.
let ready = null;
let wasm = null;

async function setUp(module, context) {
  wasm = await import(`./${module}.js`);
  await wasm.default();
  wasm.init_worker(context);
}

self.onmessage = async (event) => {
  const m = event.data;
  if (m.kind === "init") {
    ready = setUp(m.module, m.context);
    try {
      await ready;
      self.postMessage({ kind: "ready" });
    } catch (e) {
      self.postMessage({ kind: "failed", error: String(e) });
    }
    return;
  }
  if (m.kind !== "job") return;
  try {
    await ready;
    const t = performance.now();
    const bytes = wasm.decode_job(m.bytes);
    const ms = performance.now() - t;
    self.postMessage({ kind: "done", id: m.id, bytes, ms }, [bytes.buffer]);
  } catch (e) {
    self.postMessage({ kind: "error", id: m.id, error: String(e) });
  }
};
