// Editor of a spacecraft's planned attitude (plan.js): paste the CSV, use it or clear it. The
// predicted attitude plot and table use it from their next request.
import { el, STYLE } from './dom.js';
import { parsePlan, planText, setPlan } from './plan.js';

function status(text) {
  if (!text.trim()) return 'No plan: after the last frame predictions hold the last estimate inertially fixed (inertial hold).';
  const samples = parsePlan(text);
  return `Predictions after the last frame use this plan (planned): ${samples.length} samples from ` +
    `${samples[0].time} to ${samples[samples.length - 1].time}, slerp between them, held before the first and after the last.`;
}

export function planViewProvider() {
  return {
    key: 'esg.plan.view',
    name: 'Planned attitude',
    cssClass: 'icon-object',
    canView: (domainObject) => domainObject.type === 'esg.plan',
    view(domainObject) {
      const sc = domainObject.esg.spacecraft;
      return {
        show(element) {
          const area = el('textarea', { class: 'esg-plan-text', rows: 12, cols: 90, spellcheck: 'false',
            style: 'font-family: monospace; background:#222; color:#ddd;' });
          area.value = planText(sc);
          const note = el('p', { class: 'esg-plan-status' }, status(area.value));
          const use = el('button', { class: 'c-button esg-plan-use' }, 'Use this plan');
          const clear = el('button', { class: 'c-button esg-plan-clear' }, 'Clear');
          use.onclick = () => {
            try {
              setPlan(sc, area.value);
              note.textContent = status(area.value);
              note.className = 'esg-plan-status';
            } catch (err) {
              note.textContent = `Not used: ${err.message}`;
              note.className = 'esg-plan-status notice';
            }
          };
          clear.onclick = () => {
            area.value = '';
            setPlan(sc, '');
            note.textContent = status('');
            note.className = 'esg-plan-status';
          };
          element.append(el('div', { class: 'esg-view' }, el('style', {}, STYLE),
            el('h2', {}, `Planned attitude of ${sc}`),
            el('p', { class: 'muted' },
              'One line per sample: time,q0,q1,q2,q3 (RFC 3339 UTC; q_in_b, body to inertial, scalar first), ',
              'the CSV of esg predict --planned. Kept in this browser tab only.'),
            area, el('p', {}, use, ' ', clear), note));
        },
        destroy() {}
      };
    }
  };
}
