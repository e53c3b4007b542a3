import { describe, expect, it } from 'vitest';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import {
  LIGHT_TYPES, defaultLight, degToRad, hexToLinear, insideBounds, lightCoverage, linearToHex, preBakeWarnings, radToDeg, radToDegRounded, skyControls,
  skyRadiance, sunAngles, sunDirection,
} from '../src/state/lighting.js';
import { FIELD_UI, fieldUi, humanize, splitReferences } from '../src/state/formLabels.js';
import { buildFieldTree, walkFields } from '../src/state/schema.js';
import { chartValues, clusterCount, lightCount, metricColumns, metricInfo, probeCount, sceneLabel } from '../src/state/stats.js';

const schema = JSON.parse(readFileSync(fileURLToPath(new URL('../../proto/schema/bake-config.schema.json', import.meta.url)), 'utf8'));
const ROOM = [[0, 0, 0], [4, 3, 4]];

describe('degrees and radians', () => {
  it('convert both ways', () => {
    expect(degToRad(180)).toBeCloseTo(Math.PI, 12);
    expect(radToDeg(Math.PI / 4)).toBeCloseTo(45, 12);
    expect(radToDegRounded(degToRad(37.5))).toBe(37.5);
    expect(radToDegRounded(Math.PI / 4)).toBe(45);
  });
  it('a sun from elevation and azimuth, and back', () => {
    expect(sunDirection(90, 0).map((x) => Math.round(x * 1e9) / 1e9)).toEqual([0, -1, 0]);  // overhead: straight down
    const d = sunDirection(30, 90);  // sun towards +X, low: light travels towards -X and down
    expect(d[0]).toBeCloseTo(-Math.cos(degToRad(30)), 12);
    expect(d[1]).toBeCloseTo(-0.5, 12);
    expect(Math.hypot(...d)).toBeCloseTo(1, 12);
    for (const [el, az] of [[45, 30], [10, 200], [80, 359]]) expect(sunAngles(sunDirection(el, az))).toEqual({ elevation: el, azimuth: az });
  });
});

describe('colours and sky', () => {
  it('sRGB pickers <-> linear RGB', () => {
    expect(hexToLinear('#ffffff')).toEqual([1, 1, 1]);
    expect(hexToLinear('#000000')).toEqual([0, 0, 0]);
    expect(hexToLinear('#808080')[0]).toBeCloseTo(0.2158605, 5);
    expect(linearToHex([0.2158605, 0.2158605, 0.2158605])).toBe('#808080');
    expect(linearToHex([4, 2, 0])).toBe(linearToHex([1, 0.5, 0]));  // brighter than 1: the hue
  });
  it('sky colour x strength', () => {
    expect(skyRadiance('#ffffff', 0)).toEqual([0, 0, 0]);
    expect(skyRadiance('#ffffff', 500)).toEqual([500, 500, 500]);
    expect(skyControls([0, 0, 0])).toEqual({ hex: '#ffffff', strength: 0 });
    const c = skyControls([300, 300, 600]);
    expect(c.strength).toBe(600);
    expect(skyRadiance(c.hex, c.strength)[2]).toBeCloseTo(600, 6);
  });
});

