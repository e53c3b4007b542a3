// GI mode "leaking": trilinear interpolation of the probes' SH, no visibility (DESIGN "Runtime shading":
// SH = trilinear(volume); E = SH · n). Light leaks through walls thinner than a cell: the problem MD and DDGI
// solve. Two forms (proto/bundle.md 5.1; Python: workers/kernels/samplers.py leaking / leaking_l2):
//   KILN_SH_L2 defined (the renderers define it when the bake has `sh_l2`; the default, docs/architecture.md
//   "Runtime SH evaluation"): L2, 9 coefficients from uShL2, the sh_l2 volume (three.js LightProbeGrid layout:
//   7 padded RGBA32F sub-volumes stacked along z), 7 fetches, linear RH01 evaluation (sh.glsl shIrradianceL2),
//   clamped at 0.
//   else: L1 from sh_l1_r/g/b (RGBA32F, texel (i, j, k) = probe (i, j, k), channels L0, L1(y), L1(z), L1(x)),
//   3 fetches, the non-linear L1 reconstruction (sh.glsl shIrradianceL1).
// All sampled with LINEAR filtering, CLAMP_TO_EDGE.
#include "sh.glsl"
#include "probe_grid.glsl"
#include "gi_grid.glsl"

#ifdef KILN_SH_L2
uniform highp sampler3D uShL2;

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  vec3 texel = giProbeTexel(p);
  vec4 s0 = texture(uShL2, giPaddedStackedUVW(texel, 0.0, 7.0));
  vec4 s1 = texture(uShL2, giPaddedStackedUVW(texel, 1.0, 7.0));
  vec4 s2 = texture(uShL2, giPaddedStackedUVW(texel, 2.0, 7.0));
  vec4 s3 = texture(uShL2, giPaddedStackedUVW(texel, 3.0, 7.0));
  vec4 s4 = texture(uShL2, giPaddedStackedUVW(texel, 4.0, 7.0));
  vec4 s5 = texture(uShL2, giPaddedStackedUVW(texel, 5.0, 7.0));
  vec4 s6 = texture(uShL2, giPaddedStackedUVW(texel, 6.0, 7.0));
  return max(shIrradianceL2Packed(s0, s1, s2, s3, s4, s5, s6, n), 0.0);  // P_x, MD eq 1
}
#else
uniform highp sampler3D uShR;
uniform highp sampler3D uShG;
uniform highp sampler3D uShB;

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  vec3 uvw = probeGridUVW(p);
  return max(shIrradianceL1(texture(uShR, uvw), texture(uShG, uvw), texture(uShB, uvw), n), 0.0);  // P_x, MD eq 1
}
#endif
