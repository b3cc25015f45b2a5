// One stored diagnosis (GET /api/spacecraft/:id/diagnoses/:n, GetDiagnosis with its report):
// verdict, whether esgd ran it itself and for which alert, findings with their parameters and
// evidence, the mismatch found, the fit before and after, and the gap errors as a bar chart.
// Report fields: docs/discovery.md "JSON".
// "Apply to the model" (POST .../diagnoses/:n/apply, ApplyDiagnosis with the write role): what the
// diagnosis would set (its `applies` lines) and what not, confirmed in a dialog, then the result:
// the configuration version stored and the re-run from the archive, or esgd's refusal. Offered
// only to a caller with the write role (api.js canWrite); a read-only one sees what it would set.
import { apiFetch, canWrite } from './api.js';
import { el, fixed, STYLE } from './dom.js';
import { gapChart } from './gapChart.js';
import { COEFFICIENTS } from './series.js';

const AXIS = ['x', 'y', 'z'];
// The fixed drift terms' report names (their configuration JSON keys, "c1DegH[0]") from the
// console's table of them (series.js COEFFICIENTS): "C11, rotor displacement (1st harmonic)".
const FIXED_TERM_NAMES = {};
for (const c of COEFFICIENTS) {
  const name = `${c.label}, ${c.meaning}`;
  if (c.component < 0) FIXED_TERM_NAMES[c.jsonKey] = name;
  else (FIXED_TERM_NAMES[c.jsonKey] ||= [])[c.component] = name;
}
// The report's parameter names (its JSON keys, docs/discovery.md "JSON") in the words of the drift
// model and the effect library; a vector's index is the axis of the gyro's case frame k. Each entry:
// a name, or per index a name.
const PARAMETER_NAMES = {
  ...FIXED_TERM_NAMES,
  driftStepDegH: AXIS.map((a) => `drift step about case ${a}`),
  driftStepSizeDegH: 'drift step size',
  onsetHours: 'onset (flight time)',
  onsetLowerHours: 'onset, earliest',
  onsetUpperHours: 'onset, latest',
  displacementUm: AXIS.map((a) => `rotor displacement along case ${a}`),
  displacementSizeUm: 'rotor displacement size',
  displacementRateUmPerH: AXIS.map((a) => `rotor displacement rate along case ${a}`),
  displacementRateSizeUmPerH: 'rotor displacement rate size',
  impliedDisplacementRateSizeUmPerH: 'rotor displacement rate size implied',
  misalignmentArcsec: AXIS.map((a) => `misalignment about case ${a}`),
  latencyMs: 'star-tracker latency',
  randomWalkDegHSqrtH: 'rate random walk',
  configuredRandomWalkDegHSqrtH: 'rate random walk configured',
  offsetVoltageMv: 'offset voltage'
};
const UNIT_SUFFIX = /(DegHSqrtH|DegH|UmPerH|Um|Hours|Arcsec|Ms|Mv|Deg|S)$/;

// "c1DegH[0]" -> "C11, rotor displacement (1st harmonic)"; a name not in the table in words
// ("lineAngleDeg" -> "line angle", an index as the case axis).
export function parameterName(key) {
  const m = /^([A-Za-z0-9]+)(?:\[(\d+)\])?$/.exec(key || '');
  if (!m) return key;
  const [, base, index] = m;
  const known = PARAMETER_NAMES[base];
  if (Array.isArray(known) && index !== undefined && known[Number(index)]) return known[Number(index)];
  if (typeof known === 'string') return known;
  const words = base.replace(UNIT_SUFFIX, '').replace(/([A-Z])/g, ' $1').toLowerCase().trim();
  return index === undefined ? words : `${words}, case ${AXIS[Number(index)] || index}`;
}

function parameterTable(parameters) {
  return el('table', {},
    el('thead', {}, el('tr', {}, el('th', {}, 'parameter'), el('th', {}, 'value'), el('th', {}, '1-sigma'), el('th', {}, 'unit'))),
    el('tbody', {}, (parameters || []).map((p) => el('tr', {},
      el('td', { 'data-parameter': p.name, title: `${p.name} in the report (esg diagnose --json)` }, parameterName(p.name)),
      el('td', { class: 'num' }, fixed(p.value, 5)),
      el('td', { class: 'num' }, p.sigma === undefined ? '-' : fixed(p.sigma, 5)), el('td', {}, p.unit || '')))));
}

