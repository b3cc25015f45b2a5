// JSON shapes of the console API (docs/console-gateway.md "JSON"), driven by the message
// descriptors @grpc/proto-loader produced, so every field is converted by its declared type and
// never guessed from its value:
//   - field names as in the .proto files (snake_case), every scalar and repeated field present
//     (proto3 defaults included, repeated fields possibly []), absent message fields omitted;
//     except a deprecated field holding its default (a drift model's fields of the release
//     before its keyed `coefficients`), left out as `esg --json` leaves it out;
//   - google.protobuf.Timestamp <-> ISO-8601 UTC string with milliseconds
//     ("2026-01-01T00:00:00.000Z"); parsing keeps up to nanoseconds;
//   - int64 as JSON numbers (proto-loader is set up with longs: Number), enums as their names;
//   - non-finite doubles as the proto3 JSON strings "NaN", "Infinity", "-Infinity".
'use strict';

const TIMESTAMP = 'google.protobuf.Timestamp';

class ConvertError extends Error {}

// Whether a field holds its proto3 default: no entries, no message, 0, false or ''. A deprecated
// field at its default was not given (docs/formats.md: esgd writes the keyed coefficients, the
// fields of the release before are read only).
function isDefault(field, value, repeated) {
  if (value === null || value === undefined) return true;
  if (repeated) return Array.isArray(value) && value.length === 0;
  if (field.type === 'TYPE_MESSAGE') return false;
  return value === 0 || value === false || value === '';
}

// Resolves a field's typeName (relative, as protobufjs writes it) against the package scope of
// the message that declares it, the way protoc does: innermost scope first.
function resolveType(definition, scope, typeName) {
  if (typeName.startsWith('.')) typeName = typeName.slice(1);
  const parts = scope.split('.');
  for (let n = parts.length; n >= 0; n--) {
    const candidate = [...parts.slice(0, n), typeName].filter(Boolean).join('.');
    if (definition[candidate]) return candidate;
  }
  throw new Error(`proto: type '${typeName}' not found from '${scope}'`);
}

function packageOf(fullName) {
  return fullName.slice(0, Math.max(0, fullName.lastIndexOf('.')));
}

function timestampToIso(ts) {
  const ms = Number(ts.seconds) * 1000 + Math.floor((ts.nanos || 0) / 1e6);
  const date = new Date(ms);
  if (Number.isNaN(date.getTime())) return null;
  return date.toISOString();
}

// ISO-8601 UTC (or with an offset) -> {seconds, nanos}; null when it is not one. Accepts
// "2019-03-01T00:00:00Z", "2019-03-01T00:00:00.123456789Z", "2019-03-01T03:00:00+03:00" and a
// date alone ("2019-03-01": its midnight UTC).
function isoToTimestamp(text) {
  if (typeof text !== 'string') return null;
  const m = /^(\d{4}-\d{2}-\d{2})(?:[Tt ](\d{2}:\d{2}(?::\d{2})?)(?:\.(\d{1,9}))?([Zz]|[+-]\d{2}:\d{2}))?$/
    .exec(text);
  if (!m) return null;
  const whole = m[2] ? `${m[1]}T${m[2]}${m[4].toUpperCase()}` : `${m[1]}T00:00:00Z`;
  const ms = Date.parse(whole);
  if (Number.isNaN(ms)) return null;
  // Date.parse rolls "02-30" over into March: reject dates that do not print back the same.
  const [y, mo, d] = m[1].split('-').map(Number);
  const check = new Date(Date.UTC(y, mo - 1, d));
  if (check.getUTCFullYear() !== y || check.getUTCMonth() !== mo - 1 || check.getUTCDate() !== d) {
    return null;
  }
  const nanos = m[3] ? Number(m[3].padEnd(9, '0')) : 0;
  return { seconds: Math.floor(ms / 1000), nanos };
}

class Converter {
  // definition: the package definition of @grpc/proto-loader (its keys are full type names).
  constructor(definition) {
    this.definition = definition;
  }

  descriptor(typeName) {
    const entry = this.definition[typeName];
    if (!entry || !entry.type || !entry.type.field) throw new Error(`proto: no message ${typeName}`);
    return entry.type;
  }

