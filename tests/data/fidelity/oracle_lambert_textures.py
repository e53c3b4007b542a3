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
``--material importer`` is untouched too (it never calls the replacement).
"""
import os
import runpy
import sys

ORACLE = os.environ.get("KILN_ORACLE", "/work/shared/oracle/cycles_irradiance_points.py")
sys.path.insert(0, os.path.dirname(os.path.abspath(ORACLE)))

import pb_common as pb  # noqa: E402  (the oracle imports this same module object)
import bpy  # noqa: E402

_stock_diffuse_materials = pb.diffuse_materials


def _keep_emission(nt, p, name):
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
    add = nt.nodes.new("ShaderNodeAddShader")
    targets = [link.to_socket for link in p.outputs["BSDF"].links]
    for link in list(p.outputs["BSDF"].links):
        nt.links.remove(link)
    for sock in targets:
        nt.links.new(add.outputs["Shader"], sock)
    nt.links.new(p.outputs["BSDF"], add.inputs[0])        # the stock code relinks this to its Lambert
    nt.links.new(em.outputs["Emission"], add.inputs[1])
    print(f"[fidelity] material {name!r}: emission kept (colour {tuple(round(v, 4) for v in col.default_value)[:3]}"
          f"{' texture' if col.is_linked else ''}, strength {strength.default_value:g})")


def _fold_metallic_textures():
    for mat in list(bpy.data.materials):
        nt = mat.node_tree if mat.use_nodes else None
        if nt is None:
            continue
        for p in [n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"]:
            _keep_emission(nt, p, mat.name)
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


def diffuse_materials():
    _fold_metallic_textures()
    _stock_diffuse_materials()


pb.diffuse_materials = diffuse_materials
runpy.run_path(ORACLE, run_name="__main__")
