import { describe, expect, it } from 'vitest';
import { BoxGeometry, Group, Mesh, MeshBasicMaterial, MeshStandardMaterial, SphereGeometry } from 'three';
import { isUnlitMesh, litBounds } from '../src/renderer/unlit.js';

describe('unlit meshes (KHR_materials_unlit: left out of the bake)', () => {
  const room = new Mesh(new BoxGeometry(4, 3, 4), new MeshStandardMaterial());
  const dome = new Mesh(new SphereGeometry(500), new MeshBasicMaterial());   // what GLTFLoader makes of unlit
  const root = new Group();
  root.add(room, dome);

  it('are the meshes whose every material is a MeshBasicMaterial (or replaced one)', () => {
    expect(isUnlitMesh(dome)).toBe(true);
    expect(isUnlitMesh(room)).toBe(false);
    const replaced = new Mesh(new BoxGeometry(), new MeshStandardMaterial());
    replaced.material.userData.kilnOriginal = new MeshBasicMaterial();
    expect(isUnlitMesh(replaced)).toBe(true);
    const mixed = new Mesh(new BoxGeometry(), [new MeshBasicMaterial(), new MeshStandardMaterial()]);
    expect(isUnlitMesh(mixed)).toBe(false);
    expect(isUnlitMesh(new Group())).toBe(false);
  });

  it('do not set the bounds the shadow maps cover', () => {
    const b = litBounds(root);
    expect(b.max.x).toBeCloseTo(2, 6);
    expect(b.min.y).toBeCloseTo(-1.5, 6);
    expect(litBounds(new Group()).isEmpty()).toBe(true);
  });
});
