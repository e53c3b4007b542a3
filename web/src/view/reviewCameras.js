/**
 * Review cameras in the viewer (pure; no three.js): the views every bake of a scene is scored from
 * (GET /v1/scenes/{id}/cameras: stored by PUT, the glTF's own, or the ones the evaluate stage placed in free space
 * looking at geometry) and the ones this bake's evaluate stage recorded (manifest `evaluate.cameras`: position,
 * target, fov). The viewer starts at the first and lists them all; "Save this view" appends a camera with PUT.
 * glTF coordinates (metres, +Y up), vertical field of view in degrees.
 */

export const MAX_REVIEW_CAMERAS = 16;  // server/api/schemas.py MAX_REVIEW_CAMERAS
const NAME_RE = /^[a-z0-9_-]{1,32}$/;  // proto.models.CameraSpec.name

const vec3 = (v) => Array.isArray(v) && v.length === 3 && v.every((x) => typeof x === 'number' && Number.isFinite(x));

/** A camera record of either source as {name, position, target, fov_y, source} (null when unusable). */
export function normalizeCamera(c, source = '') {
  if (!c || !vec3(c.position) || !vec3(c.target)) return null;
  const fov = Number(c.fov_y ?? c.fov);
  return {
    name: typeof c.name === 'string' && c.name ? c.name : '',
    position: [...c.position], target: [...c.target],
    fov_y: Number.isFinite(fov) && fov > 1 && fov < 179 ? fov : null,
    source,
  };
}

/** The review cameras this bake's evaluate stage used (its stats' `cameras`, as the manifest records them). */
export function bakeReviewCameras(bake) {
  const ev = (bake?.stages || []).find((s) => s.name === 'evaluate');
  const cams = ev?.stats?.cameras;
  return Array.isArray(cams) ? cams.map((c) => normalizeCamera(c, 'bake')).filter(Boolean) : [];
}

const near = (a, b, eps = 1e-4) => a.every((x, i) => Math.abs(x - b[i]) <= eps * Math.max(1, Math.abs(x)));

/** Same view: same position and target (names and sources differ between the scene's list and the bake's). */
export function sameView(a, b) {
  return near(a.position, b.position) && near(a.target, b.target);
}

/**
 * The camera list: the scene's review cameras (`doc` = GET /v1/scenes/{id}/cameras, may be null) first, then the
 * bake's own that are not among them. Unnamed cameras get `view-<i>`.
 */
export function mergeReviewCameras(doc, bakeCams = []) {
  const out = [];
  for (const c of doc?.cameras || []) {
    const n = normalizeCamera(c, doc.source || 'scene');
    if (n) out.push(n);
  }
  for (const c of bakeCams) if (!out.some((o) => sameView(o, c))) out.push(c);
  return out.map((c, i) => ({ ...c, name: c.name || `view-${i}` }));
}

/** A name for artifact names and the API's pattern: lower case, [a-z0-9_-], at most 32 characters. */
export function safeName(name, fallback = 'view') {
  const s = String(name || '').toLowerCase().replace(/[^a-z0-9_-]+/g, '-').slice(0, 32);
  return NAME_RE.test(s) ? s : fallback;
}

/** A name not taken by `cameras`: view-1, view-2, ... */
export function newCameraName(cameras) {
  const taken = new Set((cameras || []).map((c) => c.name));
  for (let i = 1; ; i++) if (!taken.has(`view-${i}`)) return `view-${i}`;
}

/** A camera as PUT /v1/scenes/{id}/cameras takes it (CameraSpec: no extra fields, fov_y in (1, 179) or left out). */
export function cameraSpec(c) {
  const out = { name: safeName(c.name), position: c.position.map(Number), target: c.target.map(Number) };
  const fov = Number(c.fov_y ?? c.fov);
  if (Number.isFinite(fov) && fov > 1 && fov < 179) out.fov_y = fov;
  return out;
}

/**
 * The body of the PUT that appends `view` to the scene's current review cameras (`doc`: GET's answer), or throws
 * when the scene already has MAX_REVIEW_CAMERAS. Names stay unique.
 */
export function appendCameraBody(doc, view) {
  const current = (doc?.cameras || []).map(normalizeCamera).filter(Boolean).map(cameraSpec);
  if (current.length >= MAX_REVIEW_CAMERAS) throw new Error(`the scene already has ${MAX_REVIEW_CAMERAS} review cameras (the most a scene keeps)`);
  const seen = new Set();
  for (const c of current) {  // names as the server would make them unique
    let n = c.name;
    for (let i = 2; seen.has(n); i++) n = `${c.name.slice(0, 28)}-${i}`;
    c.name = n;
    seen.add(n);
  }
  const spec = cameraSpec({ ...view, name: view.name || newCameraName(current) });
  if (seen.has(spec.name)) spec.name = newCameraName(current);
  return { cameras: [...current, spec] };
}
