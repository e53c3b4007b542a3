import { describe, expect, it } from 'vitest';
import { viewScale } from '../src/view/autocamera.js';
import { markerSize } from '../src/view/lightMarkers.js';

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
