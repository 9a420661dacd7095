// Build the viewer bundle into dist/: index.html + viewer.js (the native 4D viewer, no
// dependencies), splatv.html + splatv.js (the .splatv in gsplat.js, bundled in, no CDN),
// the pages' viewer.css and gsplat's licence. The Rust exporter copies dist/ into each export's viewer/ folder.
import { build } from "esbuild";
import { copyFileSync, mkdirSync } from "node:fs";

mkdirSync("dist", { recursive: true });
for (const [entry, out] of [["src/main.js", "viewer.js"], ["src/splatv.js", "splatv.js"]]) {
  await build({
    entryPoints: [entry],
    bundle: true,
    format: "esm",
    minify: !process.env.VIEWER_DEBUG,
    target: "es2020",
    outfile: `dist/${out}`,
    logLevel: "warning",
  });
}
copyFileSync("index.html", "dist/index.html");
copyFileSync("splatv.html", "dist/splatv.html");
copyFileSync("viewer.css", "dist/viewer.css");
copyFileSync("node_modules/gsplat/LICENSE", "dist/gsplat-LICENSE.txt");
console.log("viewer: built dist/");
