// L1 spherical harmonics: radiance coefficients -> irradiance (Ramamoorthi & Hanrahan 2001, eq 7-8).
// Coefficient order per channel (proto/bundle.md 5.1, three.js SphericalHarmonics3):
//   c.x = L0 (Y00 = 0.282095), c.y = L1(y), c.z = L1(z), c.w = L1(x)   (Y1m = 0.488603 · {y, z, x})
// Python reference: workers/kernels/sh.py sh_irradiance (order 1).
#include "common.glsl"

float shIrradianceL1Channel(vec4 c, vec3 n) {
  return SH_IRR_C0 * c.x + SH_IRR_C1 * (c.y * n.y + c.z * n.z + c.w * n.x);  // Σ Â_l L_lm Y_lm(n)
}

// E(n) for unit world-space normal n, linear RGB; constant radiance L gives π·L. Not clamped.
vec3 shIrradianceL1(vec4 r, vec4 g, vec4 b, vec3 n) {
  return vec3(shIrradianceL1Channel(r, n), shIrradianceL1Channel(g, n), shIrradianceL1Channel(b, n));
}
