// Build the viewer bundle into dist/: index.html, viewer.js (gsplat bundled in, no CDN)
// and gsplat's licence. The Rust exporter copies dist/ into each export's viewer/ folder.
import { build } from "esbuild";
import { copyFileSync, mkdirSync } from "node:fs";

mkdirSync("dist", { recursive: true });
await build({
  entryPoints: ["src/main.js"],
  bundle: true,
  format: "esm",
  minify: !process.env.VIEWER_DEBUG,
  target: "es2020",
  outfile: "dist/viewer.js",
  logLevel: "warning",
});
copyFileSync("index.html", "dist/index.html");
copyFileSync("node_modules/gsplat/LICENSE", "dist/gsplat-LICENSE.txt");
console.log("viewer: built dist/");
