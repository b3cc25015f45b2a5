#!/usr/bin/env python3
"""The one-screen summary of scripts/demo.sh (at most 40 lines of 100 columns).

Reads what the demo saved in its work directory (argument 1) and prints it for a newcomer:
  truth.csv         esg simulate --truth: the simulated coefficients in its '# gN_true_...' lines
  status.json       esg status --spacecraft RDK-1 -o json
  history.json      esg history --from <last frame> -o json: the last snapshot per gyro
  predict.json      esg predict -o json over the 6 h after the last frame
  alerts.json       esg alerts -o json
  gap_1.json, gap_10.json   esg gap -o json with models 1+11 and 10+11
Coefficients are in deg/h in each gyro's case frame k (docs/conventions.md); the 1-sigma is the
filter's. Standard library only (python3 is installed by scripts/install-deps.sh).
"""
import json
from datetime import datetime
import os
import sys


def load(work, name):
    with open(os.path.join(work, name)) as f:
        return json.load(f)


def truth_coefficients(path):
    """{gyro id: {'k0': x, 'c1': [..], 'c2': [..]}} from the truth CSV's metadata lines."""
    truth = {}
    with open(path) as f:
        for line in f:
            if not line.startswith('# g'):
                if not line.startswith('#'):
                    break
                continue
            key, _, value = line[2:].partition(':')
            gyro, _, rest = key.partition('_true_')
            if not rest.endswith('_deg_h') or not gyro[1:].isdigit():
                continue
            term = rest[:-len('_deg_h')]
            truth.setdefault(int(gyro[1:]), {})[term] = json.loads(value)
    return truth


def words(enum_name, prefix):
    return enum_name[len(prefix):].lower().replace('_', ' ') if enum_name.startswith(
        prefix) else enum_name


def coefficient_rows(truth, snapshots):
    """(term, [(truth, estimate, sigma) per gyro]) for k0, C1 and C2 (model (10)), and the gyros."""
    latest = {}
    for s in snapshots:
        latest[s['gyroId']] = s  # in time order: the last one wins
    gyros = sorted(g for g in latest if g in truth)
    # (label, truth key, component, the term's key of the keyed coefficients, docs/formats.md)
    terms = [('k0', 'k0', None, 'k0')]
    for name, key in (('C1', 'c1'), ('C2', 'c2')):
        for i, axis in enumerate('xyz'):
            terms.append((f'{name} {axis}', key, i, f'{key}{axis}'))

    def keyed(model, term):
        return next((c['valueDegH'] for c in model.get('coefficients', []) if c['term'] == term),
                    0.0)

    rows = []
    for label, key, i, term in terms:
        cells = []
        for g in gyros:
            model, sigma = latest[g]['model'], latest[g]['sigma']
            true = truth[g][key] if i is None else truth[g][key][i]
            cells.append((true, keyed(model, term), keyed(sigma, term)))
        rows.append((label, cells))
    return gyros, rows


