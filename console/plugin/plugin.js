// The ESG console plugin: object types, the object tree, telemetry, alerts as faults, and the
// console's own views. Installed by public/index.html after the operator has signed in.
import { diagnosisViewProvider } from './diagnosisView.js';
import { diagnosisInspectorProvider, makeFaultProvider } from './faults.js';
import { fleetViewProvider } from './fleetView.js';
import { healthViewProvider } from './healthView.js';
import { NAMESPACE } from './keys.js';
import { objectProvider, TELEMETRY_TYPE } from './objects.js';
import { planViewProvider } from './planView.js';
import { installRevisions } from './revisions.js';
import { setNotifier, telemetryProvider } from './telemetry.js';
import { installRoundTimeTicks } from './ticks.js';
import { makeSpacecraftTree } from './tree.js';
import { unavailableViewProvider } from './unavailableView.js';

export default function EsgConsolePlugin() {
  return function install(openmct) {
    openmct.types.addType(TELEMETRY_TYPE, {
      name: 'ESG telemetry', description: 'Values computed by esgd', cssClass: 'icon-telemetry', creatable: false
    });
    openmct.types.addType('esg.fleet', {
      name: 'ESG fleet overview', description: 'Every spacecraft session', cssClass: 'icon-dataset', creatable: false
    });
    openmct.types.addType('esg.health', {
      name: 'ESG spacecraft health', description: 'State, sensor health, model, alerts and last diagnosis of one spacecraft', cssClass: 'icon-object', creatable: false
    });
    openmct.types.addType('esg.diagnosis', {
      name: 'ESG diagnosis', description: 'Model-discrepancy diagnosis report', cssClass: 'icon-notebook', creatable: false
    });
    openmct.types.addType('esg.plan', {
      name: 'ESG planned attitude', description: 'Planned attitude used by predictions', cssClass: 'icon-timeline', creatable: false
    });
    openmct.types.addType('esg.unavailable', {
      name: 'ESG view not available', description: 'Data esgd does not serve', cssClass: 'icon-alert-rect', creatable: false
    });

    openmct.objects.addProvider(NAMESPACE, objectProvider);
    openmct.objects.addRoot({ namespace: NAMESPACE, key: 'root' });
    const tree = makeSpacecraftTree();
    openmct.composition.addProvider(tree);
    tree.watch();
    setNotifier(openmct);
    openmct.telemetry.addProvider(telemetryProvider);
    installRevisions(openmct);

    openmct.install(openmct.plugins.FaultManagement());
    openmct.faults.addProvider(makeFaultProvider(openmct));
    openmct.inspectorViews.addProvider(diagnosisInspectorProvider(openmct));

    openmct.objectViews.addProvider(fleetViewProvider());
    openmct.objectViews.addProvider(healthViewProvider());
    openmct.objectViews.addProvider(diagnosisViewProvider());
    openmct.objectViews.addProvider(unavailableViewProvider());
    openmct.objectViews.addProvider(planViewProvider());

    // Open MCT's plots with their time ticks at round times.
    installRoundTimeTicks(openmct);
  };
}
