"""Stage ``ingest``: the scene as the bake sees it — the normalized scene plus the
config's lighting (DESIGN stage 0).

The upload itself was parsed and validated when it arrived (:mod:`workers.ingest`); this
stage resolves the lights every later stage uses: the glTF's KHR_lights_punctual lights
(unless ``scene.use_scene_lights`` is false) followed by the config's lights, and the sky.

Output ``lights`` (json): ``{"lights": [light dicts as in workers.scene], "sky": [r, g, b]}``.
"""
from __future__ import annotations

import numpy as np

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


def run_ingest(ctx: StageContext) -> StageOutput:
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
    return StageOutput(
        artifacts=[Artifact("lights", {"lights": lights, "sky": list(section.sky)}, format="json",
                            description="resolved lights (scene + config) and sky radiance")],
        stats=stats,
    )
