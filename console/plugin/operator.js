// The operator's name for acknowledgements when esgd runs without tokens (with tokens esgd takes
// the token's name and this is never asked). Asked once per browser tab in a small dialog of our
// own: Open MCT's form text field reports its value throttled (500 ms), so a name typed quickly
// and confirmed at once would be cut short.
import { el } from './dom.js';

const NAME_KEY = 'esg.operator';

function ask() {
  return new Promise((resolve, reject) => {
    const input = el('input', { id: 'esg-operator-name', type: 'text', size: 32, autocomplete: 'off' });
    const dialog = el('dialog', { id: 'esg-operator-dialog', style: 'background:#333;color:#ddd;border:1px solid #666;padding:16px' },
      el('form', { method: 'dialog' },
        el('p', {}, 'Your name, recorded by esgd with the acknowledgement:'),
        input,
        el('p', {},
          el('button', { id: 'esg-operator-ok', type: 'submit', value: 'ok' }, 'Acknowledge'), ' ',
          el('button', { id: 'esg-operator-cancel', type: 'submit', value: 'cancel' }, 'Cancel'))));
    document.body.append(dialog);
    dialog.addEventListener('close', () => {
      const name = input.value.trim();
      dialog.remove();
      if (dialog.returnValue === 'ok' && name) resolve(name);
      else reject(new Error('no operator name given'));
    });
    dialog.showModal();
    input.focus();
  });
}

export async function operatorName() {
  const stored = sessionStorage.getItem(NAME_KEY);
  if (stored) return stored;
  const name = await ask();
  sessionStorage.setItem(NAME_KEY, name);
  return name;
}
