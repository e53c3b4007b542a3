"""The shared GI mode table and runtime constants (proto/gi_modes.json through proto/gi_modes.py)."""
from __future__ import annotations

import re

import pytest

from proto import gi_modes as G
from proto.glsl_preprocess import load_sources
from proto.models import BakeConfig


def test_constants_are_the_contracts():
    assert G.MASK_OFFSET_SAMPLES == 1.0                     # one refined sample per axis along n + v
    assert G.SELF_SHADOW_BIAS == BakeConfig().light.self_shadow_bias == 0.3   # DDGI-P eq 2's B, the config default
    assert G.BIAS_SPACING_FRACTION == 0.75                  # DDGI-P eq 2's 0.75·D
    src = load_sources()
    assert re.search(rf"#define KILN_PRT_MAX_GROUPS {G.PRT_MAX_GROUPS}\b", src["mode_prt.glsl"])
    assert (G.MAX_LIGHTS, G.MAX_3D_TEXTURE_DEPTH, G.MAX_TEXTURE_SIZE) == (8, 2048, 16384)


def test_every_mode_has_its_shader_and_known_kinds():
    src = load_sources()
    assert G.MODE_IDS == ("direct", "leaking", "ddgi", "mask", "mask_normalized", "prt")
    for m in G.MODES.values():
        assert m["shader"] == f"mode_{m['id']}.glsl" and m["shader"] in src
        for t in m["textures"]:
            assert t["kind"] in G.KINDS
            assert re.search(rf"uniform\s+\w+\s+sampler[23]D\s+{t['uniform']};", "".join(src.values())), t
        for u in m["uniforms"]:
            assert re.search(rf"uniform\s+[\w\s]+\b{u}\b", "".join(src.values())), u


def test_expand_patterns():
    assert G.expand("cluster_sh_{k}_{c}", 2) == ["cluster_sh_0_r", "cluster_sh_0_g", "cluster_sh_0_b",
                                                  "cluster_sh_1_r", "cluster_sh_1_g", "cluster_sh_1_b"]
    assert G.expand("cluster_weights_{q}", 4) == ["cluster_weights_0123"]
    assert G.expand("cluster_weights_{q}", 5) == ["cluster_weights_0123", "cluster_weights_4567"]
    assert G.expand("sh_l2", 3) == ["sh_l2"]


def test_cluster_count_and_has_l2():
    l1 = ["sh_l1_r", "cluster_sh_0_r", "cluster_sh_1_r"]
    assert G.cluster_count(l1) == 2 and G.cluster_count([]) == 0
    assert not G.has_l2("leaking", l1) and G.has_l2("leaking", l1 + ["sh_l2"])
    assert not G.has_l2("mask", l1 + ["cluster_sh_l2_0"])
    assert G.has_l2("mask_normalized", l1 + ["cluster_sh_l2_0", "cluster_sh_l2_1"])
    assert not G.has_l2("mask", ["cluster_sh_l2_0"])           # no clusters: nothing to read
    assert not G.has_l2("ddgi", l1 + ["sh_l2"])


def test_texture_bindings():
    names = [f"cluster_sh_{k}_{c}" for k in range(5) for c in "rgb"] + [f"cluster_sh_l2_{k}" for k in range(5)]
    b = G.texture_bindings("mask_normalized", names, 2)
    assert list(b) == ["uMaskIndirection", "uMaskAtlas", "uClusterShL2", "uClusterWeights"]   # one atlas for any K
    assert b["uClusterShL2"] == ([f"cluster_sh_l2_{k}" for k in range(5)], "stack")
    assert b["uClusterWeights"] == (["cluster_weights_0123", "cluster_weights_4567"], "stack")
    b1 = G.texture_bindings("mask", names[:6], 1)           # K = 2: no weights in plain mask GI
    assert list(b1) == ["uMaskIndirection", "uMaskAtlas", "uClusterSh"] and len(b1["uClusterSh"][0]) == 6
    assert G.texture_bindings("leaking", [], 1) == {u: ([f"sh_l1_{c}"], "volume") for u, c in
                                                     (("uShR", "r"), ("uShG", "g"), ("uShB", "b"))}
    assert G.texture_bindings("ddgi", [], 1)["uProbeData"] == (["probe_positions_relocated", "probe_states"],
                                                              "probe-data")
    basis = [[f"prt_sh_basis_c{k}_g{g}" for g in range(2)] for k in range(9)]
    assert G.texture_bindings("prt", [], 2, basis)["uPrtBasis"][0] == [n for row in basis for n in row]
    assert G.texture_bindings("prt", [], 1, basis)["uPrtBasis"][0] == [n for row in basis[:4] for n in row]
    with pytest.raises(ValueError, match="sh.basis"):
        G.texture_bindings("prt", [], 1)


def test_mode_defines():
    assert G.mode_defines("leaking", 2) == {"KILN_SH_L2": 1} and G.mode_defines("leaking", 1) == {}
    assert G.mode_defines("mask", 1, 3) == {"KILN_MASK_CLUSTERS": 3}
    assert G.mode_defines("mask_normalized", 2, 5) == {"KILN_SH_L2": 1, "KILN_MASK_CLUSTERS": 5}
    assert G.mode_defines("ddgi", 2) == {} and G.mode_defines("direct", 1) == {}


def test_self_shadow_bias_from_the_bake():
    cfg = BakeConfig.model_validate({"light": {"self_shadow_bias": 0.8}}).model_dump(mode="json")
    assert G.self_shadow_bias(cfg) == 0.8
    assert G.self_shadow_bias({"light": {}}) == G.self_shadow_bias(None) == G.SELF_SHADOW_BIAS
