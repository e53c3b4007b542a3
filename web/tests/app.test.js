import { describe, expect, it } from 'vitest';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { SSEParser } from '../src/api/sse.js';
import { buildFieldTree, configDiff, fieldErrors, walkFields } from '../src/state/schema.js';
import { GI_MODES, modeAvailability } from '../src/state/modes.js';
import { bakeSeconds, bakeWarnings, compareBakes, comparePreviews, configDelta, evalPreviews, flattenMetrics, memoryBytes, stageGroups } from '../src/state/stats.js';

const schema = JSON.parse(readFileSync(fileURLToPath(new URL('../../proto/schema/bake-config.schema.json', import.meta.url)), 'utf8'));

describe('SSE parser', () => {
  it('splits events across chunks, skips comments, handles CRLF', () => {
    const p = new SSEParser();
    expect(p.push('event: progress\ndata: {"a"')).toEqual([]);
    expect(p.push(': 1}\n\n: keep-alive\n\nevent: status\r\ndata: {"b": 2}\r\n\r\n')).toEqual([
      { event: 'progress', data: '{"a": 1}', id: undefined },
      { event: 'status', data: '{"b": 2}', id: undefined },
    ]);
  });
});

describe('config form model from the JSON Schema', () => {
  const tree = buildFieldTree(schema);
  const byPath = Object.fromEntries(walkFields(tree).map((n) => [n.path, n]));
  it('has every section with defaults and bounds', () => {
    expect(tree.children.map((c) => c.key)).toEqual(expect.arrayContaining(['seed', 'scene', 'place', 'trace', 'light', 'visibility', 'masks', 'prt']));
    expect(byPath['place.counts'].kind).toBe('nullable');
    expect(byPath['place.counts'].default).toBeNull();   // the automatic grid
    expect(byPath['place.counts'].inner.kind).toBe('tuple');
    expect(byPath['trace.rays_per_probe']).toMatchObject({ kind: 'integer', min: 16, max: 4096, default: 256 });
    expect(byPath['light.sh_order']).toMatchObject({ kind: 'enum', options: [1, 2] });
    expect(byPath['scene.lights'].kind).toBe('list');
    expect(byPath['scene.lights'].item.kind).toBe('object');
    expect(byPath['place.box'].inner.kind).toBe('object');
  });
  it('sends only what differs from the defaults', () => {
    const values = JSON.parse(JSON.stringify(tree.default));
    expect(configDiff(tree, values)).toEqual({});
    values.place.counts = [4, 4, 4];
    values.place.spacing = null;
    values.trace.rays_per_probe = 64;
    expect(configDiff(tree, values)).toEqual({ place: { counts: [4, 4, 4] }, trace: { rays_per_probe: 64 } });
  });
  it('puts 422 messages on the named fields', () => {
    const paths = walkFields(tree).map((n) => n.path);
    const msg = 'config.place.counts.0: Input should be greater than or equal to 1; config.place: Value error, give exactly one of counts or spacing; config.bogus: unknown field';
    expect(fieldErrors(msg, paths)).toEqual([
      { path: 'place.counts', message: '0: Input should be greater than or equal to 1' },
      { path: 'place', message: 'Value error, give exactly one of counts or spacing' },
      { path: '', message: 'bogus: unknown field' },
    ]);
    expect(fieldErrors('no scene 123', paths)).toEqual([{ path: '', message: 'no scene 123' }]);
  });
});

describe('GI modes light up only with their artifacts and shader', () => {
  const has = (f) => ['mode_direct.glsl', 'mode_leaking.glsl'].includes(f);
  const mode = (id) => GI_MODES.find((m) => m.id === id);
  it('direct always, leaking with the SH volumes', () => {
    expect(modeAvailability(mode('direct'), [], has).available).toBe(true);
    expect(modeAvailability(mode('leaking'), ['sh_l1_r'], has)).toMatchObject({ available: false, reason: 'not baked', missing: ['sh_l1_g', 'sh_l1_b'] });
    expect(modeAvailability(mode('leaking'), ['sh_l1_r', 'sh_l1_g', 'sh_l1_b'], has).available).toBe(true);
  });
  it('says "not baked" before "no shader"', () => {
    expect(modeAvailability(mode('mask'), [], has).reason).toBe('not baked');
    expect(modeAvailability(mode('mask'), ['mask_indirection', 'mask_atlas', 'cluster_sh_0_r'], has).reason).toBe('shader not written yet');
  });
});

