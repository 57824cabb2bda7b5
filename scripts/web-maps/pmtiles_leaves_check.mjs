// The archive of pmtiles_leaves_check.py read by the npm `pmtiles` package (the reader
// MapLibre's protocol uses) in Node: every tile through `getZxy`, which walks the root and
// leaf directories, against the bytes computed here. Exits non-zero on the first difference.
// Usage: node pmtiles_leaves_check.mjs NODE_MODULES ARCHIVE.pmtiles MAX_ZOOM
import { openSync, readSync } from "node:fs";
import { pathToFileURL } from "node:url";
import path from "node:path";

const [nodeModules, archive, maxZoomArg] = process.argv.slice(2);
const { PMTiles, zxyToTileId } = await import(
  pathToFileURL(path.join(nodeModules, "pmtiles/dist/esm/index.js")).href);
const fd = openSync(archive, "r");
const source = {
  getKey: () => archive,
  getBytes: async (offset, length) => {
    const buf = Buffer.alloc(length);
    const n = readSync(fd, buf, 0, length, offset);
    return { data: buf.buffer.slice(buf.byteOffset, buf.byteOffset + n) };
  },
};
const sourceOf = (t) => (t % 5n === 4n ? sourceOf(t - 1n) : t % 11n === 10n && t > 20n ? 7n : t);
function payload(s) {
  const n = Number((s * 2654435761n) % 301n);
  const head = Buffer.from(`tile ${s}:`);
  const tail = Buffer.alloc(n);
  for (let i = 0; i < n; i++) tail[i] = Number((s * 7n + BigInt(i) * 13n) % 251n);
  return Buffer.concat([head, tail]);
}
const p = new PMTiles(source);
const header = await p.getHeader();
if (!(header.leafDirectoryLength > 0)) throw new Error("no leaf directories");
let checked = 0;
const maxZoom = Number(maxZoomArg);
for (let z = 0; z <= maxZoom; z++) {
  for (let x = 0; x < 1 << z; x++) {
    for (let y = 0; y < 1 << z; y++) {
      const got = await p.getZxy(z, x, y);
      const want = payload(sourceOf(BigInt(zxyToTileId(z, x, y))));
      if (!got || !Buffer.from(got.data).equals(want)) throw new Error(`tile ${z}/${x}/${y} differs`);
      checked++;
    }
  }
}
console.log(JSON.stringify({ reader: "npm pmtiles", tiles: checked,
  leafDirectoryBytes: header.leafDirectoryLength }));
