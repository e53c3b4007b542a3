// GI mode "leaking": trilinear interpolation of the probes' L1 SH, no visibility (DESIGN "Runtime shading":
// 1 fetch per SH texture; SH = trilinear(volume); E = SH · n). Light leaks through walls thinner than a cell:
// the problem MD and DDGI solve. Volumes sh_l1_r/g/b: RGBA32F, texel (i, j, k) = probe (i, j, k),
// channels L0, L1(y), L1(z), L1(x) (proto/bundle.md 5.1); sampled with LINEAR filtering, CLAMP_TO_EDGE.
#include "sh.glsl"
#include "probe_grid.glsl"

uniform highp sampler3D uShR;
uniform highp sampler3D uShG;
uniform highp sampler3D uShB;

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  vec3 uvw = probeGridUVW(p);
  return max(shIrradianceL1(texture(uShR, uvw), texture(uShG, uvw), texture(uShB, uvw), n), 0.0);
}
