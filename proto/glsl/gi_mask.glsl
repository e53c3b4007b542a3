// Mask GI (MD eq 3) from compressed masks (MD §3.4.2), shared by mode_mask.glsl and mode_mask_normalized.glsl.
// Python references: workers/kernels/samplers.py mask / mask_normalized (dense masks) and
// workers/kernels/compress.py sample_compressed (the atlas path, same arithmetic as below).
//   m = the K masks at p: 1 indirection texelFetch + 1 atlas fetch per 4 clusters (LINEAR, inside the block)
//   E = Σ_{k < K, m_k > 0} m_k · E(trilinear(cluster_sh_k)(p), n)         3 fetches per cluster with m_k > 0
//   normalized: E / Σ_k m_k w_k, w_k = channel k of trilinear(cluster_weights) (1 fetch per 4 clusters,
//   only when some m_k > 0); 0 where that sum is 0.
// Fetches per pixel: mask 1 + A + 3·z, normalized 1 + A + A·[z > 0] + 3·z, with A = ceil(K / 4) and z the
// clusters with m_k > 0 at the pixel.
// Textures (all 3D, CLAMP_TO_EDGE):
//   uMaskIndirection  mask_indirection (RGBA8 UNORM, NEAREST): per cell the block coordinates of its block
//   uMaskAtlas0123    mask_atlas_0123 (RGBA8 UNORM, LINEAR); uMaskAtlas4567 mask_atlas_4567 when K > 4
//   uClusterSh        the 3·K volumes cluster_sh_{k}_{r,g,b} stacked along z in the order k0 r, k0 g, k0 b,
//                     k1 r, ... (their bytes concatenated): depth 3·K·nz, RGBA32F, LINEAR
//   uClusterWeights   cluster_weights_0123 (+ _4567) stacked the same way, RGBA32F, LINEAR
// Uniforms from the atlas meta: uMaskS (S, samples_per_cell), uMaskT (block_size), uMaskLo (border_lo).
#include "common.glsl"
#include "sh.glsl"
#include "gi_grid.glsl"

uniform highp sampler3D uMaskIndirection;
uniform highp sampler3D uMaskAtlas0123;
uniform highp sampler3D uMaskAtlas4567;
uniform highp sampler3D uClusterSh;
uniform highp sampler3D uClusterWeights;
uniform int uClusterCount;  // K, 1..8
uniform float uMaskS;
uniform float uMaskT;
uniform float uMaskLo;

// The compressed masks of clusters 0-3 (atlas 0) or 4-7 (atlas 1) at p (compress.py module doc).
void giMasks(vec3 p, out vec4 m0, out vec4 m1) {
  vec3 live = vec3(greaterThan(uGridCounts, vec3(1.5)));
  vec3 cells = max(uGridCounts - 1.0, vec3(1.0));
  vec3 g = giGridCoord(p) + 0.5 * (1.0 - live);
  vec3 t = clamp(g * uMaskS - 0.5, vec3(0.0), cells * uMaskS - 1.0);
  vec3 cell = min(floor((t + 0.5 * uMaskLo) / uMaskS), cells - 1.0);
  vec3 blk = floor(texelFetch(uMaskIndirection, ivec3(cell), 0).xyz * 255.0 + 0.5);
  vec3 local = clamp(t - cell * uMaskS + uMaskLo, 0.0, uMaskT - 1.0);
  vec3 tc = blk * uMaskT + local + 0.5;
  m0 = texture(uMaskAtlas0123, tc / vec3(textureSize(uMaskAtlas0123, 0)));
  m1 = vec4(0.0);
  if (uClusterCount > 4) m1 = texture(uMaskAtlas4567, tc / vec3(textureSize(uMaskAtlas4567, 0)));
}

// Σ_k m_k E_k(n) (rgb) and, when `normalized`, Σ_k m_k w_k (returned in den; else 1).
vec3 giMaskSum(vec3 p, vec3 n, bool normalized, out float den) {
  vec4 m0, m1;
  giMasks(p, m0, m1);
  float m[8] = float[8](m0.x, m0.y, m0.z, m0.w, m1.x, m1.y, m1.z, m1.w);
  vec3 texel = giProbeTexel(p);
  float slots = 3.0 * float(uClusterCount);
  vec3 e = vec3(0.0);
  bool hit = false;
  for (int k = 0; k < 8; ++k) {
    if (k >= uClusterCount) break;
    if (m[k] <= 0.0) continue;  // clusters with m_k = 0 are skipped: no fetches
    hit = true;
    float s = 3.0 * float(k);
    vec4 r = texture(uClusterSh, giStackedUVW(texel, s, slots));
    vec4 gg = texture(uClusterSh, giStackedUVW(texel, s + 1.0, slots));
    vec4 b = texture(uClusterSh, giStackedUVW(texel, s + 2.0, slots));
    e += m[k] * shIrradianceL1(r, gg, b, n);
  }
  den = 1.0;
  if (normalized) {
    den = 0.0;
    if (hit) {
      float wslots = uClusterCount > 4 ? 2.0 : 1.0;
      vec4 w0 = texture(uClusterWeights, giStackedUVW(texel, 0.0, wslots));
      den = dot(m0, w0);
      if (uClusterCount > 4) den += dot(m1, texture(uClusterWeights, giStackedUVW(texel, 1.0, wslots)));
    }
  }
  return e;
}
