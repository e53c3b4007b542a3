/**
 * A first view of a scene. Closed scenes (rooms) are black from outside when their lights are inside, so
 * the viewer looks for a point inside the bounds that sees front faces all around (inside a room, not inside
 * a wall) and looks along its longest free horizontal direction. Open scenes get an orbit view from outside.
 * Raycasts with three's Raycaster; skipped for big scenes (no BVH here).
 */
import { Box3, Raycaster, Vector3 } from 'three';

const MAX_TRIANGLES = 200000;  // above this, raycasting without a BVH takes too long: outside view

function triangleCount(root) {
  let n = 0;
  root.traverse((o) => {
    if (o.isMesh) n += (o.geometry.index ? o.geometry.index.count : o.geometry.attributes.position.count) / 3;
  });
  return n;
}

function outsideView(box) {
  const c = box.getCenter(new Vector3());
  const size = box.getSize(new Vector3());
  const r = Math.max(size.length() * 0.5, 1e-3);
  const pos = c.clone().add(new Vector3(0.55, 0.45, 1.0).normalize().multiplyScalar(r * 2.2));
  return { position: pos.toArray(), target: c.toArray(), inside: false };
}

/**
 * Clip planes and fly speed for a scene of this size, whatever its unit: a 4 cm diorama (a tabletop AR scene at
 * its real size) must not lose 5 mm to the near plane nor be crossed ten times a second; a 2 km town keeps a
 * depth range of 1 m to 40 km. Proportional to the size (the near plane 1/2000 of it, the far 20x).
 * @param {number} size  the bounds' diagonal, scene units (metres)
 * @returns {{near: number, far: number, speed: number}}  speed in units per second
 */
export function viewScale(size) {
  const s = Number.isFinite(size) && size > 0 ? size : 10;
  const near = Math.max(1e-6, s / 2000);
  return { near, far: s * 20 + 10 * near, speed: Math.max(1e-5, s / 8) };
}

/**
 * @param {import('three').Object3D|null} root  the scene (null: only bounds are known)
 * @param {number[][]} [bounds]  [[minx, miny, minz], [maxx, maxy, maxz]] when known
 * @returns {{position: number[], target: number[], inside: boolean}}
 */
export function autoCamera(root, bounds) {
  const box = bounds ? new Box3(new Vector3(...bounds[0]), new Vector3(...bounds[1]))
    : root ? new Box3().setFromObject(root) : new Box3(new Vector3(-1, -1, -1), new Vector3(1, 1, 1));
  if (!root || triangleCount(root) > MAX_TRIANGLES) return outsideView(box);
  root.updateMatrixWorld(true);
  const meshes = [];
  root.traverse((o) => { if (o.isMesh) meshes.push(o); });
  const ray = new Raycaster();
  const size = box.getSize(new Vector3());
  const dirs = [];
  for (let a = 0; a < 8; a++) dirs.push(new Vector3(Math.cos((a * Math.PI) / 4), 0, Math.sin((a * Math.PI) / 4)));
  dirs.push(new Vector3(0, 1, 0), new Vector3(0, -1, 0));
  let best = null;
  let open = 0, enclosed = 0;
  const steps = [0.2, 0.35, 0.5, 0.65, 0.8];
  for (const fx of steps) for (const fz of steps) for (const fy of [0.45, 0.6]) {
    const p = new Vector3(box.min.x + fx * size.x, box.min.y + fy * size.y, box.min.z + fz * size.z);
    let front = 0, back = 0, miss = 0, bestDir = null, bestDist = 0;
    for (const d of dirs) {
      ray.set(p, d);
      const hit = ray.intersectObjects(meshes, false)[0];
      if (!hit) { miss++; continue; }
      const n = hit.face ? hit.face.normal.clone().transformDirection(hit.object.matrixWorld) : null;
      if (n && n.dot(d) < 0) front++; else back++;
      if (d.y === 0 && hit.distance > bestDist) { bestDist = hit.distance; bestDir = d; }
    }
    if (back) continue;  // inside a solid
    if (miss) { open++; continue; }  // sees out of the scene
    enclosed++;
    const score = bestDist;
    if (!best || score > best.score) best = { score, p, dir: bestDir };
  }
  // mostly open space (a yard, a box on a floor, a Cornell box's open side): look from outside; only
  // scenes that are mostly rooms get the inside view
  if (!best || !best.dir || open >= enclosed) return outsideView(box);
  // step back from the far wall: stand near one end of the free line and look along it
  const back = best.dir.clone().multiplyScalar(-1);
  ray.set(best.p, back);
  const behind = ray.intersectObjects(meshes, false)[0];
  const retreat = behind ? Math.max(0, behind.distance - 0.25 * Math.min(size.x, size.z) * 0.2) * 0.8 : 0;
  const pos = best.p.clone().addScaledVector(back, retreat);
  const target = best.p.clone().addScaledVector(best.dir, best.score * 0.5);
  target.y -= 0.15 * size.y;  // look slightly down: floors catch most of the light
  return { position: pos.toArray(), target: target.toArray(), inside: true };
}
