"""Run the shared Cycles oracle with its Lambert model following metallic textures and keeping emission (Blender).

    blender -b --python tests/data/fidelity/oracle_lambert_textures.py -- SCENE.glb POINTS.json OUT.json [oracle args]

Same arguments and output as ``../shared/oracle/cycles_irradiance_points.py`` (``KILN_ORACLE`` overrides its
path), which this runs unchanged. The one difference: the oracle's ``--material lambert`` gives every material the
albedo ``base colour (factor x texture) x (1 - metallic)``, but reads ``metallic`` from the factor only (it warns
when a ``metallicRoughnessTexture`` drives it). Before its replacement runs, every Principled BSDF whose Metallic
input is linked (the importer's Separate RGB B channel, times the factor) gets that ``(1 - metallic)`` multiplied
into its Base Color by nodes, and its Metallic set to an unlinked 0 — so the oracle's own code then builds exactly
the stated model, texel by texel. Second difference: the stock replacement removes the Principled BSDF, and with it the importer's emission
(``emissiveFactor`` x ``KHR_materials_emissive_strength`` on the Principled's Emission inputs), so emissive surfaces
go dark (measured on ``cornell``: its emitter panel gave E = 0 everywhere). Every Principled BSDF that emits gets an
Emission shader (same colour, texture and strength) added to its output first, so the Lambert that replaces it still
emits. Materials without a metallic texture or emission are untouched (identical to the stock run);
``--material importer`` is untouched too (it never calls the replacement). A single-sided emitter (glTF
``doubleSided`` false; the importer sets ``use_backface_culling``, which Cycles ignores) emits from its front only,
as glTF draws it and Kiln bakes it (workers/kernels/emitters.py): its Emission strength is multiplied by
(1 - Backfacing).

Lights (both ``--material`` modes): Blender 3.4's importer drops KHR_lights_punctual ``range`` ("TODO range"); Kiln
applies the spec's recommended window ``W(d) = clamp(1 - (d/range)^4, 0, 1)^2`` on top of the inverse square law
(workers/kernels/shading.py, direct_irradiance), so every point or spot light with a range gets W(ray length) as its
Emission strength (Cycles evaluates a light's nodes at the sampled distance). Checked against closed forms with
``--samples 256``: a 1 cd point light with range 2 m, 1.5 m above a receiver facing it, gave E_direct 0.20781 W/m2
(closed form 0.20769); one without a range 1.0000 (1); a single-sided 0.2 m square of 10 cd/m2 1 m below a receiver
facing its back 0.0006, its double-sided twin 0.3949 (closed form 0.3957).
"""
import json
import os
import runpy
import sys

ORACLE = os.environ.get("KILN_ORACLE", "/work/shared/oracle/cycles_irradiance_points.py")
sys.path.insert(0, os.path.dirname(os.path.abspath(ORACLE)))

import pb_common as pb  # noqa: E402  (the oracle imports this same module object)
import bpy  # noqa: E402

_stock_diffuse_materials = pb.diffuse_materials
_stock_load_gltf = pb.load_gltf


def _keep_emission(nt, p, name, single_sided=False):
    col, strength = p.inputs["Emission"], p.inputs["Emission Strength"]
    if strength.is_linked:
        raise RuntimeError(f"material {name!r}: a linked emission strength is not handled")
    if not col.is_linked and (max(tuple(col.default_value)[:3]) <= 0.0 or strength.default_value <= 0.0):
        return
    em = nt.nodes.new("ShaderNodeEmission")
    if col.is_linked:
        nt.links.new(col.links[0].from_socket, em.inputs["Color"])
    else:
        em.inputs["Color"].default_value = tuple(col.default_value)
    em.inputs["Strength"].default_value = strength.default_value
    if single_sided:
        # glTF: the back of a single-sided surface is not there (doubleSided false; the importer sets
        # use_backface_culling, which Cycles ignores); Cycles emits from both sides: strength x (1 - Backfacing)
        geo = nt.nodes.new("ShaderNodeNewGeometry")
        front = nt.nodes.new("ShaderNodeMath")
        front.operation = "SUBTRACT"
        front.inputs[0].default_value = 1.0
        nt.links.new(geo.outputs["Backfacing"], front.inputs[1])
        mul = nt.nodes.new("ShaderNodeMath")
        mul.operation = "MULTIPLY"
        mul.inputs[1].default_value = strength.default_value
        nt.links.new(front.outputs["Value"], mul.inputs[0])
        nt.links.new(mul.outputs["Value"], em.inputs["Strength"])
    add = nt.nodes.new("ShaderNodeAddShader")
    targets = [link.to_socket for link in p.outputs["BSDF"].links]
    for link in list(p.outputs["BSDF"].links):
        nt.links.remove(link)
    for sock in targets:
        nt.links.new(add.outputs["Shader"], sock)
    nt.links.new(p.outputs["BSDF"], add.inputs[0])        # the stock code relinks this to its Lambert
    nt.links.new(em.outputs["Emission"], add.inputs[1])
    print(f"[fidelity] material {name!r}: emission kept (colour {tuple(round(v, 4) for v in col.default_value)[:3]}"
          f"{' texture' if col.is_linked else ''}, strength {strength.default_value:g}"
          f"{', front side only (single-sided)' if single_sided else ''})")


