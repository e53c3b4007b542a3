"""Cameras for the evaluate stage: given or auto-placed inside the scene (DESIGN stage 7).

Frames and conventions
----------------------
- World space is glTF's: metres, +Y up, right-handed.
- A camera looks from ``position`` toward ``target``; its own frame is OpenGL's: it looks along its
  -Z axis, +X to the right of the image, +Y up in the image.
- ``view_matrix()`` maps world to camera coordinates, ``projection_matrix()`` camera to clip
  coordinates (OpenGL, NDC z in [-1, 1], vertical field of view ``fov_y`` in degrees, aspect
  ``width / height``). Both are (4, 4) float64 acting on column vectors (``clip = P @ V @ [x, 1]``);
  upload ``M.T`` (column-major) to GLSL.
- Images are (H, W, C) with row 0 at the *top*; pixel (row i, column j) is centred at
  NDC ``x = 2 (j + 0.5) / W - 1``, ``y = 1 - 2 (i + 0.5) / H`` — the sample position of OpenGL
  rasterization, so :meth:`Camera.pixel_rays` hits what the rasterizer shows in that pixel.

Auto placement (:func:`auto_cameras`)
-------------------------------------
Candidates are the given points (e.g. relocated ACTIVE probe positions) or a regular grid inside
the bounds. A candidate is kept when it is in free space, judged by 64 rays on a fixed spherical
Fibonacci set: at most ``max_backface`` of the rays hit a back face (a point inside a closed solid,
or behind single-sided walls, sees back faces — the per-ray test of DDGI-P §6.1), at least
``min_hits`` of them hit anything, and no hit is closer than ``clearance`` × the bounds diagonal.
Its *centrality* ``min(1, t_min / (0.25 · t_90))`` (t_90: the 90th percentile of its hit distances,
the size of the space it sees) favours the middle of a room over a corner, and its *enclosure*
(the squared fraction of its rays that hit anything) favours rooms over the open sky above a level.
For each kept candidate, view directions on a Fibonacci set (pitch within ±45°) are scored with a
coarse 12 x 9 frustum of rays::

    view = coverage · (0.25 + min(1, std(log t))) · min(1, median t / (0.5 · t_90)) · min(1, surfaces / 3)

— front-face coverage, a spread of depths, not a wall at the lens, and several surface orientations
(``surfaces``: normal-direction bins holding ≥ 5% of the hits). A candidate scores its best view ×
centrality × enclosure. Cameras are then picked greedily: the best score first, then the best score times a
diversity factor (distance to the chosen positions and angle to the chosen view directions).
Everything is deterministic (fixed ray sets, ties to the lowest index). The target is the point at
the median depth of the central rays; near/far come from the frustum's hit distances.

Review cameras (:func:`review_cameras`): the bake's own, else the glTF's, else auto-placed, else a default.

Consumers: workers/render/gbuffer.py, the reference and evaluate stages, the reference path tracer
(:mod:`workers.kernels.pathtrace`) through :meth:`Camera.pixel_rays`.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from workers.kernels.sampling import fibonacci_sphere

__all__ = ["Camera", "auto_cameras", "camera_basis", "camera_record", "default_camera", "fit_clip_planes", "look_at",
           "perspective", "review_cameras"]

DEFAULT_WIDTH = 512
DEFAULT_HEIGHT = 384
DEFAULT_FOV_Y = 60.0  # degrees


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n == 0:
        raise ValueError(f"cannot normalize {v}")
    return v / n


def camera_basis(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """(3, 3) float64 rows: right (+X), up (+Y), back (+Z) of a camera at ``position`` looking at ``target``.

    When the view direction is (nearly) parallel to ``up``, world -Z (or +X) stands in for ``up``.
    """
    f = _unit(np.asarray(target, np.float64) - np.asarray(position, np.float64))  # forward = -Z
    u = _unit(up)
    if abs(float(f @ u)) > 0.999:
        u = np.array([0.0, 0.0, -1.0]) if abs(f[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    r = _unit(np.cross(f, u))
    u2 = np.cross(r, f)
    return np.stack([r, u2, -f])


def look_at(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Right-handed view matrix (world -> camera, camera looks along -Z), (4, 4) float64."""
    basis = camera_basis(position, target, up)
    m = np.eye(4)
    m[:3, :3] = basis
    m[:3, 3] = -basis @ np.asarray(position, np.float64)
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL perspective projection (gluPerspective): camera -> clip, NDC z in [-1, 1], (4, 4) float64."""
    if not (0 < fov_y_deg < 180):
        raise ValueError(f"perspective: fov_y must be in (0, 180) degrees, got {fov_y_deg}")
    if not (0 < near < far) or not math.isfinite(far):
        raise ValueError(f"perspective: need 0 < near < far < inf, got near={near}, far={far}")
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    position, target : (3,) metres, world space. fov_y : vertical field of view, degrees.
    width, height : image size in pixels. up : world up hint. near, far : clip distances in metres
    (``None``: set by :func:`fit_clip_planes` or the renderer from the scene bounds). name : a label.
    """

    position: tuple
    target: tuple
    fov_y: float = DEFAULT_FOV_Y
    width: int = DEFAULT_WIDTH
    height: int = DEFAULT_HEIGHT
    up: tuple = (0.0, 1.0, 0.0)
    near: float | None = None
    far: float | None = None
    name: str = ""
    score: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        p = tuple(float(x) for x in self.position)
        t = tuple(float(x) for x in self.target)
        if len(p) != 3 or len(t) != 3 or not all(map(math.isfinite, p + t)):
            raise ValueError(f"Camera: position and target must be finite 3-vectors, got {self.position}, {self.target}")
        if p == t:
            raise ValueError("Camera: position and target coincide")
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"Camera: width and height must be >= 1, got {self.width}x{self.height}")
        if not (0 < float(self.fov_y) < 180):
            raise ValueError(f"Camera: fov_y must be in (0, 180) degrees, got {self.fov_y}")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "target", t)
        object.__setattr__(self, "up", tuple(float(x) for x in self.up))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "fov_y", float(self.fov_y))

    # ------------------------------------------------------------------ matrices
    @property
    def aspect(self) -> float:
        return self.width / self.height

    @property
    def forward(self) -> np.ndarray:
        return _unit(np.subtract(self.target, self.position))

    def basis(self) -> np.ndarray:
        """(3, 3) rows right, up, back (world space)."""
        return camera_basis(self.position, self.target, self.up)

    def view_matrix(self) -> np.ndarray:
        return look_at(self.position, self.target, self.up)

    def projection_matrix(self, near: float | None = None, far: float | None = None) -> np.ndarray:
        near = self.near if near is None else near
        far = self.far if far is None else far
        if near is None or far is None:
            raise ValueError("Camera.projection_matrix: near/far unset (use fit_clip_planes or pass them)")
        return perspective(self.fov_y, self.aspect, near, far)

    def view_projection(self, near: float | None = None, far: float | None = None) -> np.ndarray:
        return self.projection_matrix(near, far) @ self.view_matrix()

    # ------------------------------------------------------------------ rays
    def pixel_directions(self, rows=None, cols=None) -> np.ndarray:
        """Unit world-space directions through pixel centres.

        With no arguments: (H·W, 3) float64 in row-major image order (row 0 = top). With ``rows``
        and ``cols`` (continuous pixel coordinates, centres at ``index + 0.5``): one ray each.
        """
        if rows is None:
            jj, ii = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
            rows, cols = ii.ravel(), jj.ravel()
        rows = np.asarray(rows, np.float64)
        cols = np.asarray(cols, np.float64)
        t = math.tan(math.radians(self.fov_y) / 2)
        x = (2 * cols / self.width - 1) * t * self.aspect
        y = (1 - 2 * rows / self.height) * t
        local = np.stack([x, y, -np.ones_like(x)], axis=-1)
        d = local @ self.basis()  # rows of the basis are the camera axes in world space
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(origins, dirs): (H·W, 3) float64 rays through every pixel centre, row-major, row 0 = top."""
        d = self.pixel_directions()
        return np.broadcast_to(np.asarray(self.position, np.float64), d.shape).copy(), d

    # ------------------------------------------------------------------ (de)serialization
    def to_dict(self) -> dict:
        return {"name": self.name, "position": list(self.position), "target": list(self.target),
                "fov_y": self.fov_y, "width": self.width, "height": self.height, "up": list(self.up),
                "near": self.near, "far": self.far, "score": dict(self.score)}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        keys = ("position", "target", "fov_y", "width", "height", "up", "near", "far", "name", "score")
        return cls(**{k: d[k] for k in keys if k in d and d[k] is not None})


# --------------------------------------------------------------------------------- clip planes
def fit_clip_planes(camera: Camera, caster=None, bounds=None, samples: int = 32) -> Camera:
    """The camera with near/far set from the scene.

    far: 1.01 × the distance to the farthest corner of ``bounds`` (or 1.5 × the farthest hit of a
    ``samples`` × ``samples`` grid of frustum rays). near: half the closest hit of that grid, at
    least ``1e-4 ×`` far (a 24-bit depth buffer then resolves about ``6e-5 × z² / near`` at
    depth z); without a caster, ``1e-3 ×`` far.
    """
    pos = np.asarray(camera.position, np.float64)
    far = None
    if bounds is not None:
        b = np.asarray(bounds, np.float64)
        corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        far = 1.01 * float(np.linalg.norm(corners - pos, axis=1).max())
    near = None
    if caster is not None:
        n = int(samples)
        jj, ii = np.meshgrid((np.arange(n) + 0.5) / n * camera.width, (np.arange(n) + 0.5) / n * camera.height)
        d = camera.pixel_directions(ii.ravel(), jj.ravel())
        h = caster.intersect(np.broadcast_to(pos, d.shape), d)
        if h.hit.any():
            t = h.t[h.hit].astype(np.float64)
            far = max(far or 0.0, 1.5 * float(t.max()))
            near = 0.5 * float(t.min())
    if far is None or far <= 0:
        far = 1000.0
    near = max(near if near is not None else 1e-3 * far, 1e-4 * far)
    return replace(camera, near=near, far=far)


# --------------------------------------------------------------------------------- auto placement
def _fixed_rotation() -> np.ndarray:
    # a generic fixed rotation so that the probe-ray set has no direction along the axes
    w, x, y, z = np.array([0.9239, 0.2209, -0.1768, 0.2652]) / np.linalg.norm([0.9239, 0.2209, -0.1768, 0.2652])
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _grid_candidates(bounds: np.ndarray, per_axis: int) -> np.ndarray:
    lo, hi = bounds
    axes = [lo[a] + (np.arange(per_axis) + 0.5) / per_axis * (hi[a] - lo[a]) for a in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return g


def _normal_bins(normals: np.ndarray) -> np.ndarray:
    """Quantize unit normals to at most 26 direction bins (each component to -1, 0, 1 at ±0.5)."""
    q = np.where(normals > 0.5, 2, np.where(normals < -0.5, 0, 1))
    return q[..., 0] * 9 + q[..., 1] * 3 + q[..., 2]


def auto_cameras(caster, bounds, count: int = 3, *, candidates=None, per_axis: int = 6, width: int = DEFAULT_WIDTH,
                 height: int = DEFAULT_HEIGHT, fov_y: float = DEFAULT_FOV_Y, max_backface: float = 0.1,
                 min_hits: float = 0.3, clearance: float = 0.005, probe_rays: int = 64, view_dirs: int = 48,
                 max_pitch_deg: float = 45.0) -> list[Camera]:
    """Up to ``count`` cameras in free space inside ``bounds`` looking at geometry (see the module doc).

    Parameters
    ----------
    caster : workers.raycast.RayCaster
        The scene's ray caster (its ``triangles`` give the hit normals).
    bounds : (2, 3) array_like
        Min and max corners (metres): the scene bounds or the bake box.
    candidates : (N, 3) array_like, optional
        Candidate positions (e.g. relocated ACTIVE probes); default a ``per_axis``³ grid in ``bounds``.
    clearance : float
        Minimum distance to any geometry, as a fraction of the bounds diagonal.

    Returns
    -------
    list of Camera, best first, each with near/far set and ``score`` = {"coverage", "depth_spread",
    "median_depth", "surfaces", "centrality", "enclosure", "score"}. Empty when no candidate is in free space looking
    at geometry (an open scene like the furnace): use :func:`default_camera` then.
    """
    b = np.asarray(bounds, np.float64)
    if b.shape != (2, 3) or not np.all(np.isfinite(b)) or np.any(b[1] < b[0]):
        raise ValueError(f"auto_cameras: bounds must be finite (2, 3) min/max corners, got {b}")
    diag = float(np.linalg.norm(b[1] - b[0])) or 1.0
    cand = _grid_candidates(b, int(per_axis)) if candidates is None else np.asarray(candidates, np.float64).reshape(-1, 3)
    if cand.size == 0 or count < 1:
        return []
    tri = np.asarray(caster.triangles, np.float64)
    tri_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) if len(tri) else np.zeros((1, 3))
    tri_n /= np.maximum(np.linalg.norm(tri_n, axis=1, keepdims=True), 1e-300)

    # 1. free space: few back faces, some geometry, nothing too close
    dirs = fibonacci_sphere(int(probe_rays)).astype(np.float64) @ _fixed_rotation().T
    o = np.repeat(cand, len(dirs), axis=0)
    d = np.tile(dirs, (len(cand), 1))
    h = caster.intersect(o, d)
    hit = h.hit.reshape(len(cand), -1)
    back = h.backface.reshape(len(cand), -1)
    t = np.where(hit, h.t.reshape(len(cand), -1), np.inf)
    keep = ((back.mean(axis=1) <= max_backface) & (hit.mean(axis=1) >= min_hits)
            & (t.min(axis=1) >= clearance * diag))
    cand, t, hit = cand[keep], t[keep], hit[keep]
    if len(cand) == 0:
        return []
    # centrality: the nearest surface is not much closer than the typical one (the middle of a room)
    far_free = np.array([np.percentile(tt[hh], 90) for tt, hh in zip(t, hit)])
    centrality = np.minimum(1.0, t.min(axis=1) / (0.25 * far_free))
    enclosure = hit.mean(axis=1) ** 2   # inside rooms rather than above the roofs of an open level

    # 2. best view direction per candidate, by a coarse frustum of rays
    vd = fibonacci_sphere(int(view_dirs)).astype(np.float64) @ _fixed_rotation().T
    vd = vd[np.abs(vd[:, 1]) <= math.sin(math.radians(max_pitch_deg))]
    gw, gh = 12, 9
    jj, ii = np.meshgrid((np.arange(gw) + 0.5) / gw * width, (np.arange(gh) + 0.5) / gh * height)
    centre = (np.abs(ii - height / 2) <= height / 4) & (np.abs(jj - width / 2) <= width / 4)
    # the pixel directions of a view direction do not depend on the camera's position: one set for all candidates
    rd = np.concatenate([Camera(np.zeros(3), v, fov_y=fov_y, width=width, height=height)
                         .pixel_directions(ii.ravel(), jj.ravel()) for v in vd])            # (K·108, 3)
    K, n_px = len(vd), gw * gh
    hh = caster.intersect(np.repeat(cand, len(rd), axis=0), np.tile(rd, (len(cand), 1)))
    front_all = (hh.hit & ~hh.backface).reshape(len(cand), K, n_px)
    t_all = hh.t.reshape(len(cand), K, n_px).astype(np.float64)
    bins_all = _normal_bins(tri_n[np.where(hh.hit, hh.tri, 0)]).reshape(len(cand), K, n_px)
    rows = np.repeat(np.arange(K), n_px).reshape(K, n_px)
    best = []
    for ci in range(len(cand)):
        f, tt = front_all[ci], t_all[ci]
        nf = f.sum(axis=1)
        cov = f.mean(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)                 # all-NaN rows: views with no front hit
            spread = np.nanstd(np.where(f, np.log(np.where(f, tt, 1.0)), np.nan), axis=1)
            med = np.nanmedian(np.where(f, tt, np.nan), axis=1)
            cm = f & centre.ravel()[None]
            target_t = np.where(cm.any(axis=1), np.nanmedian(np.where(cm, tt, np.nan), axis=1), med)
        counts = np.zeros((K, 27), np.int64)
        np.add.at(counts, (rows[f], bins_all[ci][f]), 1)
        surfaces = (counts >= 0.05 * nf[:, None]).sum(axis=1)
        ok = nf >= 4
        scores = np.where(ok, cov * (0.25 + np.minimum(1.0, np.nan_to_num(spread)))
                          * np.minimum(1.0, np.nan_to_num(med) / (0.5 * far_free[ci])) * np.minimum(1.0, surfaces / 3.0),
                          0.0)
        k = int(np.argmax(scores))
        meta = ((float(cov[k]), float(spread[k]), float(med[k]), float(target_t[k]), int(surfaces[k])) if ok[k]
                else (float(cov[k]), 0.0, 0.0, math.inf, 0))
        best.append((scores[k] * centrality[ci] * enclosure[ci], vd[k], meta))

    # 3. greedy diverse pick
    score = np.array([s for s, _, _ in best])
    order_ok = score > 0
    chosen: list[int] = []
    while len(chosen) < count and order_ok.any():
        if chosen:
            pos = cand[chosen]
            vdir = np.array([best[c][1] for c in chosen])
            dist = np.linalg.norm(cand[:, None, :] - pos[None], axis=-1) / diag  # (N, C)
            ang = 1.0 - np.array([b_[1] for b_ in best]) @ vdir.T               # (N, C) in [0, 2]
            div = np.min(dist + 0.25 * ang, axis=1)
            total = score * np.minimum(1.0, div / 0.25)
            total[chosen] = -1
            total[~order_ok] = -1
        else:
            total = np.where(order_ok, score, -1)
        c = int(np.argmax(total))
        if total[c] <= 0:
            break
        chosen.append(c)

    out = []
    for n_, c in enumerate(chosen):
        s, v, (cov, spread, med, target_t, surfaces) = best[c]
        p = cand[c]
        if not math.isfinite(target_t):
            target_t = 1.0
        cam = Camera(p, p + v * target_t, fov_y=fov_y, width=width, height=height, name=f"auto-{n_}",
                     score={"coverage": cov, "depth_spread": spread, "median_depth": med, "surfaces": surfaces,
                            "centrality": float(centrality[c]), "enclosure": float(enclosure[c]), "score": float(s)})
        out.append(fit_clip_planes(cam, caster, b))
    return out


def default_camera(bounds, *, width: int = DEFAULT_WIDTH, height: int = DEFAULT_HEIGHT,
                   fov_y: float = DEFAULT_FOV_Y) -> Camera:
    """A camera outside ``bounds`` looking at their centre from +Z (and a little above): the fallback
    when :func:`auto_cameras` finds nothing (open scenes)."""
    b = np.asarray(bounds, np.float64)
    c = b.mean(axis=0)
    ext = b[1] - b[0]
    r = 0.5 * float(np.linalg.norm(ext)) or 1.0
    dist = r / math.tan(math.radians(fov_y) / 2) * 1.1
    pos = c + _unit([0.0, 0.35, 1.0]) * dist
    cam = Camera(pos, c, fov_y=fov_y, width=width, height=height, name="default")
    return replace(cam, near=max(1e-3 * (dist + r), dist - 1.5 * r), far=dist + 1.5 * r)


def review_cameras(config, scene, caster) -> tuple[list[Camera], str]:
    """The review cameras of a bake and where they come from: ``"config"``, ``"gltf"``, ``"auto"``, ``"default"``
    or ``"none"``; names are unique and safe for artifact names.

    ``config.evaluate.cameras`` when it is a list (the server puts the scene's stored review cameras there);
    else the glTF's own cameras (``scene.cameras``, at most 16); else ``evaluate.cameras`` cameras placed by
    :func:`auto_cameras` in free space inside the scene bounds; else :func:`default_camera` (an open scene).
    ``caster`` fits the clip planes and places the automatic cameras.
    """
    ev = config.evaluate
    kw = dict(width=int(ev.width), height=int(ev.height))
    box = np.asarray(scene.bounds, np.float64)
    specs, source = None, None
    if isinstance(ev.cameras, (list, tuple)):
        specs = [c.model_dump() if hasattr(c, "model_dump") else dict(c) for c in ev.cameras]
        source = "config"
    elif getattr(scene, "cameras", None) and int(ev.cameras) > 0:
        specs, source = [dict(c) for c in scene.cameras][:16], "gltf"
    if specs is not None:
        out, taken = [], set()
        for i, d in enumerate(specs):
            name = d.get("name") or f"cam-{i}"
            while name in taken:
                name = f"{name[:28]}-{i}"
            taken.add(name)
            cam = Camera(d["position"], d["target"], fov_y=d.get("fov_y") or float(ev.fov_y), name=name, **kw)
            out.append(fit_clip_planes(cam, caster, box))
        return out, source
    n = int(ev.cameras)
    if n <= 0:
        return [], "none"
    cams = auto_cameras(caster, box, n, fov_y=float(ev.fov_y), **kw)
    if cams:
        return cams, "auto"
    return [default_camera(box, fov_y=float(ev.fov_y), **kw)], "default"


def camera_record(cam: Camera) -> dict:
    """What the manifest records of a review camera (the ``evaluate`` stats' ``cameras``): name, position,
    target (world space, metres), vertical fov (degrees), width, height (pixels)."""
    return {"name": cam.name, "position": [float(x) for x in cam.position], "target": [float(x) for x in cam.target],
            "fov": float(cam.fov_y), "width": cam.width, "height": cam.height}
