// SVG bar chart of a diagnosis' gap test: for each star-tracker gap of the fit, the attitude error
// reached at its end [arcsec] with the configured model (before) and with the findings (after).
// The report carries these numbers (fit.before/after.gaps), not per-step series, so a bar chart
// of them is the faithful picture.
const NS = 'http://www.w3.org/2000/svg';
const W = 640;
const H = 240;
const PAD = { left: 56, right: 12, top: 16, bottom: 54 };
const COLOURS = { before: '#ff8c3a', after: '#4fb3ff' };

function svg(tag, attrs, text) {
  const node = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}

// The smallest 1, 2, 2.5 or 5 times a power of ten at or above v, so the four gridlines fall on
// round numbers.
function niceTop(v) {
  const p = 10 ** Math.floor(Math.log10(v / 4));
  for (const m of [1, 2, 2.5, 5, 10]) if (4 * m * p >= v) return 4 * m * p;
  return v;
}

export function gapChart(fit) {
  const before = (fit && fit.before && fit.before.gaps) || [];
  const after = (fit && fit.after && fit.after.gaps) || [];
  const n = Math.max(before.length, after.length);
  const root = svg('svg', { width: W, height: H, viewBox: `0 0 ${W} ${H}`, class: 'esg-gap-chart' });
  if (n === 0) {
    root.append(svg('text', { x: 10, y: 20, fill: '#aaa' }, 'No star-tracker gaps in the diagnosed span.'));
    return root;
  }
  const values = [...before, ...after].map((g) => g.finalErrorArcsec || 0);
  const top = niceTop(Math.max(...values, 1));
  const plotW = W - PAD.left - PAD.right;
  const plotH = H - PAD.top - PAD.bottom;
  const y = (v) => PAD.top + plotH * (1 - v / top);
  // Axis and five gridlines with their values.
  for (let i = 0; i <= 4; i++) {
    const v = (top * i) / 4;
    root.append(svg('line', { x1: PAD.left, x2: W - PAD.right, y1: y(v), y2: y(v), stroke: '#444' }));
    root.append(svg('text', { x: PAD.left - 6, y: y(v) + 4, fill: '#aaa', 'font-size': 11, 'text-anchor': 'end' }, String(Number(v.toPrecision(3)))));
  }
  root.append(svg('text', { x: 12, y: PAD.top + plotH / 2, fill: '#aaa', 'font-size': 11,
    transform: `rotate(-90 12 ${PAD.top + plotH / 2})`, 'text-anchor': 'middle' }, 'error at gap end [arcsec]'));
  const slot = plotW / n;
  const bar = Math.min(28, slot / 3);
  for (let i = 0; i < n; i++) {
    const x0 = PAD.left + slot * i + slot / 2;
    [['before', before[i], -bar], ['after', after[i], 0]].forEach(([which, gap, dx]) => {
      if (!gap) return;
      const v = gap.finalErrorArcsec || 0;
      const rect = svg('rect', { x: x0 + dx, y: y(v), width: bar, height: y(0) - y(v), fill: COLOURS[which] });
      rect.append(svg('title', {}, `${which}: ${v.toFixed(1)} arcsec, drift ${(gap.driftRateDegH || 0).toFixed(4)} deg/h`));
      root.append(rect);
    });
    const gap = before[i] || after[i];
    const label = `${gap.startHours.toFixed(1)}-${gap.endHours.toFixed(1)} h`;
    root.append(svg('text', { x: x0, y: H - PAD.bottom + 16, fill: '#ccc', 'font-size': 11, 'text-anchor': 'middle' }, label));
    root.append(svg('text', { x: x0, y: H - PAD.bottom + 30, fill: '#999', 'font-size': 10, 'text-anchor': 'middle' }, gap.regime || ''));
  }
  [['before', 'configured model (before)'], ['after', 'with the findings (after)']].forEach(([which, text], i) => {
    const x = PAD.left + i * 220;
    root.append(svg('rect', { x, y: H - 14, width: 10, height: 10, fill: COLOURS[which] }));
    root.append(svg('text', { x: x + 14, y: H - 5, fill: '#ccc', 'font-size': 11 }, text));
  });
  return root;
}
