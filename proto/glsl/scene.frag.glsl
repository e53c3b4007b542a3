// Scene surfaces: L_out = emission + albedo/π · (E_direct + E_indirect) (DESIGN stage 2, Lambertian),
// with E_indirect from the GI mode bound to the @mode slot, evaluated in the bake frame (gi_view.glsl uGiFrame).
// Output is display-encoded (tonemap.glsl).
// Define KILN_SHADOWS to shadow the direct light with shadows.glsl (the caller renders the maps).
#include "common.glsl"
#ifdef KILN_SHADOWS
#define KILN_LIGHT_VISIBILITY 1
#endif
#include "lights.glsl"
#ifdef KILN_SHADOWS
#include "shadows.glsl"
#endif
#include "tonemap.glsl"
#include "gi_view.glsl"
#include "material.glsl"
#include "@mode"

uniform vec3 uBaseColor;           // linear RGB (glTF baseColorFactor)
uniform sampler2D uBaseColorMap;   // sRGB texture, decoded to linear by the sampler
uniform bool uHasBaseColorMap;
uniform float uBaseAlpha;          // baseColorFactor alpha
uniform bool uHasVertexColor;      // COLOR_0 multiplies the base colour ([glTF] 3.7.2.1)
uniform float uMetallic;           // metallicFactor
uniform float uRoughness;          // roughnessFactor (perceptual)
uniform sampler2D uMetallicRoughnessMap;   // linear: G = roughness, B = metallic
uniform bool uHasMetallicRoughnessMap;
uniform float uAlphaCutoff;        // < 0 opaque; else alphaMode MASK (BLEND is baked as a cutout at 0.5)
uniform vec3 uEmissive;            // linear RGB radiance (emissiveFactor · strength)
uniform float uIndirectScale;      // 1 normally, 0 to hide GI
uniform vec3 cameraPosition;       // set by three.js for every ShaderMaterial (the ddgi mode's view bias)
uniform int uOutput;               // 0 shaded, 1 indirect irradiance only, 2 direct irradiance only, 3 albedo

in vec3 vWorldPos;
in vec3 vWorldNormal;
in vec2 vUv;
in vec4 vColor;

out vec4 fragColor;

void main() {
  vec3 n = normalize(vWorldNormal);
  if (!gl_FrontFacing) n = -n;  // back faces (double-sided or seen from inside) shade with the flipped normal
  vec4 base = vec4(uBaseColor, uBaseAlpha);
  if (uHasBaseColorMap) base *= texture(uBaseColorMap, vUv);
  if (uHasVertexColor) base *= vColor;
  if (uAlphaCutoff >= 0.0 && base.a < uAlphaCutoff) discard;   // a cutout's hole, as the bake's rays see it
  float metallic = uMetallic, roughness = uRoughness;
  if (uHasMetallicRoughnessMap) {
    vec4 mr = texture(uMetallicRoughnessMap, vUv);
    roughness *= mr.g;
    metallic *= mr.b;
  }
  vec3 albedo = giAlbedo(base.rgb, metallic, roughness);
  giViewDir = uGiFrame * normalize(cameraPosition - vWorldPos);            // the GI modes work in the bake frame
  vec3 eDirect = directIrradiance(vWorldPos, n);                            // direct light: world
  vec3 eIndirect = uIndirectScale * giIndirectIrradiance(uGiFrame * vWorldPos, uGiFrame * n);
  vec3 radiance;
  if (uOutput == 1) radiance = eIndirect * INV_PI;
  else if (uOutput == 2) radiance = eDirect * INV_PI;
  else if (uOutput == 3) radiance = albedo;
  else radiance = uEmissive + albedo * INV_PI * (eDirect + eIndirect);
  fragColor = vec4(displayColor(radiance), 1.0);
}
