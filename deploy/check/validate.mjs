// Validates rendered overlays against the upstream JSON schemas that the npm packages
// kubernetes-models, @kubernetes-models/gateway-api and @kubernetes-models/prometheus-operator
// generate from the Kubernetes OpenAPI spec and the Gateway API and Prometheus Operator CRDs
// (types, required fields, enums, patterns, bounds; unknown fields are not rejected there:
// manifests.py's strict schemas do that).
//
//   node validate.mjs OUT_DIR/OVERLAY...   (reads OUT_DIR/OVERLAY.json, written by manifests.py)
//
// BackendTrafficPolicy has no such package: manifests.py's subset schema is its check.
import { readFileSync } from "node:fs";

const modules = {
  "v1": (kind) => `kubernetes-models/v1/${kind}`,
  "apps/v1": (kind) => `kubernetes-models/apps/v1/${kind}`,
  "policy/v1": (kind) => `kubernetes-models/policy/v1/${kind}`,
  "gateway.networking.k8s.io/v1": (kind) =>
    `@kubernetes-models/gateway-api/gateway.networking.k8s.io/v1/${kind}`,
  "monitoring.coreos.com/v1": (kind) =>
    `@kubernetes-models/prometheus-operator/monitoring.coreos.com/v1/${kind}`,
};
const noSchema = new Set(["gateway.envoyproxy.io/v1alpha1/BackendTrafficPolicy"]);

let failed = 0;
for (const arg of process.argv.slice(2)) {
  const file = arg.endsWith(".json") ? arg : `${arg}.json`;
  const docs = JSON.parse(readFileSync(file, "utf8"));
  const done = [];
  for (const doc of docs) {
    const id = `${doc.apiVersion}/${doc.kind}`;
    const where = `${file}: ${doc.kind}/${doc.metadata?.name}`;
    if (noSchema.has(id)) continue;
    const path = modules[doc.apiVersion]?.(doc.kind);
    if (!path) {
      console.error(`validate.mjs: ${where}: no schema for ${id}`);
      failed++;
      continue;
    }
    let Model;
    try {
      Model = (await import(path))[doc.kind];
    } catch (e) {
      console.error(`validate.mjs: ${where}: no model ${path}: ${e.message}`);
      failed++;
      continue;
    }
    if (doc.kind === "Secret" && doc.data) {
      // kustomize's secretGenerator wraps long base64 values over lines; the API server's
      // base64 decoding skips line breaks, the schema's "byte" format does not.
      for (const k of Object.keys(doc.data)) doc.data[k] = doc.data[k].replace(/\n/g, "");
    }
    try {
      new Model(doc).validate();
      done.push(doc.kind);
    } catch (e) {
      console.error(`validate.mjs: ${where}: ${e.message}`);
      failed++;
    }
  }
  console.log(`validate.mjs: ${file}: ${done.length} objects pass the upstream schemas (${done.join(", ")})`);
}
process.exit(failed ? 1 : 0);
