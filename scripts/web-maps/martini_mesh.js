// @mapbox/martini (RTIN) and delatin (Delaunay refinement) meshes for
// scripts/web-maps/martini_compare.py: reads one JSON object a line from stdin ({mesher:
// "martini" | "delatin", size, heights, maxError}; heights row after row, size = 2^k + 1) and
// writes one a line to stdout ({vertices: [x0, y0, x1, y1, ...] in grid cells, triangles: [...]}).
// Usage: node martini_mesh.js NODE_DIR (the directory holding node_modules/@mapbox/martini and
// node_modules/delatin).
const path = require("path");
const readline = require("readline");
const { pathToFileURL } = require("url");
const dir = process.argv[2];
const Martini = require(path.resolve(dir, "node_modules/@mapbox/martini/martini.js"));

(async () => {
  // delatin is an ES module.
  const Delatin = (await import(pathToFileURL(path.resolve(dir, "node_modules/delatin/index.js")))).default;
  const rtins = new Map();
  readline.createInterface({ input: process.stdin }).on("line", (line) => {
    const job = JSON.parse(line);
    let vertices, triangles;
    if (job.mesher === "delatin") {
      const tin = new Delatin(job.heights, job.size, job.size);
      tin.run(job.maxError);
      [vertices, triangles] = [tin.coords, tin.triangles];
    } else {
      if (!rtins.has(job.size)) rtins.set(job.size, new Martini(job.size));
      const mesh = rtins.get(job.size).createTile(new Float32Array(job.heights)).getMesh(job.maxError);
      [vertices, triangles] = [mesh.vertices, mesh.triangles];
    }
    process.stdout.write(JSON.stringify({ vertices: Array.from(vertices),
                                          triangles: Array.from(triangles) }) + "\n");
  });
})();
