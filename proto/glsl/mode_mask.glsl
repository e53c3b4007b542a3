// GI mode "mask": Mask GI, MD eq 3, E = Σ_k m_k(x') · SH_k(x)·n over the K cluster volumes, clusters with
// m_k = 0 skipped, masks read from the compressed atlas at the lookup point x' (gi_mask.glsl has the
// textures, the lookup and the fetch count).
#include "gi_mask.glsl"

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  float den;
  return max(giMaskSum(p, n, false, den), 0.0);  // MD eq 3; clamped at 0 like leaking (SH ringing)
}
