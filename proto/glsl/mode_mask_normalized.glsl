// GI mode "mask_normalized" (ours, DESIGN stage 4): Mask GI divided by Σ_k m_k(x) w_k(x), w_k the trilinear
// weight of cluster k's probes (cluster_weights); 0 where that is 0. Removes the darkening of MD Fig 4.
#include "gi_mask.glsl"

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  float den;
  vec3 e = giMaskSum(p, n, true, den);
  // clamped at 0 like leaking: the SH of a strongly directional probe rings negative away from its light
  return den > 0.0 ? max(e / den, 0.0) : vec3(0.0);
}
