// The view direction hook of the GI modes: unit vector from the shaded point toward the viewer (ω_o of
// DDGI-P eq 2, used by the ddgi mode's self-shadow bias). The surface shader sets it before calling
// giIndirectIrradiance (scene.frag.glsl from three.js' cameraPosition, deferred.frag.glsl from uEye).
vec3 giViewDir = vec3(0.0, 0.0, 1.0);
