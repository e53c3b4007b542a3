import { describe, expect, it } from 'vitest';
import { viewScale } from '../src/view/autocamera.js';

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