describe('light defaults and checks', () => {
  it('a point light in candela near the ceiling, a sun in lux, a spot with degrees', () => {
    const p = defaultLight('point', ROOM);
    expect(p).toMatchObject({ type: 'point', intensity: 100, direction: null, position: [2, 2.4, 2] });
    expect(LIGHT_TYPES.point.unit).toBe('cd');
    const sun = defaultLight('directional', ROOM);
    expect(sun.position).toBe(null);
    expect(sun.intensity).toBe(10000);
    expect(LIGHT_TYPES.directional.unit).toBe('lx');
    const spot = defaultLight('spot', ROOM);
    expect(radToDegRounded(spot.outer_cone_angle)).toBe(45);
    expect(spot.inner_cone_angle).toBeLessThan(spot.outer_cone_angle);
    expect(defaultLight(undefined).type).toBe('point');
  });
  it('bounds with the ingest stage\'s 10 % margin', () => {
    expect(insideBounds([2, 1, 2], ROOM)).toBe(true);
    expect(insideBounds([4.5, 1, 2], ROOM)).toBe(true);      // 0.5 m out, margin 0.1 x 6.4 m
    expect(insideBounds([50, 1, 2], ROOM)).toBe(false);
    expect(insideBounds([2, -1, 2], ROOM)).toBe(false);
    expect(insideBounds([50, 1, 2], null)).toBe(true);       // unknown bounds: no warning
  });
  it('warns before the bake: a light outside the scene, an unlit scene', () => {
    const scene = { bounds: ROOM, lights: 0, emissive_materials: 0 };
    const unlit = { scene: { lights: [], sky: [0, 0, 0], use_scene_lights: true } };
    expect(preBakeWarnings(unlit, scene).map((w) => w.code)).toEqual(['unlit_scene']);
    expect(preBakeWarnings({ scene: { ...unlit.scene, sky: [0.5, 0.5, 0.5] } }, scene)).toEqual([]);
    expect(preBakeWarnings(unlit, { ...scene, emissive_materials: 2 })).toEqual([]);
    expect(preBakeWarnings(unlit, { ...scene, emissive_materials: undefined })).toEqual([]);  // older scene records: unknown
    expect(preBakeWarnings(unlit, { ...scene, lights: 1 })).toEqual([]);
    const dropped = preBakeWarnings({ scene: { ...unlit.scene, use_scene_lights: false } }, { ...scene, lights: 1 });
    expect(dropped.map((w) => w.code)).toEqual(['unlit_scene']);
    expect(dropped[0].message).toContain('switched off');
    const far = { scene: { ...unlit.scene, lights: [defaultLight('point', ROOM), { ...defaultLight('point'), position: [50, 2, 2] }, defaultLight('directional')] } };
    const w = preBakeWarnings(far, scene);
    expect(w.map((x) => [x.code, x.path])).toEqual([['light_outside_scene', 'scene.lights.1']]);
    expect(w[0].message).toContain('(50, 2, 2)');
  });
});

describe('the form speaks in words', () => {
  const tree = buildFieldTree(schema);
  it('no class names or bare keys as labels, every section labelled', () => {
    for (const n of walkFields(tree)) {
      if (!n.path) continue;
      const ui = fieldUi(n);
      expect(ui.label).not.toMatch(/Section$|Config$|^[a-z_]+$/);
      expect(ui.label).not.toMatch(/θ|§/);
    }
    expect(fieldUi(tree.children.find((c) => c.key === 'place')).label).toBe('Probes');
    expect(fieldUi(tree.children.find((c) => c.key === 'light')).label).toBe('Light');
    expect(fieldUi(tree.children.find((c) => c.key === 'visibility')).label).toMatch(/^Leak removal/);
    expect(Object.keys(FIELD_UI).every((p) => walkFields(tree).some((n) => n.path === p))).toBe(true);  // no stale paths
  });
  it('paper references go to the tooltip', () => {
    expect(splitReferences('relocation limit (DDGI-P §5, Fig 7)')).toEqual({ text: 'relocation limit', refs: ['DDGI-P §5, Fig 7'] });
    const { text, refs } = splitReferences('Probe rays, relocation and classification (DDGI-P §2.3, §5 Fig 7, §6 Fig 10; stages relocate + trace).');
    expect(text).toBe('Probe rays, relocation and classification.');
    expect(refs.join(' ')).toContain('DDGI-P §2.3');
    const trace = tree.children.find((c) => c.key === 'trace');
    const ui = fieldUi(trace);
    expect(ui.help).not.toMatch(/§|DDGI/);
    expect(ui.tooltip).toContain('DDGI-P');
    expect(humanize('rays_per_probe')).toBe('Rays per probe');
  });
  it('advanced settings fold, the everyday ones stay', () => {
    expect(fieldUi({ path: 'trace.depth_sharpness', key: 'depth_sharpness' }).advanced).toBe(true);
    expect(fieldUi({ path: 'trace.rays_per_probe', key: 'rays_per_probe' }).advanced).toBe(false);
    expect(fieldUi({ path: 'scene.lights', key: 'lights' }).advanced).toBe(false);
  });
});

