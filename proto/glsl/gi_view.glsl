// The GI hook's shared state, set by the surface shader before it calls giIndirectIrradiance.
//
// uGiFrame: world (glTF) -> bake frame, a pure rotation about +Y (proto/bundle.md, the manifest's grid.frame.matrix,
// row-major M with p_bake = M · p_world; uploaded so that uGiFrame * p_world == p_bake, i.e. GLSL's column-major
// mat3 of M). Every probe artifact (grid origin/spacing/counts, probe positions, SH and mask volumes, DDGI atlases,
// PRT basis) is in the bake frame, so the GI modes take p, n and giViewDir in the bake frame: the caller passes
// uGiFrame * p_world, uGiFrame * n_world and sets giViewDir = uGiFrame * v_world. Direct light stays in world.
// GLSL ES 3.00 has no uniform initializers: every renderer sets it, the identity for a bake without grid.frame
// (an unset mat3 is zero). Renderers: web/src/renderer/renderer.js setFrame, workers/render/shading.py
// ShadingRenderer(frame=...), web/kiln-three/src/gi.js.
uniform mat3 uGiFrame;

// The view direction hook of the GI modes: unit vector from the shaded point toward the viewer (ω_o of
// DDGI-P eq 2, used by the ddgi mode's self-shadow bias and the mask modes' lookup offset), in the bake frame. The
// surface shader sets it before calling giIndirectIrradiance (scene.frag.glsl from three.js' cameraPosition,
// deferred.frag.glsl from uEye, both times uGiFrame).
vec3 giViewDir = vec3(0.0, 0.0, 1.0);
