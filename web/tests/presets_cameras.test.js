import { describe, expect, it } from 'vitest';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { PRESETS, KEPT, applyPreset, findPreset, mergeConfig, presetOf, sameValue } from '../src/state/presets.js';
import { buildFieldTree } from '../src/state/schema.js';
import {
  MAX_REVIEW_CAMERAS, appendCameraBody, bakeReviewCameras, cameraSpec, mergeReviewCameras, newCameraName, normalizeCamera, safeName, sameView,
} from '../src/view/reviewCameras.js';

const schema = JSON.parse(readFileSync(fileURLToPath(new URL('../../proto/schema/bake-config.schema.json', import.meta.url)), 'utf8'));
const onDisk = JSON.parse(readFileSync(fileURLToPath(new URL('../../proto/presets.json', import.meta.url)), 'utf8'));
const tree = buildFieldTree(schema);

describe('presets (proto/presets.json, one file with the CLI)', () => {
  it('are the file on disk, preview / medium / production in that order', () => {
    expect(PRESETS).toEqual(onDisk.presets);
    expect(PRESETS.map((p) => p.id)).toEqual(['preview', 'medium', 'production']);
    for (const p of PRESETS) expect(p.label && p.description && typeof p.config === 'object').toBeTruthy();
    for (const p of PRESETS) for (const k of KEPT) expect(p.config[k]).toBeUndefined();  // presets leave the lighting alone
  });
  it('name only fields the schema has', () => {
    const walk = (cfg, node, path) => {
      for (const [k, v] of Object.entries(cfg)) {
        const child = node.children.find((c) => c.key === k);
        expect(child, `${path}${k}`).toBeTruthy();
        if (v && typeof v === 'object' && !Array.isArray(v)) walk(v, child, `${path}${k}.`);
      }
    };
    for (const p of PRESETS) walk(p.config, tree, '');
  });
  it('medium is the defaults; preview is lighter and production heavier', () => {
    const d = tree.default;
    expect(sameValue(applyPreset(d, d, findPreset('medium')), d)).toBe(true);
    expect(presetOf(PRESETS, d, d)).toBe('medium');
    const [pv, md, pr] = PRESETS.map((p) => applyPreset(d, d, p));
    expect(pv.place.budget).toBeLessThan(md.place.budget);
    expect(pr.place.budget).toBeGreaterThan(md.place.budget);
    expect(pv.trace.rays_per_probe).toBeLessThan(md.trace.rays_per_probe);
    expect(pr.trace.rays_per_probe).toBeGreaterThan(md.trace.rays_per_probe);
    expect(pv.evaluate.enabled).toBe(false);
    expect(md.evaluate.enabled).toBe(true);
  });
  it('applying one keeps the scene section and the seed, resets the rest, and is recognised', () => {
    const d = tree.default;
    const mine = mergeConfig(d, { seed: 7, scene: { sky: [1, 2, 3] }, masks: { clusters: 8 }, place: { budget: 99 } });
    const v = applyPreset(d, mine, findPreset('preview'));
    expect(v.seed).toBe(7);
    expect(v.scene.sky).toEqual([1, 2, 3]);
    expect(v.masks.clusters).toBe(d.masks.clusters);   // not the preset's business: back to the default
    expect(v.place.budget).toBe(2000);
    expect(v.visibility.samples_per_cell).toBe(4);
    expect(presetOf(PRESETS, d, v)).toBe('preview');
    expect(presetOf(PRESETS, d, mergeConfig(v, { trace: { rays_per_probe: 65 } }))).toBe(null);  // custom
    expect(presetOf(PRESETS, d, mine)).toBe(null);
  });
  it('merge: tables key by key, lists replaced, inputs untouched', () => {
    const a = { x: { y: 1, z: [1, 2] }, w: 1 };
    const m = mergeConfig(a, { x: { z: [3] }, v: { u: 2 } });
    expect(m).toEqual({ x: { y: 1, z: [3] }, w: 1, v: { u: 2 } });
    expect(a).toEqual({ x: { y: 1, z: [1, 2] }, w: 1 });
    expect(sameValue({ a: 1, b: [1, { c: 2 }] }, { b: [1, { c: 2 }], a: 1 })).toBe(true);
    expect(sameValue({ a: 1 }, { a: 1, b: null })).toBe(false);
  });
});

