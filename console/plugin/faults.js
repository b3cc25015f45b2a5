// esgd's alerts in Open MCT's fault-management view. Open MCT knows three severities (WATCH,
// WARNING, CRITICAL); esgd four, so DISTRESS shows red with CRITICAL and the fault's name keeps
// esgd's own word. History: GET /api/alerts (SubscribeAlerts replay); live: the WebSocket alerts
// stream, each change making the view fetch the list again. Acknowledge: AcknowledgeAlert.
// A selected MODEL_DIAGNOSED alert has an inspector tab "Diagnosis" leading to the diagnosis it
// answers with.
import { apiFetch, getToken } from './api.js';
import { el } from './dom.js';
import { alertDiagnosis } from './keys.js';
import { live } from './live.js';
import { operatorName } from './operator.js';

const OPEN_MCT_SEVERITY = { INFO: 'WATCH', WARNING: 'WARNING', DISTRESS: 'CRITICAL', CRITICAL: 'CRITICAL' };
const GLOBAL = 'global-alarm-status';

function short(name, prefix) {
  return (name || '').replace(prefix, '');
}

function formatValue(value, unit) {
  if (typeof value !== 'number') return '';
  const text = Math.abs(value) >= 0.01 || value === 0 ? value.toFixed(3) : value.toExponential(3);
  return unit && unit !== '1' ? `${text} ${unit}` : text; // "1": dimensionless
}

// Minutes are enough to tell occurrences apart in a list; the full time is in the inspector.
function minute(iso) {
  return iso ? `${iso.slice(0, 16).replace('T', ' ')}Z` : '-';
}

// Open MCT's list shows a small "namespace" line over the fault's name, the trip value, the live
// value and the trigger time. The name stays short (reason, sequence, repeats) so the row fits;
// the line above carries where, how severe, since when and the state.
export function alertToFault(alert) {
  const severity = short(alert.severity, 'ALERT_SEVERITY_');
  const reason = short(alert.reason, 'ALERT_REASON_');
  const state = [alert.cleared ? 'cleared' : 'active',
    alert.acknowledged ? `acknowledged by ${alert.acknowledged_by}` : 'not acknowledged'].join(', ');
  const result = OPEN_MCT_SEVERITY[severity] || 'WATCH';
  return {
    id: `${alert.spacecraft_id}/${alert.sequence}`,
    name: `${reason} #${alert.sequence}${alert.repeat_count > 1 ? ` x${alert.repeat_count}` : ''}`,
    namespace: `${alert.spacecraft_id} / ${alert.subsystem} | ${severity} | first ${minute(alert.first_time)} | ${state}`,
    severity: result,
    acknowledged: Boolean(alert.acknowledged),
    shelved: false,
    seqNum: alert.sequence,
    // Shown as "Last Trigger Time": the latest occurrence (telemetry epoch), ISO so that Open
    // MCT's newest-first sort (a string comparison) orders it right.
    triggerTime: alert.measurement_time,
    shortDescription: alert.message,
    // "Trip value" is the value of the latest repeat, "live value" the threshold it exceeded.
    // A cleared alert's trip value is not shown as a limit violation still going on.
    triggerValueInfo: { value: formatValue(alert.value, alert.unit), rangeCondition: 'HIGH', monitoringResult: alert.cleared ? 'IN_LIMITS' : result },
    currentValueInfo: { value: `limit ${formatValue(alert.threshold, alert.unit)}`, rangeCondition: 'HIGH', monitoringResult: 'IN_LIMITS' },
    esgAlert: alert
  };
}

export function makeFaultProvider(openmct) {
  return {
    supportsRequest: (domainObject) => domainObject.type === 'faultManagement',
    supportsSubscribe: (domainObject) => domainObject.type === 'faultManagement',

    async request() {
      const body = await apiFetch('/api/alerts');
      return body.alerts.map((alert) => ({ type: 'alarms', fault: alertToFault(alert) }));
    },

    subscribe(domainObject, callback) {
      // The view loads its list on the first global status; afterwards each pushed alert (new,
      // repeated, acknowledged, cleared) reloads it from esgd's stored state.
      // The end-of-replay marker (also after a reconnect of the WebSocket) reloads it too, so
      // changes made while the socket was down are not missed.
      callback({ type: GLOBAL });
      return live.subscribe('alerts', '', null, () => callback({ type: GLOBAL }),
        (error) => openmct.notifications.error(`Alerts feed ended: ${error.code} ${error.message}`),
        () => callback({ type: GLOBAL }));
    },

    async acknowledgeFault(fault) {
      const alert = fault.esgAlert;
      // With tokens esgd takes the name of the operator's own token (empty operator_name);
      // without tokens the operator types a name, remembered for this browser tab.
      let name = '';
      try {
        if (!getToken()) name = await operatorName();
        const updated = await apiFetch(
          `/api/spacecraft/${encodeURIComponent(alert.spacecraft_id)}/alerts/${alert.sequence}/acknowledge`,
          { method: 'POST', body: { operator_name: name } });
        Object.assign(fault, alertToFault(updated));
        return { success: true };
      } catch (err) {
        const text = err.status === 403 ? 'your token does not have the write role' : err.message;
        openmct.notifications.error(`Acknowledge ${fault.id}: ${text}`);
        return { success: false };
      }
    },

    // Shelving is a console-side convenience esgd does not store: the fault hides for the
    // chosen duration in this browser only.
    async shelveFault(fault, { shelved, shelveDuration }) {
      fault.shelved = Boolean(shelved);
      if (shelved && shelveDuration) setTimeout(() => { fault.shelved = false; }, shelveDuration);
      return { success: true };
    }
  };
}

// The single fault selected in the fault-management view (Open MCT selects [the view's object,
// {selectedFaults}]), or null.
function selectedFault(selection) {
  const faults = selection?.[0]?.[1]?.context?.selectedFaults;
  return Array.isArray(faults) && faults.length === 1 ? faults[0] : null;
}

// The inspector tab "Diagnosis" of a selected MODEL_DIAGNOSED alert: which diagnosis answers the
// alert it refers to, and a link that opens its report. Below Open MCT's own fault details in
// priority, so those stay the tab shown first.
export function diagnosisInspectorProvider(openmct) {
  return {
    key: 'esg.fault.diagnosis',
    name: 'Diagnosis',
    canView: (selection) => alertDiagnosis(selectedFault(selection)?.esgAlert) !== null,
    view(selection) {
      const alert = selectedFault(selection).esgAlert;
      const diagnosis = alertDiagnosis(alert);
      return {
        show(element) {
          element.append(el('div', { class: 'c-inspect-properties esg-fault-diagnosis' },
            el('p', {}, `esgd diagnosed ${diagnosis.spacecraft} itself for alert #${Math.round(alert.threshold)} `,
              '(MODEL_INCONSISTENT): ',
              el('a', { class: 'esg-diagnosis-link', href: diagnosis.hash, 'data-diagnosis': String(diagnosis.id) },
                `open diagnosis #${diagnosis.id}`),
              ', its verdict, findings and what applying it would set.')));
        },
        priority: () => openmct.priority.DEFAULT,
        destroy() {}
      };
    }
  };
}
