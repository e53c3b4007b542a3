import { describe, expect, it } from 'vitest';
import { viewScale } from '../src/view/autocamera.js';
import { markerSize, pickSurface } from '../src/view/lightMarkers.js';
import { Group, Mesh, MeshStandardMaterial, PerspectiveCamera, PlaneGeometry } from 'three';

describe('viewScale: clip planes and fly speed from the scene size', () => {
  it('is proportional to the size, whatever the unit', () => {
    const room = viewScale(10);            // a 10 m room: as before (near 5 mm, speed 1.25 m/s)
    expect(room.near).toBeCloseTo(0.005, 9);
    expect(room.speed).toBeCloseTo(1.25, 9);
    for (const k of [0.004, 100]) {        // the same room as a 4 cm diorama, or in centimetres
      const s = viewScale(10 * k);
      expect(s.near / room.near).toBeCloseTo(k, 6);
      expect(s.far / room.far).toBeCloseTo(k, 6);
      expect(s.speed / room.speed).toBeCloseTo(k, 6);
    }
    const tiny = viewScale(0.05);          // the near plane inside the scene: it was 5 mm, a tenth of it
    expect(tiny.near).toBeLessThan(0.05 / 1000);
  });
  it('falls back to a 10 m scene without bounds', () => {
    expect(viewScale(NaN)).toEqual(viewScale(10));
    expect(viewScale(0)).toEqual(viewScale(10));
  });
});

describe('markerSize: light markers from the scene size', () => {
  const box = (d) => [[0, 0, 0], [d / Math.sqrt(3), d / Math.sqrt(3), d / Math.sqrt(3)]];
  it('keeps 1.2% of the diagonal within 3..30 cm for scenes of human size', () => {
    expect(markerSize(box(10))).toBeCloseTo(0.12, 9);
    expect(markerSize(box(1))).toBeCloseTo(0.03, 9);
    expect(markerSize(box(100))).toBeCloseTo(0.3, 9);
  });
  it('scales its limits with scenes far smaller or larger', () => {
    expect(markerSize(box(0.06))).toBeCloseTo(0.003, 9);       // a 4 cm diorama: not a 3 cm ball over all of it
    expect(markerSize(box(2800))).toBeCloseTo(8.4, 6);        // a 2.8 km town: not a 30 cm dot
    expect(markerSize(null)).toBe(0.08);
    expect(markerSize([[0, 0, 0], [0, 0, 0]])).toBe(0.08);
  });
});

describe('pickSurface: a light placed in front of the clicked surface', () => {
  const canvas = { getBoundingClientRect: () => ({ left: 0, top: 0, width: 100, height: 100 }) };
  const floor = (size) => {
    const g = new Group();
    const m = new Mesh(new PlaneGeometry(size, size), new MeshStandardMaterial());
    m.rotation.x = -Math.PI / 2;   // facing +y
    g.add(m);
    return g;
  };
  const look = (h) => {
    const cam = new PerspectiveCamera(60, 1, h / 1000, h * 100);
    cam.position.set(0, h, 0);
    cam.lookAt(0, 0, 0.0001);
    cam.updateMatrixWorld(true);
    return cam;
  };
  it('0.3 m in front in a room seen from metres away', () => {
    const hit = pickSurface(floor(10), look(3), canvas, 50, 50);
    expect(hit.offset).toBeCloseTo(0.3, 9);
    expect(hit.position[1]).toBeCloseTo(0.3, 6);
  });
  it('15% of the distance in a 4 cm diorama seen from 5 cm (not 0.3 m, far outside it)', () => {
    const hit = pickSurface(floor(0.04), look(0.05), canvas, 50, 50);
    expect(hit.offset).toBeCloseTo(0.0075, 6);
    expect(hit.position[1]).toBeCloseTo(0.0075, 6);
  });
});
