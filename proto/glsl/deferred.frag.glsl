// Deferred shading pass of the evaluate stage (workers/render/shading.py): reads a G-buffer, lights each pixel
// with the punctual lights (lights.glsl) times a ray-traced shadow mask and the GI mode bound to @mode:
//   L_out = emission + albedo/π · (E_direct + E_indirect)       (DESIGN stage 2, Lambertian; linear HDR)
// uOutput: 0 radiance, 1 E_indirect, 2 E_direct (irradiance, linear). Uncovered pixels and back faces of
// single-sided surfaces (uGPosition.w = 0) are 0. The G-buffer, uEye and the lights are world; the mode is
// evaluated in the bake frame (gi_view.glsl uGiFrame, identity for a bake without grid.frame).
// G-buffer (2D, NEAREST, row 0 = the image's top row as uploaded; the pass reads texel = gl_FragCoord):
//   uGPosition xyz world position, w 1 where shaded; uGNormal xyz unit shading normal facing the camera;
//   uGAlbedo rgb linear albedo; uGEmission rgb emitted radiance;
//   uShadowMask0 / uShadowMask1 (RGBA8) visibility of lights 0-3 / 4-7 (Embree shadow rays, 0 or 1).
// A scene with more than MAX_LIGHTS lights is drawn a group of 8 at a time (uOutput 2 for the further groups).
#include "common.glsl"
#define KILN_LIGHT_VISIBILITY 1
#include "lights.glsl"
#include "gi_view.glsl"
#include "@mode"

uniform highp sampler2D uGPosition;
uniform highp sampler2D uGNormal;
uniform highp sampler2D uGAlbedo;
uniform highp sampler2D uGEmission;
uniform highp sampler2D uShadowMask0;
uniform highp sampler2D uShadowMask1;
uniform vec3 uEye;
uniform int uOutput;

vec4 gShadow0 = vec4(1.0);
vec4 gShadow1 = vec4(1.0);

float lightVisibility(int i, vec3 p, vec3 n) {
  return i < 4 ? gShadow0[i] : gShadow1[i - 4];
}

out vec4 fragColor;

void main() {
  ivec2 gPixel = ivec2(gl_FragCoord.xy);
  vec4 P = texelFetch(uGPosition, gPixel, 0);
  if (P.w < 0.5) {
    fragColor = vec4(0.0, 0.0, 0.0, 1.0);
    return;
  }
  vec3 n = texelFetch(uGNormal, gPixel, 0).xyz;
  if (uLightCount > 0) gShadow0 = texelFetch(uShadowMask0, gPixel, 0);
  if (uLightCount > 4) gShadow1 = texelFetch(uShadowMask1, gPixel, 0);
  giViewDir = uGiFrame * normalize(uEye - P.xyz);                          // the GI modes work in the bake frame
  vec3 eDirect = directIrradiance(P.xyz, n);                                // direct light: world
  // E_direct alone (a further light group's pass, workers/render/shading.py) skips the mode's lookups
  vec3 eIndirect = uOutput == 2 ? vec3(0.0) : giIndirectIrradiance(uGiFrame * P.xyz, uGiFrame * n);
  vec3 c;
  if (uOutput == 1) c = eIndirect;
  else if (uOutput == 2) c = eDirect;
  else c = texelFetch(uGEmission, gPixel, 0).rgb + texelFetch(uGAlbedo, gPixel, 0).rgb * INV_PI * (eDirect + eIndirect);
  fragColor = vec4(c, 1.0);
}
