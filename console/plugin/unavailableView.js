// What the per-step estimate views show when esgd does not serve per-step estimates
// (GetEstimateHistory answers UNIMPLEMENTED, the gateway 501): a plain statement instead of an
// empty plot an engineer could take for "no data in this interval".
import { el, STYLE } from './dom.js';

export function unavailableViewProvider() {
  return {
    key: 'esg.unavailable.view',
    name: 'Not available',
    cssClass: 'icon-object',
    canView: (domainObject) => domainObject.type === 'esg.unavailable',
    view(domainObject) {
      return {
        show(element) {
          element.append(el('div', { class: 'esg-view' }, el('style', {}, STYLE),
            el('h2', {}, domainObject.name),
            el('p', { class: 'notice esg-unavailable' },
              'Per-step estimates are not available: this esgd does not implement ',
              'GetEstimateHistory / SubscribeEstimates (the gateway answers 501).'),
            el('p', { class: 'muted' },
              'The attitude 1-sigma, the star-tracker innovations and the time since the last ',
              'star-tracker correction need them. Coefficients, predictions, alerts and diagnoses ',
              'do not.')));
        },
        destroy() {}
      };
    }
  };
}