describe('review cameras', () => {
  const bake = {
    stages: [{ name: 'evaluate', stats: { cameras: [
      { name: 'cam-0', position: [1, 1.5, 2], target: [3, 1, 2], fov: 60, width: 160, height: 120 },
      { name: 'cam-1', position: [6, 1.5, 2], target: [5, 1, 3], fov: 50 },
      { name: 'broken', position: [1, 2], target: [0, 0, 0] },
    ] } }],
  };
  it('a bake\'s evaluate cameras, fov in degrees, unusable ones dropped', () => {
    const cams = bakeReviewCameras(bake);
    expect(cams.map((c) => c.name)).toEqual(['cam-0', 'cam-1']);
    expect(cams[0]).toEqual({ name: 'cam-0', position: [1, 1.5, 2], target: [3, 1, 2], fov_y: 60, source: 'bake' });
    expect(bakeReviewCameras(null)).toEqual([]);
    expect(bakeReviewCameras({ stages: [{ name: 'evaluate', stats: {} }] })).toEqual([]);
    expect(normalizeCamera({ position: [0, 0, 0], target: [1, 0, 0], fov_y: 500 }).fov_y).toBe(null);
  });
  it('the scene\'s first, then the bake\'s not among them', () => {
    const doc = { source: 'stored', cameras: [{ name: 'review-0', position: [6, 1.5, 2], target: [5, 1, 3], fov_y: 50 }, { position: [2, 2, 2], target: [0, 0, 0] }] };
    const list = mergeReviewCameras(doc, bakeReviewCameras(bake));
    expect(list.map((c) => [c.name, c.source])).toEqual([['review-0', 'stored'], ['view-1', 'stored'], ['cam-0', 'bake']]);
    expect(mergeReviewCameras(null, []).length).toBe(0);
    expect(sameView(list[0], { position: [6, 1.5, 2.00001], target: [5, 1, 3] })).toBe(true);
    expect(sameView(list[0], { position: [6, 1.6, 2], target: [5, 1, 3] })).toBe(false);
  });
  it('names and PUT bodies the API accepts', () => {
    expect(safeName('My View #1')).toBe('my-view-1');
    expect(safeName('')).toBe('view');
    expect(safeName('x'.repeat(40)).length).toBe(32);
    expect(newCameraName([{ name: 'view-1' }, { name: 'view-3' }])).toBe('view-2');
    expect(cameraSpec({ name: 'a', position: [0, 1, 2], target: [1, 1, 1], fov_y: null, width: 160 })).toEqual({ name: 'a', position: [0, 1, 2], target: [1, 1, 1] });
    const doc = { source: 'auto', cameras: [{ name: 'cam-0', position: [1, 1.5, 2], target: [3, 1, 2], fov_y: 60 }, { name: 'cam-0', position: [2, 1, 2], target: [3, 1, 2], fov_y: null }] };
    const body = appendCameraBody(doc, { position: [4, 1, 1], target: [4, 1, 3], fov_y: 60 });
    expect(body.cameras.map((c) => c.name)).toEqual(['cam-0', 'cam-0-2', 'view-1']);
    expect(body.cameras[2]).toEqual({ name: 'view-1', position: [4, 1, 1], target: [4, 1, 3], fov_y: 60 });
    expect(Object.keys(body.cameras[1]).sort()).toEqual(['name', 'position', 'target']);
    const full = { cameras: Array.from({ length: MAX_REVIEW_CAMERAS }, (_, i) => ({ name: `c${i}`, position: [i, 0, 0], target: [0, 0, 0] })) };
    expect(() => appendCameraBody(full, { position: [0, 1, 0], target: [0, 0, 0] })).toThrow(/16 review cameras/);
    expect(appendCameraBody(null, { position: [0, 1, 0], target: [0, 0, 0], fov_y: 45 }).cameras).toEqual([{ name: 'view-1', position: [0, 1, 0], target: [0, 0, 0], fov_y: 45 }]);
  });
});
