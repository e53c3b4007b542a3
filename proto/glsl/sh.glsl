// L1 and L2 spherical harmonics: radiance coefficients -> irradiance.
// Coefficient order per channel (proto/bundle.md 5.1, three.js SphericalHarmonics3):
//   c.x = L0 (Y00 = 0.282095), c.y = L1(y), c.z = L1(z), c.w = L1(x)   (Y1m = 0.488603 · {y, z, x})
// Python reference: workers/kernels/sh.py sh_irradiance (linear, order 1) and sh_irradiance_l1_nonlinear.
//
// shIrradianceL1 is what the GI modes call. By default it is the non-linear L1 reconstruction (Hazel 2017,
// "Reducing the ringing of L1 spherical harmonics", the Geomerics/Enlighten evaluation): the same mean
// irradiance as the linear one and, for weakly directional probes, the same linear part, but never negative.
// The linear one (Ramamoorthi & Hanrahan 2001 eq 7-8) rings below zero on the far side of a probe lit from
// one direction (a probe in a doorway: -0.45 where its octahedral irradiance says 0.25; non-linear: 0.40).
// `#define KILN_SH_LINEAR 1` selects the linear one (MD §3.2's exact eq 2/3 equivalence needs linearity).
#include "common.glsl"

float shIrradianceL1LinearChannel(vec4 c, vec3 n) {
  return SH_IRR_C0 * c.x + SH_IRR_C1 * (c.y * n.y + c.z * n.z + c.w * n.x);  // Σ Â_l L_lm Y_lm(n)
}

// E(n) = R0 · (a + (1 - a)(p + 1) q^p), R0 = Â_0 L0 Y00 (the mean), R1 = ½ Â_1 Y1 L1 (linear part 2 R1·n),
// r = min(|R1| / R0, 1), q = (1 + n·R1/|R1|) / 2, p = 1 + 2r, a = (1 - r) / (1 + r); 0 where R0 <= 0.
float shIrradianceL1NonlinearChannel(vec4 c, vec3 n) {
  float R0 = SH_IRR_C0 * c.x;
  if (R0 <= 0.0) return 0.0;
  vec3 R1 = 0.5 * SH_IRR_C1 * vec3(c.w, c.y, c.z);
  float len = length(R1);
  if (len <= 1e-6 * R0) return R0;
  float r = min(len / R0, 1.0);
  float q = clamp(0.5 * (1.0 + dot(R1, n) / len), 0.0, 1.0);
  float p = 1.0 + 2.0 * r;
  float a = (1.0 - r) / (1.0 + r);
  return R0 * (a + (1.0 - a) * (p + 1.0) * pow(q, p));
}

float shIrradianceL1Channel(vec4 c, vec3 n) {
#ifdef KILN_SH_LINEAR
  return shIrradianceL1LinearChannel(c, n);
#else
  return shIrradianceL1NonlinearChannel(c, n);
#endif
}

// E(n) for unit normal n (in the SH's frame: the bake frame, gi_view.glsl), linear RGB; constant radiance L gives π·L.
vec3 shIrradianceL1(vec4 r, vec4 g, vec4 b, vec3 n) {
  return vec3(shIrradianceL1Channel(r, n), shIrradianceL1Channel(g, n), shIrradianceL1Channel(b, n));
}

// ---- L2 (9 coefficients; workers/kernels/sh.py sh_irradiance_l2, web/src/math/sh.js shIrradianceL2)
// c0..c8: the radiance coefficients of the three.js order (sh.py module table), rgb per coefficient. Linear:
// Ramamoorthi & Hanrahan 2001 eq 7, E(n) = Σ_lm Â_l L_lm Y_lm(n), with eq 8's clamped-cosine kernel
// Â_0 = π, Â_1 = 2π/3, Â_2 = π/4 folded into SH_IRR_C0..C4 (common.glsl). Constant radiance L gives π·L.
// Not clamped: the modes clamp E at 0 (L2 of a light seen through a doorway still rings slightly below 0).
vec3 shIrradianceL2(vec3 c0, vec3 c1, vec3 c2, vec3 c3, vec3 c4, vec3 c5, vec3 c6, vec3 c7, vec3 c8, vec3 n) {
  return SH_IRR_C0 * c0                                                  // Â_0 Y00
       + SH_IRR_C1 * (c1 * n.y + c2 * n.z + c3 * n.x)                      // Â_1 Y1m
       + SH_IRR_C2 * (c4 * (n.x * n.y) + c5 * (n.y * n.z) + c7 * (n.x * n.z))  // Â_2 Y2m, m = -2, -1, 1
       + SH_IRR_C3 * (3.0 * n.z * n.z - 1.0) * c6                          // Â_2 Y20
       + SH_IRR_C4 * (n.x * n.x - n.y * n.y) * c8;                         // Â_2 Y22
}

// The 7 RGBA texels of the sh_l2 layout (proto/bundle.md 5.1, three.js LightProbeGrid): the 27 numbers
// c0.rgb, c1.rgb, ..., c8.rgb in order, 4 per texel (s6.w unused).
vec3 shIrradianceL2Packed(vec4 s0, vec4 s1, vec4 s2, vec4 s3, vec4 s4, vec4 s5, vec4 s6, vec3 n) {
  return shIrradianceL2(s0.xyz, vec3(s0.w, s1.xy), vec3(s1.zw, s2.x), s2.yzw, s3.xyz, vec3(s3.w, s4.xy),
                        vec3(s4.zw, s5.x), s5.yzw, s6.xyz, n);
}