function finding(f) {
  const e = f.evidence || {};
  const p = e.pValue === undefined ? '-' : e.pValue.toExponential(2);
  // An "unexplained" finding is a failed goodness-of-fit test, not a selected effect: its pValue
  // is that test's, and it has no evidence against a smaller model.
  const evidence = f.effect === 'unexplained'
    ? `goodness-of-fit test p = ${p}`
    : `evidence 2 ln B = ${fixed(e.evidence, 1)} (threshold ${fixed(e.threshold, 1)}), false-alarm bound ${p}, round ${e.round ?? '-'}`;
  const tb = f.timeBehaviour;
  return el('div', { class: 'esg-finding' },
    el('h3', {}, `${f.effect}${f.gyro ? ` (gyro ${f.gyro})` : ''}`),
    el('p', {}, f.explanation || f.description || ''),
    (f.parameters || []).length ? parameterTable(f.parameters) : null,
    el('p', { class: 'muted' }, evidence,
      tb ? `; time behaviour ${tb.kind}${tb.onsetHours !== undefined ? ` from ${fixed(tb.onsetHours, 2)} h` : ''}` : ''));
}

function fitTable(fit) {
  const rows = [
    ['model', (x) => x.model],
    ['residual RMS [arcsec]', (x) => fixed(x.residualRmsArcsec, 2)],
    ['drift rate across gaps [deg/h]', (x) => fixed(x.gapDriftRateDegH, 5)],
    ['held-out NEES (dof)', (x) => `${fixed(x.heldOutNees, 1)} (${x.heldOutDof ?? '-'})`],
    ['dispersion', (x) => fixed(x.dispersion, 3)]
  ];
  const before = (fit && fit.before) || {};
  const after = (fit && fit.after) || {};
  return el('table', { class: 'esg-fit' },
    el('thead', {}, el('tr', {}, el('th', {}, ''), el('th', {}, 'before (configured model)'), el('th', {}, 'after (with the findings)'))),
    el('tbody', {}, rows.map(([name, get]) => el('tr', {}, el('td', {}, name),
      el('td', { class: 'num' }, get(before) ?? '-'), el('td', { class: 'num' }, get(after) ?? '-')))));
}

function mismatch(m) {
  if (!m) return el('p', { class: 'muted' }, 'No mismatch section.');
  const where = `${m.start} to ${m.end} (${fixed(m.startHours, 2)}-${fixed(m.endHours, 2)} h, ${m.regime})`;
  return el('p', {},
    m.found ? 'A mismatch was found: ' : 'No significant mismatch; the largest excursion: ',
    `${where}, size ${fixed(m.sizeArcsec, 1)} arcsec against ${fixed(m.expectedArcsec, 1)} expected, `,
    `p = ${m.pValue === undefined ? '-' : m.pValue.toExponential(2)}${m.gyro ? `, gyro ${m.gyro}` : ''}.`);
}

// The confirmation: what is applied and what is not, and that the archive is applied again.
function confirmApply(d) {
  return new Promise((resolve) => {
    const dialog = el('dialog', { id: 'esg-apply-dialog', style: 'background:#333;color:#ddd;border:1px solid #666;padding:16px;max-width:60em' },
      el('form', { method: 'dialog' },
        el('p', {}, `Apply diagnosis ${d.id} to the configuration of ${d.spacecraft_id}? `,
          'The session is recreated and every archived frame applied again under it.'),
        el('ul', {}, (d.applies || []).map((line) => el('li', {}, line))),
        (d.does_not_apply || []).length ? el('p', { class: 'muted' }, 'Not applied:') : null,
        el('ul', { class: 'muted' }, (d.does_not_apply || []).map((line) => el('li', {}, line))),
        el('p', {},
          el('button', { id: 'esg-apply-ok', type: 'submit', value: 'ok' }, 'Apply'), ' ',
          el('button', { id: 'esg-apply-cancel', type: 'submit', value: 'cancel' }, 'Cancel'))));
    document.body.append(dialog);
    dialog.addEventListener('close', () => {
      dialog.remove();
      resolve(dialog.returnValue === 'ok');
    });
    dialog.showModal();
  });
}

