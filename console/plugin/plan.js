// The planned attitude a spacecraft's predictions use after its last frame, kept per spacecraft in
// this browser tab (sessionStorage). Text form: the CSV of `esg predict --planned`, one
// `time,q0,q1,q2,q3` line per sample (q_in_b, scalar first; an optional header line), so the same
// file serves the console and the CLI.
import { parseRfc3339 } from './time.js';

const PREFIX = 'esg.plan.';

export function parsePlan(text) {
  const samples = [];
  const lines = text.split(/\r?\n/).map((l) => l.trim()).filter((l) => l && !l.startsWith('#'));
  lines.forEach((line, i) => {
    const fields = line.split(',').map((f) => f.trim());
    if (i === 0 && Number.isNaN(Number(fields[1]))) return; // header
    if (fields.length !== 5) throw new Error(`line ${i + 1}: expected time,q0,q1,q2,q3`);
    const ms = parseRfc3339(fields[0]);
    if (!Number.isFinite(ms)) {
      throw new Error(`line ${i + 1}: '${fields[0]}' is not an RFC 3339 time such as 2019-03-01T00:00:00Z`);
    }
    const q = fields.slice(1).map(Number);
    if (q.some((x) => !Number.isFinite(x))) throw new Error(`line ${i + 1}: q0..q3 must be numbers`);
    samples.push({ time: new Date(ms).toISOString(), q_in_b: q });
  });
  for (let i = 1; i < samples.length; i++) {
    if (Date.parse(samples[i].time) <= Date.parse(samples[i - 1].time)) {
      throw new Error(`sample ${i + 1}: times must increase`);
    }
  }
  return samples;
}

export function planText(spacecraftId) {
  return sessionStorage.getItem(PREFIX + spacecraftId) || '';
}

// The planned samples, or null without a plan (esgd then holds the last estimate inertially).
export function planSamples(spacecraftId) {
  const text = planText(spacecraftId);
  return text ? parsePlan(text) : null;
}

export function setPlan(spacecraftId, text) {
  if (text.trim()) {
    parsePlan(text); // refuse a malformed plan here, with its line
    sessionStorage.setItem(PREFIX + spacecraftId, text);
  } else {
    sessionStorage.removeItem(PREFIX + spacecraftId);
  }
}