describe('dashboard columns', () => {
  const bake = {
    scene_id: 'abcdef0123456789', config: { masks: { clusters: 6 }, scene: { lights: [{}] } },
    stages: [{ name: 'ingest', seconds: 0.1, stats: { lights: 3 } }, { name: 'place', seconds: 0.2, stats: { counts: [4, 3, 2] } },
      { name: 'anneal', seconds: 1 }],
    metrics: { 'stage_seconds.place': 0.2, artifact_bytes: 1234, mask: { rmse: 0.1, pass_ms: 2, texture_bytes: 5e5, leak: 0.01 }, ratio: { mask_over_leaking: { pass_ms: 1.5 } } },
    artifacts: [{ bytes: 1234 }],
  };
  it('probes, K, lights, scene name', () => {
    expect(probeCount(bake)).toBe(24);
    expect(clusterCount(bake)).toBe(6);
    expect(clusterCount({ stages: [{ name: 'place' }] })).toBe(null);
    expect(lightCount(bake)).toBe(3);
    expect(sceneLabel([{ id: 'abcdef0123456789', filename: 'room.glb' }], bake.scene_id)).toBe('room.glb');
    expect(sceneLabel([], bake.scene_id)).toBe('abcdef0123');
  });
  it('stage times and artifact size only once; metrics with units, lower is better', () => {
    expect(metricColumns([bake])).toEqual(['mask.leak', 'mask.pass_ms', 'mask.rmse', 'mask.texture_bytes', 'ratio.mask_over_leaking.pass_ms']);
    expect(metricColumns([bake], 'key')).toEqual(['mask.leak', 'mask.pass_ms', 'mask.rmse']);
    expect(metricColumns([bake], 'none')).toEqual([]);
    expect(metricInfo('mask.pass_ms')).toMatchObject({ mode: 'mask', unit: 'ms', lowerIsBetter: true, header: 'mask shading pass (ms) ↓' });
    expect(metricInfo('mask.texture_bytes').bytes).toBe(true);
    expect(metricInfo('ratio.mask_over_leaking.pass_ms')).toMatchObject({ mode: 'mask / leaking', unit: '×' });
    expect(metricInfo('mask.rmse').help).toContain('lower is better');
    const v = chartValues(bake);
    expect(v['artifact size MiB']).toBeCloseTo(1234 / 2 ** 20);
    expect(v).not.toHaveProperty('memory MiB');
    expect(v).not.toHaveProperty(['stage_seconds.place']);
    expect(v['place seconds']).toBe(0.2);
  });
});

describe('lightCoverage: what the viewer\'s direct light leaves out', () => {
  const limits = { maxLights: 8, cubes: 4, dirs: 2 };
  const pts = (n) => Array.from({ length: n }, () => ({ type: 'point' }));
  it('says nothing when every light is drawn with a shadow map', () => {
    expect(lightCoverage([], limits)).toBe('');
    expect(lightCoverage([...pts(4), { type: 'directional' }, { type: 'directional' }], limits)).toBe('');
  });
  it('names the lights beyond a pass and the unshadowed ones', () => {
    const note = lightCoverage(pts(32), limits);
    expect(note).toContain('first 8 of the bake\'s 32 lights');
    expect(note).toContain('hold all 32');
    expect(note).toContain('4 of the 8 drawn lights are unshadowed');
    expect(lightCoverage([...pts(5)], limits)).toBe('1 of the 5 drawn lights is unshadowed here (shadow maps for 4 point/spot and 2 directional lights).');
    expect(lightCoverage([{ type: 'directional' }, { type: 'directional' }, { type: 'directional' }], limits)).toContain('1 of the 3 drawn lights is unshadowed');
  });
});