function applySection(d, writable) {
  const applies = d.applies || [];
  const result = el('p', { class: 'esg-apply-result' });
  if (!applies.length) {
    return el('div', { class: 'esg-apply' },
      el('p', { class: 'muted' }, `Nothing of this diagnosis maps to the configuration (verdict ${d.verdict}).`));
  }
  const made = el('p', { class: 'muted' }, `Made on configuration version ${d.config_version} (model ${d.model}).`);
  const notApplied = (d.does_not_apply || []).length
    ? el('p', { class: 'muted' }, `Not applied: ${d.does_not_apply.join('; ')}`) : null;
  if (!writable) {
    return el('div', { class: 'esg-apply' },
      el('ul', {}, applies.map((line) => el('li', {}, line))), notApplied, made,
      el('p', { class: 'esg-apply-read-only' },
        'Applying it needs the write role, which your token does not have: an operator with it ',
        'applies it here or with ', el('code', {}, `esg model apply --spacecraft ${d.spacecraft_id} --diagnosis ${d.id}`), '.'));
  }
  const button = el('button', { class: 'esg-apply-button', type: 'button' }, 'Apply to the model');
  button.addEventListener('click', async () => {
    if (!(await confirmApply(d))) return;
    button.disabled = true;
    result.textContent = 'Applying...';
    try {
      const r = await apiFetch(
        `/api/spacecraft/${encodeURIComponent(d.spacecraft_id)}/diagnoses/${d.id}/apply`,
        { method: 'POST', body: {} });
      result.textContent = `Applied as configuration version ${r.config_version}: ${(r.applied || []).join('; ')}. ` +
        'The session is re-running the archive.';
    } catch (err) {
      button.disabled = false;
      result.textContent = `Not applied: ${err.status === 403 ? 'your token does not have the write role' : err.message}`;
    }
  });
  return el('div', { class: 'esg-apply' },
    el('ul', {}, applies.map((line) => el('li', {}, line))), notApplied, made, button, result);
}

function render(container, d, writable) {
  const r = d.report || {};
  const findings = r.findings || [];
  container.replaceChildren(
    el('style', {}, STYLE),
    el('h2', {}, `Diagnosis ${d.id} of ${d.spacecraft_id}`),
    el('p', { class: 'muted' },
      `${d.frames} frames from ${d.first_frame_time} to ${d.last_frame_time}; computed ${d.compute_time}; `,
      `${r.filterRuns ?? '-'} filter runs`),
    el('p', {}, 'Verdict: ', el('span', { class: 'verdict esg-verdict' }, d.verdict)),
    // The service's own diagnosis of a MODEL_INCONSISTENT alert (docs/service.md "Automatic
    // diagnosis"); its MODEL_DIAGNOSED alert carries this id.
    ...(d.requested_by === 'service'
      ? [el('p', { class: 'esg-automatic', 'data-answers-alert': String(d.answers_alert) },
        `Automatic: esgd ran it for alert #${d.answers_alert} (MODEL_INCONSISTENT).`)] : []),
    // partly_explained: what the findings explain and what remains (docs/discovery.md).
    ...(r.consistency && r.consistency.summary
      ? [el('p', { class: 'esg-consistency' }, `Partly explained: ${r.consistency.summary}.`)] : []),
    el('h3', {}, `Findings (${findings.length})`),
    ...(findings.length ? findings.map(finding) : [el('p', { class: 'esg-no-findings' },
      'No finding: the configured model explains the data.')]),
    el('h3', {}, 'Apply to the model'), applySection(d, writable),
    el('h3', {}, 'Mismatch'), mismatch(r.mismatch),
    el('h3', {}, 'Fit before and after'), fitTable(r.fit),
    el('h3', {}, 'Attitude error at the end of each star-tracker gap'), gapChart(r.fit));
}

export function diagnosisViewProvider() {
  return {
    key: 'esg.diagnosis.view',
    name: 'Diagnosis report',
    cssClass: 'icon-object',
    canView: (domainObject) => domainObject.type === 'esg.diagnosis',
    view(domainObject) {
      let container = null;
      return {
        async show(element) {
          container = el('div', { class: 'esg-view esg-diagnosis' }, 'Loading the report...');
          element.append(container);
          const { spacecraft, id } = domainObject.esg;
          try {
            const [d, writable] = await Promise.all([
              apiFetch(`/api/spacecraft/${encodeURIComponent(spacecraft)}/diagnoses/${id}`), canWrite()]);
            if (container) render(container, d, writable);
          } catch (err) {
            if (container) container.replaceChildren(el('p', { class: 'notice' }, `Diagnosis ${id}: ${err.message}`));
          }
        },
        destroy() {
          container = null;
        }
      };
    }
  };
}
