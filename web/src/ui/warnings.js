/**
 * Bake warnings on screen ("no silent failures"): a count badge and the list of messages, used by the bake
 * cards, the dashboard and the viewer's banner. The data comes from `bakeWarnings` (state/stats.js).
 */
import { h } from './dom.js';

/** `⚠ N warnings`, or null when there are none. */
export function warningBadge(warnings) {
  if (!warnings || !warnings.length) return null;
  const n = warnings.length;
  return h('span.badge.warn-badge', {
    dataset: { warnings: String(n) }, title: warnings.map((w) => `[${w.code}] ${w.message}`).join('\n'),
  }, `⚠ ${n} warning${n === 1 ? '' : 's'}`);
}

/** `<ul class="bake-warnings">` with one `<li data-code>` per warning, or null when there are none. */
export function warningList(warnings) {
  if (!warnings || !warnings.length) return null;
  return h('ul.bake-warnings', warnings.map((w) => h('li', { dataset: { code: w.code, stage: w.stage || '' } },
    h('code.warn-code', w.code), ' ', w.message, w.stage ? h('span.muted', ` (${w.stage})`) : null)));
}
