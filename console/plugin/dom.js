// Tiny DOM helpers for the console's own views (fleet, diagnosis, not-available).
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') node.className = v;
    else if (k === 'style') node.style.cssText = v;
    else node.setAttribute(k, v);
  }
  for (const child of children.flat()) {
    if (child === null || child === undefined) continue;
    node.append(child instanceof Node ? child : String(child));
  }
  return node;
}

export function fixed(value, digits) {
  return typeof value === 'number' && Number.isFinite(value) ? value.toFixed(digits) : '-';
}

// "3 h 07 min" between two ISO times, or "-" when either is missing.
export function duration(fromIso, toIso) {
  if (!fromIso || !toIso) return '-';
  const minutes = Math.round((Date.parse(toIso) - Date.parse(fromIso)) / 60000);
  const h = Math.floor(Math.abs(minutes) / 60);
  const m = Math.abs(minutes) % 60;
  return `${minutes < 0 ? '-' : ''}${h} h ${String(m).padStart(2, '0')} min`;
}

export function shortName(value, prefix) {
  return (value || '').replace(prefix, '');
}

// Styles of the console's own views, in Open MCT's dark theme colours.
export const STYLE = `
.esg-view { padding: 8px 12px; overflow: auto; height: 100%; box-sizing: border-box; font-size: 13px; }
.esg-view h2 { font-size: 16px; margin: 4px 0 8px; }
.esg-view h3 { font-size: 14px; margin: 14px 0 6px; }
.esg-view table { border-collapse: collapse; margin-bottom: 8px; }
.esg-view th, .esg-view td { border-bottom: 1px solid #444; padding: 4px 10px; text-align: left; white-space: nowrap; }
.esg-view th { color: #aaa; font-weight: normal; }
.esg-view td.num { text-align: right; font-variant-numeric: tabular-nums; }
.esg-view .sev-CRITICAL { color: #ff4d4d; } .esg-view .sev-DISTRESS { color: #ff8c3a; }
.esg-view .sev-WARNING { color: #ffd23f; } .esg-view .sev-INFO { color: #6fc3ff; }
.esg-view .muted { color: #999; }
.esg-view .verdict { font-size: 18px; color: #ffd23f; }
.esg-view .notice { font-size: 15px; color: #ffb84f; margin: 20px 0; }
`;