  // A message as proto-loader deserialized it -> the console's JSON object.
  toJson(typeName, message) {
    if (typeName === TIMESTAMP) return timestampToIso(message);
    const out = {};
    const scope = packageOf(typeName);
    for (const field of this.descriptor(typeName).field) {
      const value = message[field.name];
      const repeated = field.label === 'LABEL_REPEATED';
      if (field.options && field.options.deprecated && isDefault(field, value, repeated)) continue;
      if (field.type === 'TYPE_MESSAGE') {
        const sub = resolveType(this.definition, scope, field.typeName);
        if (repeated) {
          out[field.name] = (value || []).map((v) => this.toJson(sub, v));
        } else if (value !== null && value !== undefined) {
          const converted = this.toJson(sub, value);
          if (converted !== null) out[field.name] = converted;
        }
      } else if (repeated) {
        out[field.name] = (value || []).map((v) => scalarToJson(field.type, v));
      } else {
        out[field.name] = scalarToJson(field.type, value);
      }
    }
    return out;
  }

  // The console's JSON object -> a plain object proto-loader can serialize as `typeName`.
  // Throws ConvertError whose message starts with the offending field path, e.g.
  // "planned_attitude[2].time: expected an ISO-8601 UTC time, got 'x'".
  fromJson(typeName, json, path = '') {
    if (json === null || typeof json !== 'object' || Array.isArray(json)) {
      throw new ConvertError(`${path || 'body'}: expected a JSON object`);
    }
    const descriptor = this.descriptor(typeName);
    const scope = packageOf(typeName);
    const byName = new Map(descriptor.field.map((f) => [f.name, f]));
    const out = {};
    for (const [key, value] of Object.entries(json)) {
      const where = path ? `${path}.${key}` : key;
      const field = byName.get(key);
      if (!field) throw new ConvertError(`${where}: no such field in ${typeName}`);
      if (value === null) continue;
      if (field.label === 'LABEL_REPEATED') {
        if (!Array.isArray(value)) throw new ConvertError(`${where}: expected an array`);
        out[key] = value.map((v, i) => this.fieldFromJson(field, scope, v, `${where}[${i}]`));
      } else {
        out[key] = this.fieldFromJson(field, scope, value, where);
      }
    }
    return out;
  }

  fieldFromJson(field, scope, value, where) {
    if (field.type === 'TYPE_ENUM') {
      const values = this.definition[resolveType(this.definition, scope, field.typeName)].type.value;
      if (!values.some((v) => v.name === value || v.number === value)) {
        throw new ConvertError(`${where}: expected one of ${values.map((v) => v.name).join(', ')}, got ${JSON.stringify(value)}`);
      }
      return value;
    }
    if (field.type !== 'TYPE_MESSAGE') return scalarFromJson(field.type, value, where);
    const sub = resolveType(this.definition, scope, field.typeName);
    if (sub === TIMESTAMP) {
      const ts = isoToTimestamp(value);
      if (!ts) throw new ConvertError(`${where}: expected an ISO-8601 UTC time, got ${JSON.stringify(value)}`);
      return ts;
    }
    return this.fromJson(sub, value, where);
  }
}

function scalarToJson(type, value) {
  if ((type === 'TYPE_DOUBLE' || type === 'TYPE_FLOAT') && !Number.isFinite(value)) {
    if (Number.isNaN(value)) return 'NaN';
    return value > 0 ? 'Infinity' : '-Infinity';
  }
  return value;
}

const INTEGER_TYPES = new Set(['TYPE_INT32', 'TYPE_INT64', 'TYPE_SINT32', 'TYPE_SINT64',
  'TYPE_SFIXED32', 'TYPE_SFIXED64', 'TYPE_UINT32', 'TYPE_UINT64', 'TYPE_FIXED32', 'TYPE_FIXED64']);

function scalarFromJson(type, value, where) {
  if (type === 'TYPE_DOUBLE' || type === 'TYPE_FLOAT') {
    if (typeof value === 'number') return value;
    if (value === 'NaN') return NaN;
    if (value === 'Infinity') return Infinity;
    if (value === '-Infinity') return -Infinity;
    throw new ConvertError(`${where}: expected a number, got ${JSON.stringify(value)}`);
  }
  if (INTEGER_TYPES.has(type)) {
    const n = typeof value === 'string' && /^-?\d+$/.test(value) ? Number(value) : value;
    if (!Number.isSafeInteger(n)) {
      throw new ConvertError(`${where}: expected an integer, got ${JSON.stringify(value)}`);
    }
    return n;
  }
  if (type === 'TYPE_BOOL') {
    if (typeof value !== 'boolean') throw new ConvertError(`${where}: expected true or false, got ${JSON.stringify(value)}`);
    return value;
  }
  if (type === 'TYPE_STRING') {
    if (typeof value !== 'string') throw new ConvertError(`${where}: expected a string, got ${JSON.stringify(value)}`);
    return value;
  }
  throw new ConvertError(`${where}: fields of type ${type} are not supported`);
}

module.exports = { Converter, ConvertError, isoToTimestamp, timestampToIso };
