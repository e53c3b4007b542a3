/**
 * Camera controllers: orbit (three's OrbitControls) and fly (WASD/QE + drag to look, shift for speed).
 * Both call onChange when the view moves, so the viewer renders on demand instead of every frame.
 */
import { Euler, Vector3 } from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

export class FlyControls {
  constructor(camera, dom, onChange) {
    this.camera = camera;
    this.dom = dom;
    this.onChange = onChange;
    this.speed = 2;  // metres per second, scaled to the scene by the viewer
    this.keys = new Set();
    this.enabled = false;
    this.euler = new Euler(0, 0, 0, 'YXZ');
    this.dragging = false;
    const down = (e) => { if (!this.enabled) return; this.dragging = true; this.last = [e.clientX, e.clientY]; dom.setPointerCapture?.(e.pointerId); };
    const move = (e) => {
      if (!this.enabled || !this.dragging) return;
      const dx = e.clientX - this.last[0], dy = e.clientY - this.last[1];
      this.last = [e.clientX, e.clientY];
      this.euler.setFromQuaternion(this.camera.quaternion);
      this.euler.y -= dx * 0.004;
      this.euler.x = Math.max(-1.55, Math.min(1.55, this.euler.x - dy * 0.004));
      this.camera.quaternion.setFromEuler(this.euler);
      this.onChange();
    };
    const up = () => { this.dragging = false; };
    const key = (on) => (e) => {
      if (!this.enabled || e.target.closest?.('input, select, textarea')) return;
      const k = e.key.toLowerCase();
      if (!'wasdqe'.includes(k) && k !== 'shift') return;
      if (on) this.keys.add(k); else this.keys.delete(k);
      if (on) this.onChange();
    };
    dom.addEventListener('pointerdown', down);
    dom.addEventListener('pointermove', move);
    dom.addEventListener('pointerup', up);
    window.addEventListener('keydown', key(true));
    window.addEventListener('keyup', key(false));
    window.addEventListener('blur', () => this.keys.clear());
  }

  /** Move for dt seconds; returns true while a key is held (the viewer keeps rendering). */
  update(dt) {
    if (!this.enabled || !this.keys.size) return false;
    const v = new Vector3(
      (this.keys.has('d') ? 1 : 0) - (this.keys.has('a') ? 1 : 0),
      (this.keys.has('e') ? 1 : 0) - (this.keys.has('q') ? 1 : 0),
      (this.keys.has('s') ? 1 : 0) - (this.keys.has('w') ? 1 : 0),
    );
    if (v.lengthSq() === 0) return this.keys.size > 0;
    v.normalize().multiplyScalar(this.speed * dt * (this.keys.has('shift') ? 4 : 1)).applyQuaternion(this.camera.quaternion);
    this.camera.position.add(v);
    return true;
  }
}

export function createControls(camera, dom, onChange) {
  const orbit = new OrbitControls(camera, dom);
  orbit.enableDamping = false;
  orbit.addEventListener('change', onChange);
  const fly = new FlyControls(camera, dom, onChange);
  return {
    orbit, fly,
    mode: 'orbit',
    setMode(mode) {
      this.mode = mode;
      orbit.enabled = mode === 'orbit';
      fly.enabled = mode === 'fly';
      if (mode === 'orbit') {
        // keep looking where the fly camera looked: put the orbit target in front of it
        const dir = new Vector3(0, 0, -1).applyQuaternion(camera.quaternion);
        const dist = Math.max(20 * camera.near, camera.position.distanceTo(orbit.target));  // near: the scene's size / 2000
        orbit.target.copy(camera.position).addScaledVector(dir, dist);
        orbit.update();
      }
    },
    lookAt(position, target) {
      camera.position.fromArray(position);
      orbit.target.fromArray(target);
      camera.lookAt(orbit.target);
      orbit.update();
      onChange();
    },
    update(dt) { return fly.update(dt); },
  };
}