describe('dashboard numbers', () => {
  const a = {
    id: 'a', created: 10, started: 10, finished: 14, config: { place: { counts: [8, 8, 8] }, seed: 0 },
    stages: [{ name: 'place', seconds: 0.5, cached: false, status: 'succeeded' }, { name: 'visibility.0', seconds: 1, status: 'succeeded' }, { name: 'visibility', seconds: 0.25, status: 'succeeded' }],
    artifacts: [{ bytes: 1000 }, { bytes: 24 }], metrics: { leaking: { rmse: 0.2 }, flip: 0.1 },
  };
  const b = { ...a, id: 'b', finished: 16, config: { place: { counts: [4, 4, 4] }, seed: 0 }, artifacts: [{ bytes: 500 }], metrics: { leaking: { rmse: 0.1 } } };
  it('groups sharded stages, sums memory, flattens metrics', () => {
    expect(stageGroups(a).visibility).toMatchObject({ seconds: 1.25, parts: 2 });
    expect(memoryBytes(a)).toBe(1024);
    expect(memoryBytes({})).toBe(null);
    expect(bakeSeconds(a)).toBe(4);
    expect(flattenMetrics(a.metrics)).toEqual({ 'leaking.rmse': 0.2, flip: 0.1 });
  });
  it('compares two bakes', () => {
    const rows = Object.fromEntries(compareBakes(a, b).map((r) => [r.name, r]));
    expect(rows['bake seconds']).toMatchObject({ a: 4, b: 6, delta: 2, relative: 0.5 });
    expect(rows['leaking.rmse'].delta).toBeCloseTo(-0.1);
    expect(rows.flip).toMatchObject({ a: 0.1, b: null, delta: null });
    expect(configDelta(a.config, b.config)).toEqual([{ path: 'place.counts', a: [8, 8, 8], b: [4, 4, 4] }]);
  });
});

describe('evaluate previews (bundle.md 5.4)', () => {
  const png = (name) => ({ name, format: 'png' });
  const bake = (names) => ({ artifacts: names.map(png).concat([{ name: 'eval_metrics', format: 'json' }]) });
  it('pairs previews with heatmaps per camera and mode, reference first', () => {
    const p = evalPreviews(bake(['eval_contact', 'eval_cam-0_mask_normalized', 'eval_cam-0_mask_normalized_error',
      'eval_cam-0_leaking', 'eval_cam-0_leaking_error', 'eval_cam-0_reference', 'eval_my_cam_mask', 'eval_cam-1_ddgi']));
    expect(p.map((x) => [x.camera, x.mode, x.name, x.error])).toEqual([
      ['cam-0', 'reference', 'eval_cam-0_reference', null],
      ['cam-0', 'leaking', 'eval_cam-0_leaking', 'eval_cam-0_leaking_error'],
      ['cam-0', 'mask_normalized', 'eval_cam-0_mask_normalized', 'eval_cam-0_mask_normalized_error'],
      ['cam-1', 'ddgi', 'eval_cam-1_ddgi', null],
      ['my_cam', 'mask', 'eval_my_cam_mask', null],
    ]);
  });
  it('compares only when both bakes have previews', () => {
    const a = bake(['eval_cam-0_reference', 'eval_cam-0_leaking']);
    const b = bake(['eval_cam-0_reference', 'eval_cam-0_ddgi']);
    expect(comparePreviews(a, bake([]))).toEqual([]);
    const rows = comparePreviews(a, b);
    expect(rows.map((r) => [r.mode, !!r.a, !!r.b])).toEqual([['reference', true, true], ['leaking', true, false], ['ddgi', false, true]]);
  });
});

describe('bake warnings', () => {
  it('takes the top-level list, else gathers the stages\' stats.warnings (shards folded, duplicates once)', () => {
    const top = [{ code: 'unlit_scene', message: 'nothing lights the scene', stage: 'ingest' }];
    expect(bakeWarnings({ warnings: top, stages: [{ name: 'light', stats: { warnings: [{ code: 'x', message: 'y' }] } }] })).toBe(top);
    expect(bakeWarnings(null)).toEqual([]);
    expect(bakeWarnings({ status: 'queued' })).toEqual([]);
    const slab = { code: 'not_converged', message: 'slab' };
    expect(bakeWarnings({
      stages: [{ name: 'ingest', stats: { warnings: [top[0]] } }, { name: 'visibility.0', stats: { warnings: [slab] } },
        { name: 'visibility.1', stats: { warnings: [slab] } }, { name: 'place', stats: {} }],
    })).toEqual([
      { code: 'unlit_scene', message: 'nothing lights the scene', stage: 'ingest' },
      { code: 'not_converged', message: 'slab', stage: 'visibility' },
    ]);
  });
});

describe('gridSummary', () => {
  it('says the probe count, the spacing and the turn of the bake frame', async () => {
    const { gridSummary } = await import('../src/state/stats.js');
    const place = (stats) => ({ stages: [{ name: 'ingest', stats: {} }, { name: 'place', stats }] });
    expect(gridSummary(place({ counts: [10, 4, 5], spacing: [0.25, 0.3, 0.25] }))).toBe('200 probes, 0.30 m apart');
    expect(gridSummary(place({ counts: [46, 16, 20], spacing: [0.21, 0.21, 0.21], frame: { yaw_deg: 30, matrix: [] } })))
      .toBe('14,720 probes, 0.21 m apart; grid turned 30.0° about the vertical to follow the walls');
    expect(gridSummary(place({ counts: [2, 2, 2], spacing: [1, 1, 1], frame: { yaw_deg: 0 } }))).toBe('8 probes, 1.00 m apart');
    expect(gridSummary({ stages: [] })).toBe('');
    expect(gridSummary(null)).toBe('');
  });
});
