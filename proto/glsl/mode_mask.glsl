// GI mode "mask": Mask GI, MD eq 3, E = Σ_k m_k(x) · SH_k(x)·n over the K cluster volumes, clusters with
// m_k = 0 skipped, masks read from the compressed atlas (gi_mask.glsl has the textures and the fetch count).
#include "gi_mask.glsl"

vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  float den;
  return giMaskSum(p, n, false, den);
}
