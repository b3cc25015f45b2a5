// The operator's name for acknowledgements when esgd runs without tokens (with tokens esgd takes
// the token's name and this is never asked). Asked once per browser tab in an Open MCT form.
const NAME_KEY = 'esg.operator';

export async function operatorName(openmct) {
  const stored = sessionStorage.getItem(NAME_KEY);
  if (stored) return stored;
  const data = await openmct.forms.showForm({
    title: 'Operator name',
    sections: [{
      rows: [{
        key: 'name',
        control: 'textfield',
        name: 'Your name (recorded with the acknowledgement)',
        required: true,
        cssClass: 'l-input-lg',
        value: ''
      }]
    }],
    buttons: { submit: { label: 'OK' } }
  });
  const name = (data.name || '').trim();
  if (!name) throw new Error('no operator name given');
  sessionStorage.setItem(NAME_KEY, name);
  return name;
}
