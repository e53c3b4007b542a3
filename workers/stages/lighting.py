"""Stage ``ingest`` (this module's name says what it does): the scene as the bake sees it — the normalized
scene plus the config's lighting (DESIGN stage 0).

The stage keeps its public name ``ingest``: stage names are in every stored manifest and stage record, in the
cache keys (:func:`proto.stages.plan`) and in what the web app and API clients look up. The upload itself was
parsed and validated when it arrived (:mod:`workers.gltf`); this stage resolves the lights every later stage
uses: the glTF's KHR_lights_punctual lights (unless ``scene.use_scene_lights`` is false) followed by the
config's lights, and the sky.

Output ``lights`` (json): ``{"lights": [light dicts as in workers.scene], "sky": [r, g, b]}``; ``scene``
(glb): the normalized scene with those lights as glTF binary (:mod:`workers.scene_glb`), so a bundle shows
its geometry without the original upload.
Warnings (``stats["warnings"]``): ``unlit_scene`` when no light, no emissive surface and a black sky leave
the bake black; ``light_outside_scene`` for a point/spot light far outside the scene bounds.
"""
from __future__ import annotations

import numpy as np

from workers.scene_glb import scene_to_glb
from workers.stages.base import Artifact, StageContext, StageError, StageOutput


def _config_light(light) -> dict:
    d = light.model_dump()
    if d["direction"] is not None:
        v = np.asarray(d["direction"], float)
        d["direction"] = (v / np.linalg.norm(v)).tolist()
    d["position"] = list(d["position"]) if d["position"] is not None else None
    d["color"] = list(d["color"])
    d["name"] = f"config:{light.type}"
    return d


LIGHT_BOUNDS_MARGIN = 0.1
"""A point or spot light farther outside the scene bounds than this fraction of their diagonal gets a
``light_outside_scene`` warning."""


def _fmt(v) -> str:
    return "(" + ", ".join(f"{float(c):.3g}" for c in v) + ")"


def _lighting_warnings(scene, section, lights: list[dict], n_emissive: int) -> list[dict]:
    """``unlit_scene`` when nothing lights the scene; ``light_outside_scene`` per point/spot light whose
    position lies outside the scene bounds expanded by :data:`LIGHT_BOUNDS_MARGIN` of the diagonal."""
    out = []
    if not lights and n_emissive == 0 and max(section.sky) == 0:
        n = len(scene.lights)
        dropped = (f" (the scene's {n} light{' is' if n == 1 else 's are'} dropped by scene.use_scene_lights = false)"
                   if n and not section.use_scene_lights else "")
        out.append({"code": "unlit_scene",
                    "message": "nothing lights the scene: no lights" + dropped + ", no emissive surface and "
                               "a black sky (scene.sky = [0, 0, 0]), so the bake is black; add [[scene.lights]] "
                               "or a sky"})
    lo, hi = scene.bounds
    margin = LIGHT_BOUNDS_MARGIN * float(np.linalg.norm(hi - lo))
    for i, light in enumerate(lights):
        if light.get("type") not in ("point", "spot") or light.get("position") is None:
            continue
        pos = np.asarray(light["position"], float)
        if np.all(pos >= lo - margin) and np.all(pos <= hi + margin):
            continue
        name = f" {light['name']!r}" if light.get("name") else ""
        out.append({"code": "light_outside_scene",
                    "message": f"{light['type']} light {i}{name} at {_fmt(pos)} lies outside the scene bounds "
                               f"{_fmt(lo)} .. {_fmt(hi)} (plus {LIGHT_BOUNDS_MARGIN:.0%} of their diagonal): "
                               "it probably lights little or nothing of the scene; check its position and units "
                               "(metres, glTF frame, +Y up)"})
    return out


def run_lighting(ctx: StageContext) -> StageOutput:
    """Run the ``ingest`` stage: resolve the lights and sky, warn about lighting, write the scene as GLB."""
    section = ctx.config.scene
    scene = ctx.scene
    ctx.report(0.1)
    if scene.n_triangles == 0:
        raise StageError("no_triangles", "the scene has no triangles")
    lights = [dict(l) for l in scene.lights] if section.use_scene_lights else []
    lights += [_config_light(l) for l in section.lights]
    emissive = np.array([np.max(m.get("emissive", [0, 0, 0])) > 0 or m.get("emissive_texture") is not None
                         for m in scene.materials], bool)
    n_emissive = int(emissive[scene.material].sum()) if len(emissive) else 0
    ctx.report(1.0)
    stats = {
        "triangles": scene.n_triangles,
        "materials": len(scene.materials),
        "textures": len(scene.textures),
        "lights": len(lights),
        "scene_lights": len(scene.lights),
        "emissive_triangles": n_emissive,
        "bounds": scene.bounds.round(6).tolist(),
        "sky": list(section.sky),
        "unlit": not lights and n_emissive == 0 and max(section.sky) == 0,
    }
    warnings = _lighting_warnings(scene, section, lights, n_emissive)
    if warnings:  # the contract of every stage: stats["warnings"] = [{"code", "message"}, ...]
        stats.setdefault("warnings", []).extend(warnings)
    glb = scene_to_glb(scene, lights)
    stats["scene_bytes"] = len(glb)
    return StageOutput(
        artifacts=[Artifact("lights", {"lights": lights, "sky": list(section.sky)}, format="json",
                            description="resolved lights (scene + config) and sky radiance"),
                   Artifact("scene", glb, format="glb",
                            description="the baked scene as glTF binary: normalized geometry, materials, "
                                        "textures, vertex colours and the resolved lights (KHR_lights_punctual)",
                            meta={"triangles": scene.n_triangles, "materials": len(scene.materials),
                                  "textures": len(scene.textures), "lights": len(lights)})],
        stats=stats,
    )
