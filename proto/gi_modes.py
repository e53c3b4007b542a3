"""The runtime GI modes and shared constants, read from ``proto/gi_modes.json`` (one source with the viewer).

``gi_modes.json`` says, per GI mode, the ``proto/glsl`` file of its ``@mode`` slot, the artifacts it needs, its
textures (sampler uniform → artifact names and upload kind), its other uniforms and its ``#define``\\ s, and holds
the constants both renderers use (DDGI-P eq 2's B default and 0.75, the mask lookup offset, texture limits). The
viewer imports the same file (``web/src/state/modes.js``); ``workers/render/shading.py`` binds through
:func:`texture_bindings` and tests check both sides set exactly the uniforms and defines listed here.

Pure: the file is read once at import; no other I/O.
"""
from __future__ import annotations

import json
import re
from collections.abc import Collection, Mapping
from pathlib import Path

__all__ = ["SPEC", "MODES", "MODE_IDS", "KINDS", "GRID_UNIFORMS", "SELF_SHADOW_BIAS", "BIAS_SPACING_FRACTION",
           "MASK_OFFSET_SAMPLES", "MASK_SEEN_THRESHOLD", "MASK_BLEND", "MAX_LIGHTS", "PRT_MAX_GROUPS", "MAX_3D_TEXTURE_DEPTH", "MAX_TEXTURE_SIZE",
           "cluster_count", "expand", "has_l2", "texture_bindings", "mode_defines", "self_shadow_bias"]

SPEC: dict = json.loads((Path(__file__).resolve().parent / "gi_modes.json").read_text(encoding="utf-8"))
MODES: dict[str, dict] = {m["id"]: m for m in SPEC["modes"]}
MODE_IDS: tuple[str, ...] = tuple(MODES)
KINDS: dict[str, dict] = SPEC["kinds"]
GRID_UNIFORMS: tuple[str, ...] = tuple(SPEC["grid_uniforms"])
_C = {k: v["value"] for k, v in SPEC["constants"].items()}

SELF_SHADOW_BIAS: float = float(_C["self_shadow_bias"])
"""B of DDGI-P eq 2 where a bake does not give ``light.self_shadow_bias`` (dimensionless)."""
BIAS_SPACING_FRACTION: float = float(_C["bias_spacing_fraction"])
"""The 0.75 of DDGI-P eq 2: the bias is 0.75·D·B metres, D the smallest probe spacing."""
MASK_OFFSET_SAMPLES: float = float(_C["mask_offset_samples"])
"""uMaskOffset: refined samples (per axis) the mask lookup moves along n + v."""
MASK_SEEN_THRESHOLD: float = float(_C["mask_seen_threshold"])
"""uMaskSeen: a cluster's mask at the point from which it counts as seen there (the lookup's both-sides blend)."""
MASK_BLEND: tuple[float, float] = tuple(float(x) for x in _C["mask_blend"])
"""uMaskBlend: shares of the offset read's clusters seen at the point between which the lookup goes from the point's
read to the offset read."""
MAX_LIGHTS: int = int(_C["max_lights"])
"""Lights a shading pass takes (lights.glsl)."""
PRT_MAX_GROUPS: int = int(_C["prt_max_groups"])
"""Groups of 4 PRT basis slots (mode_prt.glsl KILN_PRT_MAX_GROUPS)."""
MAX_3D_TEXTURE_DEPTH: int = int(_C["max_3d_texture_depth"])
"""Deepest stacked 3D texture built for L2 cluster volumes without a device at hand (texels)."""
MAX_TEXTURE_SIZE: int = int(_C["max_texture_size"])
"""Widest 2D texture uploaded as stored without a device at hand (texels): wider DDGI atlases are re-packed."""

_PLACEHOLDER = re.compile(r"\{([kcq])\}")


def cluster_count(names: Collection[str]) -> int:
    """K: the number of ``cluster_sh_{k}_r`` for k = 0, 1, ... among the artifact ``names``."""
    K = 0
    while f"cluster_sh_{K}_r" in names:
        K += 1
    return K


def expand(pattern: str, K: int) -> list[str]:
    """Artifact names of a ``gi_modes.json`` pattern: ``{k}`` over clusters 0..K-1, ``{c}`` over r, g, b, ``{q}``
    over the groups of 4 clusters (ceil(K/4) of '0123', '4567'); the first placeholder varies slowest."""
    values = {"k": [str(k) for k in range(K)], "c": SPEC["patterns"]["channels"],
              "q": SPEC["patterns"]["cluster_groups"][:-(-K // 4)]}
    out = [pattern]
    for key in _PLACEHOLDER.findall(pattern):
        out = [n.replace("{" + key + "}", v, 1) for n in out for v in values[key]]
    return out


def has_l2(mode: str, names: Collection[str]) -> bool:
    """Whether the bake's artifact ``names`` hold every L2 volume ``mode`` reads (its ``l2_needs``; the mask modes:
    ``cluster_sh_l2_{k}`` for each of K ≥ 1 clusters)."""
    need = MODES[mode].get("l2_needs")
    if not need:
        return False
    K = cluster_count(names)
    if any("{" in p for p in need) and K < 1:
        return False
    return all(n in names for p in need for n in expand(p, K))


def texture_bindings(mode: str, names: Collection[str], sh_order: int,
                     prt_basis: list | None = None) -> dict[str, tuple[list[str], str]]:
    """``{sampler uniform: (artifact names, kind)}`` that ``mode`` binds for a bake with artifact ``names`` shaded at
    ``sh_order`` (1 or 2). ``prt_basis``: the ``prt`` section's ``sh.basis`` ([coefficient][group] names), for prt
    (all 9 coefficients at order 2, else the first 4). ``KINDS[kind]`` says how to upload (dims, filter)."""
    K = cluster_count(names)
    out = {}
    for t in MODES[mode]["textures"]:
        if t.get("sh_order", sh_order) != sh_order or K < t.get("min_clusters", 0):
            continue
        if t["artifacts"] == ["prt.sh.basis"]:
            if prt_basis is None:
                raise ValueError("the prt mode's textures need the prt section's sh.basis")
            arts = [n for row in prt_basis[:9 if sh_order == 2 else 4] for n in row]
        else:
            arts = [n for p in t["artifacts"] for n in expand(p, K)]
        out[t["uniform"]] = (arts, t["kind"])
    return out


def mode_defines(mode: str, sh_order: int, clusters: int = 0) -> dict[str, int]:
    """The ``#define``\\ s of ``mode``'s shader: ``KILN_SH_L2`` = 1 at SH order 2, ``KILN_MASK_CLUSTERS`` = K."""
    out = {}
    for name, rule in MODES[mode]["defines"].items():
        if rule == "sh_order == 2":
            if sh_order == 2:
                out[name] = 1
        elif rule == "K":
            out[name] = int(clusters)
        else:
            raise ValueError(f"gi_modes.json: unknown define rule {rule!r}")
    return out


def self_shadow_bias(config: Mapping | None) -> float:
    """B of DDGI-P eq 2 for a bake: its config's ``light.self_shadow_bias`` (a ``BakeConfig`` dump or a manifest's
    ``config``), else :data:`SELF_SHADOW_BIAS`."""
    light = (config or {}).get("light") or {}
    value = light.get("self_shadow_bias")
    return SELF_SHADOW_BIAS if value is None else float(value)
