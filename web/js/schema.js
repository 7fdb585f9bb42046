// Checks data from the API against the frame schema (generated from hptvsim/episodes/frames.py).
// A small JSON Schema subset: $ref, anyOf, enum, type, properties, required,
// additionalProperties, items, prefixItems. Enough for every type frames.py generates.

import { FRAME_SCHEMA } from "./frames.gen.js";

function resolve(ref) {
  const name = ref.split("/").pop();
  const def = FRAME_SCHEMA.$defs[name];
  if (!def) throw new Error(`unknown schema reference ${ref}`);
  return def;
}

function typeOf(v) {
  if (v === null) return "null";
  if (Array.isArray(v)) return "array";
  return typeof v;
}

function check(s, v, path, errors) {
  if (errors.length > 20) return;
  if (s.$ref) {
    check(resolve(s.$ref), v, path, errors);
    return;
  }
  if (s.anyOf) {
    for (const alt of s.anyOf) {
      const e = [];
      check(alt, v, path, e);
      if (e.length === 0) return;
    }
    errors.push(`${path}: ${JSON.stringify(v)?.slice(0, 40)} matches none of its allowed types`);
    return;
  }
  if (s.enum) {
    if (!s.enum.includes(v)) errors.push(`${path}: ${JSON.stringify(v)} is not one of ${s.enum.join(", ")}`);
    return;
  }
  const t = typeOf(v);
  switch (s.type) {
    case "null":
    case "boolean":
    case "string":
      if (t !== s.type) errors.push(`${path}: expected ${s.type}, got ${t}`);
      return;
    case "number":
      if (t !== "number" || !Number.isFinite(v)) errors.push(`${path}: expected a number, got ${t}`);
      return;
    case "integer":
      if (!Number.isInteger(v)) errors.push(`${path}: expected an integer, got ${JSON.stringify(v)}`);
      return;
    case "array":
      if (t !== "array") {
        errors.push(`${path}: expected an array, got ${t}`);
        return;
      }
      if (s.prefixItems) {
        if (v.length !== s.prefixItems.length) errors.push(`${path}: expected ${s.prefixItems.length} items`);
        s.prefixItems.forEach((item, i) => check(item, v[i], `${path}[${i}]`, errors));
      } else if (s.items) {
        // long number arrays: check the type quickly
        if (s.items.type === "number") {
          if (!v.every((x) => typeof x === "number")) errors.push(`${path}: expected numbers`);
        } else {
          v.forEach((x, i) => check(s.items, x, `${path}[${i}]`, errors));
        }
      }
      return;
    case "object":
      if (t !== "object") {
        errors.push(`${path}: expected an object, got ${t}`);
        return;
      }
      for (const key of s.required || []) {
        if (!(key in v)) errors.push(`${path}.${key}: missing`);
      }
      for (const [key, value] of Object.entries(v)) {
        const sub = s.properties?.[key];
        if (sub) check(sub, value, `${path}.${key}`, errors);
        else if (s.additionalProperties === false) errors.push(`${path}.${key}: not in the schema`);
        else if (s.additionalProperties) check(s.additionalProperties, value, `${path}.${key}`, errors);
      }
      return;
    default:
      errors.push(`${path}: the validator has no rule for ${JSON.stringify(s).slice(0, 60)}`);
  }
}

/** Problems of `value` as the schema type `name` (an empty list when it conforms). */
export function validate(name, value) {
  const errors = [];
  check(resolve(`#/$defs/${name}`), value, name, errors);
  return errors;
}

/** The schema's version tag. */
export const VERSION = FRAME_SCHEMA.version;
