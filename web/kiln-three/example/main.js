/**
 * @kiln/three example: a baked Kiln bundle in a plain three.js scene (MeshStandardMaterial from GLTFLoader, the
 * glTF's own lights with shadow maps), lit indirectly by the bake.
 *
 * Query parameters: bundle (URL of the bundle folder, default ./bundle/) or bake (a bake id on the Kiln server that
 * serves the page, or on ?server=URL), mode (grid | off | leaking | ddgi | mask |
 * mask_normalized; default grid, or leaking for a bake whose probe grid is turned: grid.frame), material (standard | lambert), cam=px,py,pz,tx,ty,tz (glTF coordinates, metres),
 * fov (vertical, degrees), exposure (default 0.4; ACES), shadows (0 to turn the shadow maps off). Without cam: the Kiln
 * viewer's first view (web/src/view/autocamera.js, inside a room of a closed scene).
 * window.kiln exposes the state and renderLinear() (linear HDR pixels) for the browser tests.
 */
import {
  ACESFilmicToneMapping, Box3, Color, FloatType, MeshLambertMaterial, PCFShadowMap, PerspectiveCamera, RGBAFormat,
  Vector3, WebGLRenderTarget, WebGLRenderer,
} from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { loadKilnBundle } from '../src/index.js';
import { autoCamera } from '../../src/view/autocamera.js';   // the Kiln viewer's first view: inside a room

const q = new URLSearchParams(location.search);
const canvas = document.getElementById('view');
const status = document.getElementById('status');
const renderer = new WebGLRenderer({ canvas, antialias: true });
renderer.setPixelRatio(Math.min(2, devicePixelRatio || 1));
renderer.toneMapping = ACESFilmicToneMapping;
renderer.toneMappingExposure = Number(q.get('exposure') || 0.4);
renderer.shadowMap.enabled = q.get('shadows') !== '0';
renderer.shadowMap.type = PCFShadowMap;

const camera = new PerspectiveCamera(Number(q.get('fov') || 60), 1, 0.01, 100);
const controls = new OrbitControls(camera, canvas);
const materials = { standard: new Map(), lambert: new Map() };   // mesh -> material of each kind
const state = { mode: q.get('mode'), material: q.get('material') || 'standard' };   // mode: loadKilnBundle's by default

function lambertOf(m) {
  return new MeshLambertMaterial({ name: `${m.name}:lambert`, color: m.color, map: m.map, emissive: m.emissive,
    emissiveMap: m.emissiveMap, emissiveIntensity: m.emissiveIntensity, side: m.side, vertexColors: m.vertexColors,
    alphaTest: m.alphaTest, transparent: m.transparent, opacity: m.opacity });
}

function setupScene(scene, bundle) {
  const box = new Box3().setFromObject(scene);
  scene.traverse((o) => {
    if (o.isMesh) {
      o.castShadow = o.receiveShadow = true;
      materials.standard.set(o, o.material);
      materials.lambert.set(o, lambertOf(o.material));
    }
    if (o.isLight && o.shadow && !o.isLightProbeGrid) {
      o.castShadow = true;
      o.shadow.mapSize.set(1024, 1024);
      o.shadow.bias = -0.0005;
      o.shadow.normalBias = 0.01;
      o.shadow.camera.near = 0.02;
      o.shadow.camera.far = box.getSize(new Vector3()).length() * 2;
      if (o.isDirectionalLight) {   // cover the scene's box
        const r = box.getSize(new Vector3()).length() / 2;
        Object.assign(o.shadow.camera, { left: -r, right: r, top: r, bottom: -r, far: 4 * r });
        o.target.position.copy(box.getCenter(new Vector3()));
        o.position.copy(o.target.position).addScaledVector(o.getWorldDirection(new Vector3()), -2 * r);
      }
    }
  });
  const sky = bundle.manifest.config?.scene?.sky || [0, 0, 0];
  scene.background = new Color(sky[0], sky[1], sky[2]);
  const cam = (q.get('cam') || '').split(',').map(Number);
  if (cam.length === 6 && cam.every(Number.isFinite)) {
    camera.position.set(cam[0], cam[1], cam[2]);
    controls.target.set(cam[3], cam[4], cam[5]);
  } else {
    const auto = autoCamera(scene, bundle.manifest.scene?.bounds);
    camera.position.fromArray(auto.position);
    controls.target.fromArray(auto.target);
  }
  camera.near = 0.01;
  camera.far = box.getSize(new Vector3()).length() * 4 + 1;
  camera.lookAt(controls.target);
  controls.update();
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}

async function main() {
  // ?bake=ID: a bake on the Kiln server that serves this page (kiln serve: /app/kiln-three/example/), else a folder
  const bake = q.get('bake');
  const loaded = await loadKilnBundle(bake ? (q.get('server') || new URL('../../../', location.href).href)
    : (q.get('bundle') || './bundle/'), renderer, { bake });
  const { scene, gi, bundle } = loaded;
  setupScene(scene, bundle);
  for (const m of materials.lambert.values()) gi.extend(m);

  const modeSel = document.getElementById('mode');
  const options = [['off', 'off'], ...(loaded.probeGrid ? [['grid', 'leaking: three.js LightProbeGrid']] : []),
    ...gi.modes().filter((m) => m.available).map((m) => [m.id, `${m.label} (Kiln GLSL)`])];
  for (const [id, label] of options) modeSel.add(new Option(label, id));
  const matSel = document.getElementById('material');

  const api = {
    ...loaded, camera, renderer, state,
    async setMode(id) { await gi.setMode(id); state.mode = id; modeSel.value = id; draw(); },
    setMaterial(kind) {
      for (const [mesh, m] of materials[kind]) mesh.material = m;
      state.material = kind; matSel.value = kind; draw();
    },
    /** Render at width × height into an RGBA32F target (linear radiance, no tone mapping): base64 of the Float32
     * RGBA texels, row 0 = the image's top row. */
    renderLinear(width, height) {
      const rt = new WebGLRenderTarget(width, height, { type: FloatType, format: RGBAFormat, samples: 0 });
      const aspect = camera.aspect;
      camera.aspect = width / height;
      camera.updateProjectionMatrix();
      renderer.setRenderTarget(rt);
      renderer.clear();
      renderer.render(scene, camera);
      const px = new Float32Array(width * height * 4);
      renderer.readRenderTargetPixels(rt, 0, 0, width, height, px);
      renderer.setRenderTarget(null);
      rt.dispose();
      camera.aspect = aspect;
      camera.updateProjectionMatrix();
      const flipped = new Float32Array(px.length);   // GL rows start at the bottom
      const row = width * 4;
      for (let y = 0; y < height; y++) flipped.set(px.subarray((height - 1 - y) * row, (height - y) * row), y * row);
      const bytes = new Uint8Array(flipped.buffer);
      let s = '';
      for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
      return btoa(s);
    },
  };
  window.kiln = api;
  modeSel.onchange = () => api.setMode(modeSel.value);
  matSel.onchange = () => api.setMaterial(matSel.value);
  renderer.compile(scene, camera);
  await api.setMode(state.mode || gi.mode);
  api.setMaterial(state.material);
  status.textContent = `${bundle.grid.counts.join('×')} probes, ${bundle.names.length} artifacts`;
  controls.addEventListener('change', draw);
  addEventListener('resize', () => { resize(); draw(); });
  resize();
  function draw() { renderer.render(scene, camera); }
  draw();
  api.draw = draw;
}

window.kilnReady = main().catch((e) => {
  status.textContent = `error: ${e.message}`;
  console.error(e);
  throw e;
});
