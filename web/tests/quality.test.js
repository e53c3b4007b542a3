import { describe, expect, it } from 'vitest';
import { betterOf, betterWay, chartScales, diffGain, diffImage, gatesFor, metricDeltas, patternRegExp, splitColumn } from '../src/state/quality.js';

describe('threshold patterns (fnmatch as server/gates.py check)', () => {
  const gates = [
    { text: 'mask_normalized.leak > 0.05', metric: 'mask_normalized.leak', op: '>', value: 0.05 },
    { text: '*.rmse >= 0.2', metric: '*.rmse', op: '>=', value: 0.2 },
    { text: 'mask.region.*.mean_ratio < 0.5', metric: 'mask.region.*.mean_ratio', op: '<', value: 0.5 },
  ];
  it('matches exact names and * patterns, dots literal', () => {
    expect(gatesFor('mask_normalized.leak', gates).map((g) => g.text)).toEqual(['mask_normalized.leak > 0.05']);
    expect(gatesFor('ddgi.rmse', gates).map((g) => g.text)).toEqual(['*.rmse >= 0.2']);
    expect(gatesFor('ddgi.rmse_stderr', gates)).toEqual([]);
    expect(gatesFor('mask.region.kitchen.mean_ratio', gates).map((g) => g.value)).toEqual([0.5]);
    expect(patternRegExp('mask.leak').test('maskxleak')).toBe(false);
    expect(patternRegExp('a-b.c').test('a-b.c')).toBe(true);
  });
});

describe('which bake is better', () => {
  it('lower for errors, closer to 1 for mean_ratio', () => {
    expect(betterWay('mask.rmse')).toBe('lower');
    expect(betterWay('mask.region.a.mean_ratio')).toBe('one');
    expect(betterOf('mask.leak', 0.2, 0.1)).toBe('b');
    expect(betterOf('mask.indirect_excess', 0.1, 0.3)).toBe('a');
    expect(betterOf('mask.mean_ratio', 0.7, 1.2)).toBe('b');
    expect(betterOf('mask.mean_ratio', 1.05, 0.8)).toBe('a');
    expect(betterOf('mask.rmse', 0.1, 0.1)).toBe('same');
  });
  it('deltas with combined standard errors and significance', () => {
    const a = { metrics: { 'mask.rmse': 0.2, 'mask.rmse_stderr': 0.03, 'mask.leak': 0.1, 'mask.pass_ms': 3, 'mask.mean_ratio': 0.9, 'mask.mean_ratio_stderr': 0.001, 'only_a.rmse': 1 } };
    const b = { metrics: { 'mask.rmse': 0.1, 'mask.rmse_stderr': 0.04, 'mask.leak': 0.2, 'mask.pass_ms': 1, 'mask.mean_ratio': 1.0, 'mask.mean_ratio_stderr': 0.001 } };
    const rows = Object.fromEntries(metricDeltas(a, b).map((r) => [r.key, r]));
    expect(Object.keys(rows)).toEqual(['mask.leak', 'mask.mean_ratio', 'mask.rmse']);  // quality metrics both have
    expect(rows['mask.rmse'].delta).toBeCloseTo(-0.1);
    expect(rows['mask.rmse'].se).toBeCloseTo(0.05);
    expect(rows['mask.rmse']).toMatchObject({ better: 'b', significant: false });   // 0.1 < 2 * 0.05 is false: not > 0.1
    expect(rows['mask.mean_ratio']).toMatchObject({ better: 'b', significant: true });
    expect(rows['mask.leak']).toMatchObject({ better: 'a', se: null, significant: null });
  });
  it('paired standard errors (one shared reference) replace the combined ones where given', () => {
    const a = { metrics: { 'mask.rmse': 0.2, 'mask.rmse_stderr': 0.03, 'mask.leak': 0.1, 'mask.leak_stderr': 0.01 } };
    const b = { metrics: { 'mask.rmse': 0.1, 'mask.rmse_stderr': 0.04, 'mask.leak': 0.2, 'mask.leak_stderr': 0.01 } };
    const rows = Object.fromEntries(metricDeltas(a, b, { 'mask.rmse': 0.01, 'mask.leak': null }).map((r) => [r.key, r]));
    expect(rows['mask.rmse']).toMatchObject({ se: 0.01, paired: true, significant: true });  // 0.1 > 2 * 0.01
    expect(rows['mask.leak'].paired).toBe(false);                                           // null: combined
    expect(rows['mask.leak'].se).toBeCloseTo(Math.sqrt(2) * 0.01);
  });
});

describe('chart scales', () => {
  it('map points and threshold lines inside the box, higher values higher up', () => {
    const sc = chartScales([{ value: 1 }, { value: 2, stderr: 0.5 }, { value: 3 }], [4], { width: 200, height: 100, pad: 10 });
    expect(sc.x(0)).toBe(10);
    expect(sc.x(2)).toBe(190);
    for (const v of [1, 1.5, 2.5, 4]) { expect(sc.y(v)).toBeGreaterThanOrEqual(10); expect(sc.y(v)).toBeLessThanOrEqual(90); }
    expect(sc.y(4)).toBeLessThan(sc.y(1));
    // with times the x axis is time: a bake made long after the others stands apart
    const t = chartScales([{ value: 1, time: 100 }, { value: 2, time: 110 }, { value: 3, time: 200 }], [], { width: 200, height: 100, pad: 10 });
    expect(t.timed).toBe(true);
    expect([t.x(0), t.x(1), t.x(2)]).toEqual([10, 28, 190]);
    expect(chartScales([{ value: 1, time: 5 }, { value: 2, time: 5 }], [], { width: 200, pad: 10 }).x(1)).toBe(190);  // equal times: order
    const one = chartScales([{ value: 5 }], [], { width: 100 });
    expect(one.x(0)).toBe(50);
    expect(Number.isFinite(one.y(5))).toBe(true);
  });
});

describe('A/B difference image and split', () => {
  it('amplifies |A - B| per channel, counts differing pixels', () => {
    const a = new Uint8ClampedArray([10, 20, 30, 255, 100, 100, 100, 255]);
    const b = new Uint8ClampedArray([10, 20, 30, 255, 90, 130, 100, 0]);
    const d = diffImage(a, b, 8);
    expect([...d.data]).toEqual([0, 0, 0, 255, 80, 240, 0, 255]);
    expect(d.max).toBe(30);
    expect(d.nonzero).toBe(1);
  });
  it('amplifies as much as the largest difference allows (powers of two, 1 … 16)', () => {
    expect(diffGain(0)).toBe(16);
    expect(diffGain(10)).toBe(16);
    expect(diffGain(40)).toBe(4);
    expect(diffGain(192)).toBe(1);
    expect(diffGain(255)).toBe(1);
  });
  it('splits at the slider column, clamped', () => {
    expect(splitColumn(64, 0.5)).toBe(32);
    expect(splitColumn(64, -1)).toBe(0);
    expect(splitColumn(64, 2)).toBe(64);
  });
});
