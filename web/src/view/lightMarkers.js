/**
 * Light markers drawn in every GI mode (the renderer's overlay group: drawn, never shadowed): a small
 * sphere in the light's colour for point lights, a sphere and a wireframe cone (outer angle) for spots, an
 * arrow along the sunlight above the scene for directional lights. Also the surface pick used to place a
 * light by clicking (0.3 m in front of the surface hit).
 */
import {
  ArrowHelper, BufferGeometry, Color, ConeGeometry, Group, Line, LineBasicMaterial, Matrix3, Mesh, MeshBasicMaterial, Quaternion, Raycaster,
  SphereGeometry, Vector2, Vector3,
} from 'three';

/** Metres a clicked light is placed off the surface, along its normal. */
export const PLACE_OFFSET = 0.3;
/** ... but at most this fraction of the camera's distance to the surface (a 4 cm diorama seen from 5 cm: 7.5 mm; from
 * 2 m and more, 0.3 m as before). */
export const PLACE_OFFSET_OF_DISTANCE = 0.15;

function markerColor(c) {
  const col = new Color(c?.[0] ?? 1, c?.[1] ?? 1, c?.[2] ?? 1);
  const peak = Math.max(col.r, col.g, col.b, 1e-6);
  col.multiplyScalar(1 / peak);  // a bright marker of the light's hue
  return col.lerp(new Color(1, 0.93, 0.55), 0.35);
}

/**
 * Marker size from scene bounds: 1.2 % of the diagonal, within 3..30 cm for scenes of human size; the limits scale
 * with the scene beyond it (a 4 cm diorama: 5 % of its diagonal, not a 3 cm ball over the whole scene; a 2 km town or
 * a room in centimetres: up to 0.3 % of the diagonal, not a 30 cm dot).
 */
export function markerSize(bounds) {
  if (!bounds) return 0.08;
  const d = Math.hypot(...bounds[1].map((x, i) => x - bounds[0][i]));
  if (!(d > 0)) return 0.08;
  const lo = Math.min(0.03, 0.05 * d), hi = Math.max(0.3, 0.003 * d);
  return Math.min(hi, Math.max(lo, 0.012 * d));
}

/**
 * A Group of markers for `lights` (the `lights` artifact's or the form's, KHR units).
 * @param {object[]} lights
 * @param {number[][]|null} bounds  scene bounds, for the size and where the sun arrow goes
 */
export function buildLightMarkers(lights, bounds) {
  const g = new Group();
  g.name = 'kiln:lights';
  const size = markerSize(bounds);
  const down = new Vector3(0, -1, 0);
  (lights || []).forEach((l, i) => {
    const color = markerColor(l.color);
    const m = new Group();
    m.name = `light:${i}`;
    m.userData = { light: l, index: i };
    if (l.type === 'directional') {
      const dir = new Vector3().fromArray(l.direction || [0, -1, 0]).normalize();
      const top = bounds ? new Vector3((bounds[0][0] + bounds[1][0]) / 2, bounds[1][1], (bounds[0][2] + bounds[1][2]) / 2) : new Vector3(0, 2, 0);
      const len = size * 8;
      const start = top.clone().addScaledVector(dir, -len * 1.2);
      m.add(new ArrowHelper(dir, start, len, color.getHex(), len * 0.3, len * 0.15));
    } else if (l.position) {
      const p = new Vector3().fromArray(l.position);
      const ball = new Mesh(new SphereGeometry(size, 16, 12), new MeshBasicMaterial({ color }));
      ball.position.copy(p);
      m.add(ball);
      if (l.type === 'spot' && l.direction) {
        const dir = new Vector3().fromArray(l.direction).normalize();
        const len = size * 6;
        const angle = Math.min(l.outer_cone_angle ?? Math.PI / 4, 1.45);
        const cone = new Mesh(new ConeGeometry(Math.tan(angle) * len, len, 20, 1, true),
          new MeshBasicMaterial({ color, wireframe: true, transparent: true, opacity: 0.6 }));
        // ConeGeometry points +Y with its apex at +len/2: turn the apex to the light, the opening along dir
        cone.quaternion.copy(new Quaternion().setFromUnitVectors(down, dir));
        cone.position.copy(p).addScaledVector(dir, len / 2);
        m.add(cone);
      } else {
        // a short vertical tick below a point light makes its height readable against the floor
        const geo = new BufferGeometry().setFromPoints([p.clone(), p.clone().add(new Vector3(0, -size * 3, 0))]);
        m.add(new Line(geo, new LineBasicMaterial({ color })));
      }
    }
    g.add(m);
  });
  return g;
}

/** Free a marker group's geometries and materials. */
export function disposeMarkers(group) {
  group?.traverse((o) => {
    if (o.parent?.type !== 'ArrowHelper') o.geometry?.dispose?.();  // ArrowHelper shares its geometries
    if (o.material) [].concat(o.material).forEach((m) => m.dispose());
  });
}

/**
 * The surface under a canvas pixel: {point, normal (unit, facing the camera), position (`offset` in front:
 * PLACE_OFFSET, or 15% of the camera's distance to the surface when that is less), offset}
 * or null. `root` is the loaded glTF scene.
 */
export function pickSurface(root, camera, canvas, clientX, clientY) {
  if (!root) return null;
  const r = canvas.getBoundingClientRect();
  const ndc = new Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
  const ray = new Raycaster();
  ray.setFromCamera(ndc, camera);
  root.updateMatrixWorld(true);
  const hit = ray.intersectObject(root, true).find((x) => x.face && x.object.isMesh);
  if (!hit) return null;
  const n = hit.face.normal.clone().applyMatrix3(new Matrix3().getNormalMatrix(hit.object.matrixWorld)).normalize();
  if (n.dot(ray.ray.direction) > 0) n.negate();  // the side the camera sees
  const offset = Math.min(PLACE_OFFSET, PLACE_OFFSET_OF_DISTANCE * hit.distance);
  const position = hit.point.clone().addScaledVector(n, offset);
  return { point: hit.point.toArray(), normal: n.toArray(), position: position.toArray(), offset };
}
