/**
 * Shadow maps for the direct light (proto/glsl/shadows.glsl): a distance cube map per point/spot light and
 * an orthographic distance map per directional light, re-rendered only when the lights or the scene change.
 * Distances are packed into RGBA8 (renderable on every WebGL2 device) and read with NEAREST filtering.
 */
import { isUnlitMesh, litBounds } from './unlit.js';
import {
  Color, CubeCamera, DoubleSide, GLSL3, Matrix4, NearestFilter, OrthographicCamera, RawShaderMaterial, Vector3, Vector4,
  WebGLCubeRenderTarget, WebGLRenderTarget,
} from 'three';

export const SHADOW_CUBES = 4;
export const SHADOW_DIRS = 2;
const CUBE_SIZE = 512;
const DIR_SIZE = 1024;

export class ShadowMaps {
  /** @param {import('./renderer.js').GIRenderer} gi */
  constructor(gi) {
    this.gi = gi;
    const opts = { minFilter: NearestFilter, magFilter: NearestFilter, generateMipmaps: false, depthBuffer: true };
    this.cubes = Array.from({ length: SHADOW_CUBES }, () => new WebGLCubeRenderTarget(CUBE_SIZE, opts));
    this.dirs = Array.from({ length: SHADOW_DIRS }, () => new WebGLRenderTarget(DIR_SIZE, DIR_SIZE, opts));
    this.material = new RawShaderMaterial({
      name: 'kiln:shadow-depth',
      glslVersion: GLSL3,
      vertexShader: gi.source('shadow_depth.vert.glsl'),
      fragmentShader: gi.source('shadow_depth.frag.glsl'),
      uniforms: { uShadowOrigin: { value: new Vector3() }, uShadowDirection: { value: new Vector3() }, uShadowFar: { value: 1 } },
      side: DoubleSide,
    });
    this.cubeCamera = new CubeCamera(0.01, 100, this.cubes[0]);
    this.ortho = new OrthographicCamera(-1, 1, 1, -1, 0, 1);
  }

  /** The shared uniforms the scene shaders read (added to GIRenderer.shared). */
  static uniforms(maxLights) {
    const u = {
      uShadowInfo: { value: Array.from({ length: maxLights }, () => new Vector4(-1, 1, 0, 0)) },
      uShadowMatrix: { value: Array.from({ length: maxLights }, () => new Matrix4()) },
    };
    for (let i = 0; i < SHADOW_CUBES; i++) u[`uShadowCube${i}`] = { value: null };
    for (let i = 0; i < SHADOW_DIRS; i++) u[`uShadowDir${i}`] = { value: null };
    return u;
  }

  /** Render the maps of `lights` (GIRenderer.lights) over the scene `root`. */
  update(world, root, lights) {
    const three = this.gi.three;
    const u = this.gi.shared;
    const box = litBounds(root);          // unlit meshes (a sky dome) neither cast shadows nor set the maps' extent
    if (box.isEmpty()) return;
    const centre = box.getCenter(new Vector3());
    const radius = Math.max(1e-3, box.getSize(new Vector3()).length() * 0.5);
    const hidden = [];
    world.traverse((o) => {
      if (o.isMesh && (!root.getObjectById(o.id) || isUnlitMesh(o)) && o.visible) { hidden.push(o); o.visible = false; }
    });
    const prevOverride = world.overrideMaterial;
    const prevClear = three.getClearColor(new Color());
    const prevAlpha = three.getClearAlpha();
    world.overrideMaterial = this.material;
    three.setClearColor(0xffffff, 1);  // cleared = farthest: nothing occludes
    let cube = 0, dir = 0;
    lights.forEach((l, i) => {
      const info = u.uShadowInfo.value[i];
      info.x = -1;
      if (l.type === 'directional' && dir < SHADOW_DIRS) {
        const d = new Vector3(...l.direction).normalize();
        const cam = this.ortho;
        cam.left = -radius; cam.right = radius; cam.top = radius; cam.bottom = -radius;
        cam.near = 0; cam.far = 2.2 * radius;
        cam.position.copy(centre).addScaledVector(d, -1.1 * radius);
        cam.up.set(Math.abs(d.y) > 0.9 ? 1 : 0, Math.abs(d.y) > 0.9 ? 0 : 1, 0);
        cam.lookAt(centre);
        cam.updateProjectionMatrix();
        cam.updateMatrixWorld(true);
        this.material.uniforms.uShadowOrigin.value.copy(cam.position);
        this.material.uniforms.uShadowDirection.value.copy(d);
        this.material.uniforms.uShadowFar.value = cam.far;
        three.setRenderTarget(this.dirs[dir]);
        three.clear();
        three.render(world, cam);
        u.uShadowMatrix.value[i].multiplyMatrices(cam.projectionMatrix, cam.matrixWorldInverse);
        u[`uShadowDir${dir}`].value = this.dirs[dir].texture;
        Object.assign(info, { x: dir, y: cam.far, z: 0.004 * radius, w: 1.5 / DIR_SIZE });
        dir += 1;
      } else if ((l.type === 'point' || l.type === 'spot') && cube < SHADOW_CUBES) {
        const p = new Vector3(...l.position);
        const far = p.distanceTo(centre) + radius + 1e-3;
        this.cubeCamera.renderTarget = this.cubes[cube];
        this.cubeCamera.children.forEach((c) => { c.near = Math.min(0.01, far / 1000); c.far = far; c.updateProjectionMatrix(); });
        this.cubeCamera.position.copy(p);
        this.cubeCamera.updateMatrixWorld(true);
        this.material.uniforms.uShadowOrigin.value.copy(p);
        this.material.uniforms.uShadowDirection.value.set(0, 0, 0);
        this.material.uniforms.uShadowFar.value = far;
        this.cubeCamera.update(three, world);
        u[`uShadowCube${cube}`].value = this.cubes[cube].texture;
        Object.assign(info, { x: cube, y: far, z: 0.004 * radius, w: 2.5 / CUBE_SIZE });
        cube += 1;
      }
    });
    three.setRenderTarget(null);
    world.overrideMaterial = prevOverride;
    three.setClearColor(prevClear, prevAlpha);
    hidden.forEach((o) => { o.visible = true; });
  }
}
