"""``KHR_lights_punctual``: the file's point, spot and directional lights, placed by their nodes.

A light is a definition in the document's ``KHR_lights_punctual.lights`` referenced by a node of the default
scene; it takes that node's world transform: the position is the world translation, the direction the world
transform of the local -Z axis. Colours and intensities (candela for point and spot lights, lux for
directional ones) are kept as the file gives them, refused when negative or absurd
(:mod:`workers.gltf.limits`). Output dicts are :mod:`workers.scene`'s lights. Frames: glTF's (+Y up, metres).
Consumer: :mod:`workers.gltf.reader`. Inverse: :mod:`workers.scene_glb` (lights written back).

References
----------
.. [KHR_lights_punctual] Khronos glTF extension: point, spot and directional lights.
"""

from __future__ import annotations

import math

import numpy as np

from workers.gltf.document import Document, is_int, num, vec
from workers.gltf.errors import invalid
from workers.gltf.limits import check_light_place, check_light_values
from workers.gltf.nodes import normalize_rows

__all__ = ["build_lights"]


def build_lights(doc: Document, order: list[int], world: list[np.ndarray]) -> list[dict]:
    """KHR_lights_punctual lights of the scene's nodes, world space ([KHR_lights_punctual]).

    ``position`` is the node's world translation (None for directional lights); ``direction`` is
    the world transform applied to the local -Z axis, normalized (None for point lights).
    """
    ext = doc.exts(doc.g).get("KHR_lights_punctual")
    defs = ext.get("lights", []) if isinstance(ext, dict) else []
    if not isinstance(defs, list):
        raise invalid("KHR_lights_punctual.lights must be an array")
    nodes = doc.array("nodes")
    lights = []
    for ni in order:
        ref = doc.exts(nodes[ni]).get("KHR_lights_punctual")
        if not isinstance(ref, dict):
            continue
        li = ref.get("light")
        if not is_int(li) or not 0 <= li < len(defs) or not isinstance(defs[li], dict):
            raise invalid(f"nodes[{ni}] refers to KHR_lights_punctual light {li!r}, which does not exist")
        d = defs[li]
        what = f"KHR_lights_punctual.lights[{li}]"
        kind = d.get("type")
        if kind not in ("point", "spot", "directional"):
            raise invalid(f"{what} has unknown type {kind!r}")
        color = vec(d.get("color"), 3, [1, 1, 1], f"{what}.color")
        intensity = num(d.get("intensity"), 1.0, f"{what}.intensity")
        rng = d.get("range")
        rng = None if rng is None else num(rng, None, f"{what}.range")
        check_light_values(intensity, color, what)
        if rng is not None and rng <= 0:
            raise invalid(f"{what} needs range > 0")
        inner = outer = None
        if kind == "spot":
            spot = d.get("spot", {})
            if not isinstance(spot, dict):
                raise invalid(f"{what}.spot must be an object")
            inner = num(spot.get("innerConeAngle"), 0.0, f"{what}.spot.innerConeAngle")
            outer = num(spot.get("outerConeAngle"), math.pi / 4, f"{what}.spot.outerConeAngle")
            if not 0 <= inner <= outer <= math.pi / 2 + 1e-6:
                raise invalid(f"{what} needs 0 <= innerConeAngle <= outerConeAngle <= pi/2")
        m = world[ni]
        position = None if kind == "directional" else [float(x) for x in m[:3, 3]]
        direction = None
        if kind != "point":
            dv, ok = normalize_rows(m[:3, :3] @ np.array([0.0, 0.0, -1.0]))
            if not ok:
                raise invalid(f"nodes[{ni}] scales its {kind} light's direction to zero")
            direction = [float(x) for x in dv]
        check_light_place(position, direction, ni, li)
        name = d.get("name") if isinstance(d.get("name"), str) else nodes[ni].get("name")
        lights.append(
            {
                "name": name if isinstance(name, str) else f"light_{li}",
                "type": kind,
                "color": color,
                "intensity": intensity,
                "range": rng,
                "position": position,
                "direction": direction,
                "inner_cone_angle": inner,
                "outer_cone_angle": outer,
            }
        )
    return lights