def _fold_metallic_textures():
    for mat in list(bpy.data.materials):
        nt = mat.node_tree if mat.use_nodes else None
        if nt is None:
            continue
        for p in [n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"]:
            _keep_emission(nt, p, mat.name, single_sided=mat.use_backface_culling)
            base, met = p.inputs["Base Color"], p.inputs["Metallic"]
            if not met.is_linked:
                continue
            one_minus = nt.nodes.new("ShaderNodeMath")
            one_minus.operation = "SUBTRACT"
            one_minus.use_clamp = True
            one_minus.inputs[0].default_value = 1.0
            nt.links.new(met.links[0].from_socket, one_minus.inputs[1])
            mul = nt.nodes.new("ShaderNodeMixRGB")
            mul.blend_type = "MULTIPLY"
            mul.inputs["Fac"].default_value = 1.0
            if base.is_linked:
                nt.links.new(base.links[0].from_socket, mul.inputs["Color1"])
            else:
                mul.inputs["Color1"].default_value = tuple(base.default_value)
            nt.links.new(one_minus.outputs["Value"], mul.inputs["Color2"])   # float -> grey colour
            for link in list(met.links):
                nt.links.remove(link)
            met.default_value = 0.0
            nt.links.new(mul.outputs["Color"], base)
            print(f"[fidelity] material {mat.name!r}: metallic texture folded into the base colour "
                  f"(albedo = base x (1 - metallic texel))")


def _gltf_json(path):
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] == b"glTF":
        return json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])
    return json.loads(data)


def _range_windows():
    """KHR_lights_punctual ``range`` on point and spot lights: the importer drops it ("TODO range" in Blender 3.4's
    io_scene_gltf2), Kiln applies the spec's recommended window W(d) = clamp(1 - (d/range)^4, 0, 1)^2 on top of
    the inverse square law (workers/kernels/shading.py). Give the Cycles light the same: its Emission strength
    becomes W(Light Path ray length) (Cycles evaluates a light's nodes at the sampled distance)."""
    args = pb.script_args()
    if not args:
        return
    doc = _gltf_json(os.path.abspath(args[0]))
    defs = ((doc.get("extensions") or {}).get("KHR_lights_punctual") or {}).get("lights", [])
    ranges = {}
    for d in defs:
        if d.get("type") in ("point", "spot") and d.get("range") is not None:
            name = d.get("name") or ("Point" if d["type"] == "point" else "Spot")   # the importer's names
            if ranges.get(name, d["range"]) != d["range"]:
                raise RuntimeError(f"lights named {name!r} with different ranges: not handled")
            ranges[name] = float(d["range"])
    for light in bpy.data.lights:
        base = light.name.rsplit(".", 1)[0] if light.name not in ranges else light.name
        if light.type not in ("POINT", "SPOT") or base not in ranges:
            continue
        r = ranges[base]
        light.use_nodes = True
        nt = light.node_tree
        em = [n for n in nt.nodes if n.bl_idname == "ShaderNodeEmission"][0]
        path = nt.nodes.new("ShaderNodeLightPath")
        ops = []
        for op, a, b in (("DIVIDE", None, r), ("POWER", None, 4.0), ("SUBTRACT", 1.0, None), ("POWER", None, 2.0)):
            m = nt.nodes.new("ShaderNodeMath")
            m.operation = op
            m.use_clamp = op == "SUBTRACT"                   # clamp(1 - x^4, 0, 1)
            if a is not None:
                m.inputs[0].default_value = a
            if b is not None:
                m.inputs[1].default_value = b
            ops.append(m)
        nt.links.new(path.outputs["Ray Length"], ops[0].inputs[0])
        nt.links.new(ops[0].outputs["Value"], ops[1].inputs[0])
        nt.links.new(ops[1].outputs["Value"], ops[2].inputs[1])
        nt.links.new(ops[2].outputs["Value"], ops[3].inputs[0])
        nt.links.new(ops[3].outputs["Value"], em.inputs["Strength"])
        print(f"[fidelity] light {light.name!r}: KHR range {r:g} m window W(d) = clamp(1 - (d/{r:g})^4, 0, 1)^2")


def diffuse_materials():
    _fold_metallic_textures()
    _stock_diffuse_materials()


def load_gltf(*args, **kwargs):
    sc = _stock_load_gltf(*args, **kwargs)
    _range_windows()
    return sc


pb.diffuse_materials = diffuse_materials
pb.load_gltf = load_gltf
runpy.run_path(ORACLE, run_name="__main__")
