// JSON-schema check of Kubernetes objects with the validators of the npm
// package kubernetes-models (compiled by ajv from the Kubernetes OpenAPI
// schema): types, formats, enums and required fields of every object.
//
//   node k8s_schema.mjs NODE_MODULES DOCS.json
//
// DOCS.json is what tests/deploy/k8s_fields.py writes. Prints one line per
// object and exits 1 if any is invalid or of a kind the package lacks.
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { pathToFileURL } from "node:url";

const [modules, docsFile] = process.argv.slice(2);
if (!modules || !docsFile) {
  console.error("usage: node k8s_schema.mjs NODE_MODULES DOCS.json");
  process.exit(2);
}
const docs = JSON.parse(readFileSync(docsFile, "utf8"));
let failed = 0;
for (const { file, doc, object } of docs) {
  const where = `${file} document ${doc} (${object.kind} ${object.metadata?.name ?? "?"})`;
  // apps/v1 -> kubernetes-models/apps/v1, v1 (the core group) -> kubernetes-models/v1
  const dir = join(modules, "kubernetes-models", ...object.apiVersion.split("/"));
  let model;
  try {
    model = (await import(pathToFileURL(join(dir, "index.js")).href))[object.kind];
  } catch (e) {
    model = undefined;
  }
  if (!model) {
    console.log(`FAIL ${where}: kubernetes-models has no ${object.apiVersion} ${object.kind}`);
    failed++;
    continue;
  }
  try {
    new model(object).validate();
    console.log(`ok   ${where}`);
  } catch (e) {
    console.log(`FAIL ${where}: ${e.message}`);
    failed++;
  }
}
process.exit(failed ? 1 : 0);
