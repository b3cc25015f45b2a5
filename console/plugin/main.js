// Entry point loaded by public/index.html: sign in, configure Open MCT's built-in plugins, install
// the ESG plugin and start.
import EsgConsolePlugin from './plugin.js';
import { sessions } from './sessions.js';
import { signIn } from './signin.js';
import { conductorOptions } from './time.js';

/* global openmct */
async function start() {
  await signIn();
  const list = await sessions();
  openmct.setAssetPath('/openmct/');
  openmct.install(openmct.plugins.LocalStorage());
  openmct.install(openmct.plugins.Espresso());
  openmct.install(openmct.plugins.UTCTimeSystem());
  // The per-spacecraft summary is a display layout (objects.js).
  openmct.install(openmct.plugins.DisplayLayout());
  const conductor = conductorOptions(list);
  openmct.install(openmct.plugins.Conductor(conductor));
  // The Conductor plugin sets the real-time option's clock offsets after the fixed bounds, which
  // moves them to "now"; set the flight's bounds again (a URL's tc.* bounds still win at start).
  openmct.time.setBounds(conductor.menuOptions[0].bounds);
  openmct.install(EsgConsolePlugin());
  openmct.start(document.getElementById('app'));
}

start().catch((err) => {
  document.body.textContent = `ESG console failed to start: ${err.message}`;
});
