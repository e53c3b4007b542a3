// GI mode "prt": data-driven PRT relighting (PRT eq 10; workers/prt_relight.py), mono basis, linear (no gamma).
// The CPU turns the lights into coefficients u (n slots x 3 channels: u_c = T_c [x_c, ‖x_c‖], slot 0 the
// mean); the shader sums the basis: SH_c(p) = Σ_j u_cj · trilinear(basis_j)(p) for each SH coefficient, then
// E = SH·n (sh.glsl). KILN_SH_L2 defined (the renderers define it when the basis has the 9 coefficients of an L2
// bake, light.sh_order = 2; the default): all 9 coefficients, the linear L2 evaluation, clamped at 0 (Python
// reference: relight(...)["sh_l2"] through samplers.leaking_l2); else the 4 L1 coefficients and the non-linear L1
// reconstruction (relight(...)["sh_l1_*"] through samplers.leaking).
// Fetches per pixel: C · G, G = ceil(n / 4), C = 9 (L2) or 4 (L1).
// Textures: uPrtBasis, the volumes prt_sh_basis_c{k}_g{g} (k = 0..C-1, g = 0..G-1; RGBA = slots 4g..4g+3)
// stacked along z in the order k0 g0, k0 g1, ..., k1 g0, ... (RGBA32F, LINEAR).
// Uniforms: uPrtGroups = G; uPrtCoef[c · KILN_PRT_MAX_GROUPS + g] = u_c of slots 4g..4g+3 (0 past n).
#include "sh.glsl"
#include "gi_grid.glsl"

#ifndef KILN_PRT_MAX_GROUPS
#define KILN_PRT_MAX_GROUPS 16
#endif
#ifdef KILN_SH_L2
#define KILN_PRT_COEFFS 9
#else
#define KILN_PRT_COEFFS 4
#endif

uniform highp sampler3D uPrtBasis;
uniform int uPrtGroups;
uniform vec4 uPrtCoef[3 * KILN_PRT_MAX_GROUPS];

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  vec3 texel = giProbeTexel(p);
  float slots = float(KILN_PRT_COEFFS * uPrtGroups);
  vec3 c[KILN_PRT_COEFFS];  // SH coefficient k, rgb
  for (int k = 0; k < KILN_PRT_COEFFS; ++k) c[k] = vec3(0.0);
  for (int g = 0; g < KILN_PRT_MAX_GROUPS; ++g) {
    if (g >= uPrtGroups) break;
    vec4 cr = uPrtCoef[g];
    vec4 cg = uPrtCoef[KILN_PRT_MAX_GROUPS + g];
    vec4 cb = uPrtCoef[2 * KILN_PRT_MAX_GROUPS + g];
    for (int k = 0; k < KILN_PRT_COEFFS; ++k) {
      vec4 b = texture(uPrtBasis, giStackedUVW(texel, float(k * uPrtGroups + g), slots));
      c[k] += vec3(dot(b, cr), dot(b, cg), dot(b, cb));  // y ≈ U_n u, u = M_n x: PRT eq 10
    }
  }
#ifdef KILN_SH_L2
  return max(shIrradianceL2(c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], n), 0.0);
#else
  return shIrradianceL1(vec4(c[0].r, c[1].r, c[2].r, c[3].r), vec4(c[0].g, c[1].g, c[2].g, c[3].g),
                        vec4(c[0].b, c[1].b, c[2].b, c[3].b), n);
#endif
}
