// Identifiers of the console's objects (namespace "esg"): a kind and its parts joined by "~",
// each part URI-encoded so a spacecraft id can hold any character.
export const NAMESPACE = 'esg';

export function makeKey(kind, ...parts) {
  return [kind, ...parts.map((p) => encodeURIComponent(String(p)).replace(/~/g, '%7E'))].join('~');
}

export function parseKey(key) {
  const [kind, ...parts] = key.split('~');
  return { kind, parts: parts.map(decodeURIComponent) };
}

export function id(kind, ...parts) {
  return { namespace: NAMESPACE, key: makeKey(kind, ...parts) };
}
