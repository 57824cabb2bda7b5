// @mapbox/martini (RTIN) meshes for scripts/web-maps/martini_compare.py: reads one JSON object a
// line from stdin ({size, heights, maxError}; heights row after row, size = 2^k + 1) and writes
// one a line to stdout ({vertices: [x0, y0, x1, y1, ...] in grid cells, triangles: [...]}).
// Usage: node martini_mesh.js NODE_DIR (the directory holding node_modules/@mapbox/martini).
const path = require("path");
const readline = require("readline");
const Martini = require(path.resolve(process.argv[2], "node_modules/@mapbox/martini/martini.js"));
const rtins = new Map();
readline.createInterface({ input: process.stdin }).on("line", (line) => {
  const job = JSON.parse(line);
  if (!rtins.has(job.size)) rtins.set(job.size, new Martini(job.size));
  const tile = rtins.get(job.size).createTile(new Float32Array(job.heights));
  const mesh = tile.getMesh(job.maxError);
  process.stdout.write(JSON.stringify({ vertices: Array.from(mesh.vertices),
                                        triangles: Array.from(mesh.triangles) }) + "\n");
});
