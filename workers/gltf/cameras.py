"""The glTF's own cameras, read at ingest: the evaluate stage's review cameras when a scene has any.

glTF 2.0 §3.10: a camera looks along its node's local -Z with +Y up; ``perspective.yfov`` is the vertical field
of view in radians. Each perspective camera referenced by a node of the default scene becomes, in world space
(the node's world matrix applied, as for lights),
``{"name", "position": [x, y, z], "target": position + 1 m along the view direction, "fov_y": degrees}``.

Lenient by design (the upload is validated elsewhere; a camera only chooses viewpoints): orthographic cameras,
non-finite or degenerate transforms and out-of-range fields are skipped, never an ingest error. At most
:data:`MAX_CAMERAS`, in node order. Names are made safe for artifact names (``[a-z0-9_-]``, at most 24
characters, unique; ``gltf-<i>`` when nothing is left). Positions past
:data:`workers.gltf.limits.MAX_COORD` are skipped. Consumer: :mod:`workers.gltf.reader` (``NormalizedScene.cameras``),
the evaluate stage. Inverse: :mod:`workers.scene_glb` writes no cameras.
"""
from __future__ import annotations

import math
import re

import numpy as np

from workers.gltf.limits import MAX_COORD

__all__ = ["build_cameras", "safe_camera_name", "MAX_CAMERAS"]

MAX_CAMERAS = 16


def safe_camera_name(name, index: int, taken: set[str]) -> str:
    """A name usable in artifact names (``eval_<camera>_<mode>``): lower case ``[a-z0-9_-]``, ≤ 24 characters,
    unique within ``taken`` (which it is added to)."""
    base = re.sub(r"[^a-z0-9_-]+", "-", str(name or "").lower()).strip("-_")[:24] or f"gltf-{index}"
    out, k = base, 1
    while out in taken:
        k += 1
        out = f"{base[:20]}-{k}"
    taken.add(out)
    return out


def build_cameras(gltf: dict, order: list[int], world: list[np.ndarray]) -> list[dict]:
    """Perspective cameras of the nodes ``order`` (the default scene's, depth first) with world matrices
    ``world`` (per node, (4, 4)). See the module doc."""
    defs = gltf.get("cameras") if isinstance(gltf, dict) else None
    nodes = gltf.get("nodes") if isinstance(gltf, dict) else None
    if not isinstance(defs, list) or not defs or not isinstance(nodes, list):
        return []
    out: list[dict] = []
    taken: set[str] = set()
    for ni in order:
        if len(out) >= MAX_CAMERAS:
            break
        try:
            node = nodes[ni]
            ci = node.get("camera") if isinstance(node, dict) else None
            if isinstance(ci, bool) or not isinstance(ci, int) or not 0 <= ci < len(defs):
                continue
            cam = defs[ci]
            if not isinstance(cam, dict) or cam.get("type") != "perspective":
                continue
            persp = cam.get("perspective")
            yfov = persp.get("yfov") if isinstance(persp, dict) else None
            if isinstance(yfov, bool) or not isinstance(yfov, (int, float)):
                continue
            fov = math.degrees(float(yfov))
            if not 1.0 < fov < 179.0:
                continue
            m = np.asarray(world[ni], np.float64)
            pos = m[:3, 3]
            fwd = m[:3, :3] @ np.array([0.0, 0.0, -1.0])
            n = float(np.linalg.norm(fwd))
            if not (np.all(np.isfinite(pos)) and math.isfinite(n) and n > 1e-12) or np.abs(pos).max() > MAX_COORD:
                continue
            fwd = fwd / n
            name = cam.get("name") if isinstance(cam.get("name"), str) else node.get("name")
            out.append({"name": safe_camera_name(name, len(out), taken), "position": [float(x) for x in pos],
                        "target": [float(x) for x in pos + fwd], "fov_y": round(fov, 6)})
        except (IndexError, TypeError, ValueError, AttributeError):
            continue
    return out
