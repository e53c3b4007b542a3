// GI mode "prt": data-driven PRT relighting (PRT eq 10; workers/prt_relight.py), mono basis, linear (no gamma).
// The CPU turns the lights into coefficients u (n slots x 3 channels: u_c = T_c [x_c, ‖x_c‖], slot 0 the
// mean); the shader sums the basis: SH_c(p) = Σ_j u_cj · trilinear(basis_j)(p) for the 4 L1 coefficients,
// E = SH·n (sh.glsl). Python reference: relight(...)["sh_l1_*"] through the leaking sampler.
// Fetches per pixel: 4 · G, G = ceil(n / 4).
// Textures: uPrtBasis, the volumes prt_sh_basis_c{k}_g{g} (k = 0..3, g = 0..G-1; RGBA = slots 4g..4g+3)
// stacked along z in the order k0 g0, k0 g1, ..., k1 g0, ... (RGBA32F, LINEAR).
// Uniforms: uPrtGroups = G; uPrtCoef[c · KILN_PRT_MAX_GROUPS + g] = u_c of slots 4g..4g+3 (0 past n).
#include "sh.glsl"
#include "gi_grid.glsl"

#ifndef KILN_PRT_MAX_GROUPS
#define KILN_PRT_MAX_GROUPS 16
#endif

uniform highp sampler3D uPrtBasis;
uniform int uPrtGroups;
uniform vec4 uPrtCoef[3 * KILN_PRT_MAX_GROUPS];

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  vec3 texel = giProbeTexel(p);
  float slots = 4.0 * float(uPrtGroups);
  vec4 shR = vec4(0.0);
  vec4 shG = vec4(0.0);
  vec4 shB = vec4(0.0);
  for (int g = 0; g < KILN_PRT_MAX_GROUPS; ++g) {
    if (g >= uPrtGroups) break;
    vec4 cr = uPrtCoef[g];
    vec4 cg = uPrtCoef[KILN_PRT_MAX_GROUPS + g];
    vec4 cb = uPrtCoef[2 * KILN_PRT_MAX_GROUPS + g];
    vec4 b0 = texture(uPrtBasis, giStackedUVW(texel, float(g), slots));
    vec4 b1 = texture(uPrtBasis, giStackedUVW(texel, float(uPrtGroups + g), slots));
    vec4 b2 = texture(uPrtBasis, giStackedUVW(texel, float(2 * uPrtGroups + g), slots));
    vec4 b3 = texture(uPrtBasis, giStackedUVW(texel, float(3 * uPrtGroups + g), slots));
    shR += vec4(dot(b0, cr), dot(b1, cr), dot(b2, cr), dot(b3, cr));
    shG += vec4(dot(b0, cg), dot(b1, cg), dot(b2, cg), dot(b3, cg));
    shB += vec4(dot(b0, cb), dot(b1, cb), dot(b2, cb), dot(b3, cb));
  }
  return shIrradianceL1(shR, shG, shB, n);
}
