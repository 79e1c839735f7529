// node build.mjs [DIR]: bundles entry.js into ../../staggered_cli/viewer/vendor/three.min.js
// (or DIR/three.min.js: tests/test_view.py rebuilds it there and compares)
// with fixed options (the same bytes from the same pinned versions), copies
// three's LICENSE beside it and records the versions and the sha256 in
// three.version.json (tests/test_view.py checks the bundle against it).
import { build } from "esbuild";
import { createHash } from "node:crypto";
import { copyFileSync, readFileSync, writeFileSync } from "node:fs";
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const vendor = process.argv[2] ? resolve(process.argv[2]) : join(here, "..", "..", "staggered_cli", "viewer", "vendor");
const out = join(vendor, "three.min.js");
const version = (name) => JSON.parse(readFileSync(join(here, "node_modules", name, "package.json"), "utf8")).version;

await build({
  entryPoints: [join(here, "entry.js")],
  bundle: true,
  minify: true,
  format: "iife",
  target: "es2020",
  legalComments: "inline",
  charset: "utf8",
  sourcemap: false,
  outfile: out,
  logLevel: "warning",
});
copyFileSync(join(here, "node_modules", "three", "LICENSE"), join(vendor, "LICENSE.three.txt"));
const sha256 = createHash("sha256").update(readFileSync(out)).digest("hex");
const record = { file: "three.min.js", three: version("three"), esbuild: version("esbuild"), sha256 };
writeFileSync(join(vendor, "three.version.json"), JSON.stringify(record, null, 2) + "\n");
console.log(`three.min.js: three ${record.three}, esbuild ${record.esbuild}, sha256 ${sha256}`);
