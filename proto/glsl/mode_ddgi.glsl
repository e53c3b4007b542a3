// GI mode "ddgi": DDGI visibility-weighted probe irradiance (DDGI-I §3.4.1, DDGI-P §2.2 and eq 2), the
// runtime twin of workers/kernels/ddgi.py sample_irradiance (without its offline `visible=` ray test: this
// is pure DDGI). For point x, normal n, view direction ω_o (gi_view.glsl):
//   1. self-shadow bias (DDGI-P eq 2): x_b = x + (0.2·n + 0.8·ω_o) · uDdgiBias, uDdgiBias = 0.75·D·B
//      (D the smallest spacing, B the bake's light.self_shadow_bias, 0.3 by default);
//   2. the cage of x_b on the un-relocated grid: base = clamp(floor(g), 0, counts - 2), α = clamp(g - base, 0, 1);
//   3. per corner probe i (OFF skipped), at its relocated position p_i:
//      w = ((dot(normalize(p_i - x), n) + 1) / 2)² + 0.2                    (wrap backface, unbiased x)
//      Chebyshev on the depth moments (μ, μ²) in direction x_b - p_i, r = |x_b - p_i|:
//        r > μ: c = (σ² / (σ² + (r - μ)²))³, σ² = |μ² - μ₂|; else c = 1;  w *= max(0.05, c)
//      w = max(1e-6, w); w < 0.2: w *= w² / 0.2²  (crush);  w *= Π max(0.001, trilinear lerp)
//   4. E = Σ w_i E_i(n) / Σ w_i, E_i(n) the probe's octahedral irradiance, bilinear (0 when all 8 are OFF).
// Fetches per pixel: per corner 1 probe texel (texelFetch) + 1 depth (bilinear) + 1 irradiance (bilinear)
// = 24; an OFF corner costs 1.
// Textures: uProbeData (3D RGBA32F, NEAREST; texel (i,j,k) = relocated position xyz of probe (i,j,k), w = 1
// unless OFF, 0 when OFF; built from probe_positions_relocated + probe_states), uIrradianceAtlas (2D, the
// `irradiance` artifact, LINEAR), uDepthAtlas (2D, `depth_moments`, LINEAR); an atlas wider than the device's
// MAX_TEXTURE_SIZE is bound re-packed with its tile columns wrapped (uIrradianceColumns / uDepthColumns tiles per
// row, 0 = as stored; octahedral.glsl octAtlasUVWrapped): as stored it would not upload, and DDGI read 0.
// Float atlases need OES_texture_float_linear on WebGL2 (or convert them to half floats).
#include "common.glsl"
#include "gi_grid.glsl"
#include "gi_view.glsl"
#include "octahedral.glsl"

uniform highp sampler3D uProbeData;
uniform highp sampler2D uIrradianceAtlas;
uniform highp sampler2D uDepthAtlas;
uniform float uDdgiBias;        // 0.75 · min spacing · B (metres)
uniform int uIrradianceTexels;  // n of the irradiance tiles (tile n + 2)
uniform int uDepthTexels;       // m of the depth tiles (tile m + 2)
uniform int uIrradianceColumns; // tiles per row of a wrapped irradiance atlas (octahedral.glsl octAtlasUVWrapped), 0: none
uniform int uDepthColumns;      // the same for the depth atlas

vec3 giIndirectIrradiance(vec3 x, vec3 n) {
  vec3 bp = x + (n * 0.2 + giViewDir * 0.8) * uDdgiBias;  // DDGI-P eq 2 (uDdgiBias = 0.75·D·B)
  vec3 g = giGridCoord(bp);
  vec3 hi = max(uGridCounts - 2.0, vec3(0.0));
  vec3 base = clamp(floor(g), vec3(0.0), hi);
  vec3 alpha = mix(vec3(0.0), clamp(g - base, 0.0, 1.0), greaterThan(uGridCounts, vec3(1.5)));
  ivec3 counts = ivec3(uGridCounts + 0.5);
  ivec3 ibase = ivec3(base + 0.5);
  vec2 irrSize = vec2(textureSize(uIrradianceAtlas, 0));
  vec2 depSize = vec2(textureSize(uDepthAtlas, 0));
  vec3 acc = vec3(0.0);
  float wsum = 0.0;
  for (int c = 0; c < 8; ++c) {
    ivec3 off = ivec3(c & 1, (c >> 1) & 1, (c >> 2) & 1);
    ivec3 probe = min(ibase + off, counts - 1);
    vec4 pd = texelFetch(uProbeData, probe, 0);
    if (pd.w < 0.5) continue;  // OFF
    vec3 p = pd.xyz;
    vec3 t = p - x;
    float dl = length(t);
    float cosw = dl > 0.0 ? dot(t, n) / dl : 0.0;
    float wrap = (cosw + 1.0) * 0.5;
    float w = wrap * wrap + 0.2;  // smooth backface weight, wrap shading (DDGI-I §3.4.1)
    vec3 b = bp - p;
    float r = length(b);
    float cheb = 1.0;
    if (r > 0.0) {
      vec2 mom = texture(uDepthAtlas, octAtlasUVWrapped(b, probe, counts, uDepthTexels, uDepthColumns, depSize)).rg;
      if (r > mom.x) {
        float variance = abs(mom.x * mom.x - mom.y);
        float dv = r - mom.x;
        cheb = variance / (variance + dv * dv);
        cheb = cheb * cheb * cheb;  // Chebyshev moment visibility test, variance-biased (DDGI-I §3.4.1)
      }
    }
    w *= max(0.05, cheb);
    w = max(1e-6, w);
    if (w < 0.2) w *= w * w * 25.0;  // 1 / 0.2²: log perception weight, crush (DDGI-I §3.4.1)
    vec3 lerpw = mix(1.0 - alpha, alpha, vec3(off));
    w *= max(0.001, lerpw.x) * max(0.001, lerpw.y) * max(0.001, lerpw.z);  // trilinear weight (DDGI-I §3.4.1)
    acc += w * texture(uIrradianceAtlas, octAtlasUVWrapped(n, probe, counts, uIrradianceTexels, uIrradianceColumns, irrSize)).rgb;
    wsum += w;
  }
  return wsum > 0.0 ? acc / wsum : vec3(0.0);  // the weighted blend of the 8-probe cage (DDGI-P §2.2)
}
