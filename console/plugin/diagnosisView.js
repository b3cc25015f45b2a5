// One stored diagnosis (GET /api/spacecraft/:id/diagnoses/:n, GetDiagnosis with its report):
// verdict, findings with their parameters and evidence, the mismatch found, the fit before and
// after, and the gap errors as a bar chart. Report fields: docs/discovery.md "JSON".
import { apiFetch } from './api.js';
import { el, fixed, STYLE } from './dom.js';
import { gapChart } from './gapChart.js';

function parameterTable(parameters) {
  return el('table', {},
    el('thead', {}, el('tr', {}, el('th', {}, 'parameter'), el('th', {}, 'value'), el('th', {}, '1-sigma'), el('th', {}, 'unit'))),
    el('tbody', {}, (parameters || []).map((p) => el('tr', {},
      el('td', {}, p.name), el('td', { class: 'num' }, fixed(p.value, 5)),
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

function render(container, d) {
  const r = d.report || {};
  const findings = r.findings || [];
  container.replaceChildren(
    el('style', {}, STYLE),
    el('h2', {}, `Diagnosis ${d.id} of ${d.spacecraft_id}`),
    el('p', { class: 'muted' },
      `${d.frames} frames from ${d.first_frame_time} to ${d.last_frame_time}; computed ${d.compute_time}; `,
      `${r.filterRuns ?? '-'} filter runs`),
    el('p', {}, 'Verdict: ', el('span', { class: 'verdict esg-verdict' }, d.verdict)),
    el('h3', {}, `Findings (${findings.length})`),
    ...(findings.length ? findings.map(finding) : [el('p', { class: 'esg-no-findings' },
      'No finding: the configured model explains the data.')]),
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
            const d = await apiFetch(`/api/spacecraft/${encodeURIComponent(spacecraft)}/diagnoses/${id}`);
            if (container) render(container, d);
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