def main():
    work = sys.argv[1]
    out = []
    status = load(work, 'status.json')
    truth = truth_coefficients(os.path.join(work, 'truth.csv'))
    state = words(status['state'], 'SESSION_STATE_').upper()
    out.append(f"RDK-1: {status['framesAccepted']} frames (30 h simulated, paper's calibration "
               f"profile) replayed into esgd: {state}")

    gyros, rows = coefficient_rows(truth, load(work, 'history.json')['snapshots'])
    out.append('')
    out.append('Calibrated drift coefficients [deg/h] against the simulated truth '
               '(model 10+11, last step)')
    out.append('term   ' + ''.join(f'{"g" + str(g) + " truth":>9} {"estimate":>9} {"1-sigma":>8} '
                                    for g in gyros).rstrip())
    for label, cells in rows:
        out.append(f'{label:<6} ' + ''.join(f'{t:+9.3f} {e:+9.4f} {s:8.4f} '
                                            for t, e, s in cells).rstrip())
    worst = max(abs(e - t) / s for _, cells in rows for t, e, s in cells if s > 0)
    out.append(f'|estimate - truth| at most {worst:.1f} sigma; mu and nu held at 0 '
               f'(not in model 10).')

    out.append('')
    out.append("A 12 h gap without the star tracker, offline (esg gap; the paper's Fig. 7 and 8):")
    for name, label in (('gap_1.json', 'model (1)  '), ('gap_10.json', 'model (10) ')):
        gap = load(work, name)
        out.append(f'  {label} calibrated 24 h: error after the gap {gap["finalErrorArcmin"]:6.2f} '
                   f'arcmin, drift-caused rate {gap["driftRateDegH"]:.4f} deg/h')

    predict = load(work, 'predict.json')
    samples = predict['samples']
    recorded = int(predict.get('recordedSamples', 0))
    last = predict['lastArchivedTime']

    def source_of(i):
        name = 'ATTITUDE_SOURCE_RECORDED' if i < recorded else predict['attitudeSource']
        return words(name, 'ATTITUDE_SOURCE_')

    out.append('')
    out.append(f'Prediction after the last frame ({last}), source: '
               f'{source_of(len(samples) - 1)}.')
    if predict['attitudeSource'] == 'ATTITUDE_SOURCE_INERTIAL_HOLD':
        q = samples[-1]['qInB']
        out.append('No attitude plan was given: the last estimate is held inertially fixed, q_in_b '
                   f'{q[0]:+.4f} {q[1]:+.4f}')
        out.append(f'{q[2]:+.4f} {q[3]:+.4f}, right only if the body does not turn; the 1-sigma '
                   'grows with the gyro drift.')
    out.append(f'  {"hours after":>11}  {"1-sigma about body x, y, z [arcsec]":>36}  source')
    for i, s in enumerate(samples):
        sig = s['sigmaArcsec']
        out.append(f'  {hours_between(last, s["time"]):11.1f}  {sig[0]:12.1f} {sig[1]:11.1f} '
                   f'{sig[2]:11.1f}  {source_of(i)}')

    alerts = load(work, 'alerts.json')['alerts']
    out.append('')
    out.append(f'Alerts raised: {len(alerts)}')
    for a in alerts[:kAlertsShown]:
        out.extend('  ' + line for line in alert_sentence(a))
    if len(alerts) > kAlertsShown:
        out.append(f'  and {len(alerts) - kAlertsShown} more: esg alerts --spacecraft RDK-1')
    return out


kAlertsShown = 3


def hours_between(a, b):
    """Hours from RFC 3339 time a to b (both as esg prints them, with or without milliseconds)."""
    def parse(t):
        return datetime.strptime(t.rstrip('Z').split('.')[0], '%Y-%m-%dT%H:%M:%S')
    return (parse(b) - parse(a)).total_seconds() / 3600.0


def alert_sentence(a):
    """Two lines: '#1 WARNING, cleared: star tracker innovation on star_tracker, first at
    2019-03-01T18:11:00.000Z' and '  25.3 arcsec, above its threshold of 20.5 arcsec (once).'"""
    unit = a.get('unit', '')
    unit = '' if unit in ('', '1') else ' ' + unit  # '1': dimensionless
    value, threshold = a.get('value', 0.0), a.get('threshold', 0.0)
    side = 'above' if value > threshold else 'below' if value < threshold else 'at'
    repeats = int(a.get('repeatCount', 1))
    state = 'cleared' if a.get('cleared') else 'active'
    return [f"#{a['sequence']} {words(a['severity'], 'ALERT_SEVERITY_').upper()}, {state}: "
            f"{words(a['reason'], 'ALERT_REASON_')} on {a['subsystem']}, first at "
            f"{a.get('firstTime', '?')}",
            f"   {value:.3g}{unit}, {side} its threshold of {threshold:.3g}{unit} "
            f"({'once' if repeats <= 1 else str(repeats) + ' times'})."]


if __name__ == '__main__':
    for line in main():
        print(line)
