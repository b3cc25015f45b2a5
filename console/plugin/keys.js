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

// The page's address (location hash) of a stored diagnosis's report: its object in the tree,
// ESG spacecraft / SC / Diagnoses / Diagnosis N.
export function diagnosisHash(spacecraft, diagnosisId) {
  const path = [['root'], ['sc', spacecraft], ['diags', spacecraft], ['diag', spacecraft, diagnosisId]];
  return `#/browse/${path.map(([kind, ...parts]) => `${NAMESPACE}:${makeKey(kind, ...parts)}`).join('/')}`;
}

// The diagnosis a MODEL_DIAGNOSED alert answers with (docs/service.md "Automatic diagnosis": its
// value is the diagnosis id, its text names it too): {spacecraft, id, hash}; null for any other
// alert.
export function alertDiagnosis(alert) {
  if (!alert || alert.reason !== 'ALERT_REASON_MODEL_DIAGNOSED') return null;
  const diagnosisId = Math.round(Number(alert.value));
  if (!Number.isFinite(diagnosisId) || diagnosisId <= 0) return null;
  return { spacecraft: alert.spacecraft_id, id: diagnosisId, hash: diagnosisHash(alert.spacecraft_id, diagnosisId) };
}
