// node check.mjs BUNDLE [VECTORS]: the port against the conformance vectors under Node; prints
// a JSON report on the last line, exits 1 on a problem.
import { readFile } from "node:fs/promises";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";
import * as ort from "./vendor/ort.wasm.min.mjs";
import { Bundle, checkConformance } from "./mogo.mjs";

const here = dirname(fileURLToPath(import.meta.url));
const [bundleDir, vectorsPath = join(here, "conformance.json")] = process.argv.slice(2);
ort.env.wasm.numThreads = 1;
const read = async (name) => new Uint8Array(await readFile(join(bundleDir, name)));
const bundle = await Bundle.load(ort, read);
const vectors = JSON.parse(await readFile(vectorsPath, "utf8"));
const report = await checkConformance(bundle, vectors, (line) => console.error(line));
console.log(JSON.stringify(report));
process.exit(report.problems.length ? 1 : 0);
