// Mask GI (MD eq 3) from compressed masks (MD §3.4.2), shared by mode_mask.glsl and mode_mask_normalized.glsl.
// Python references: workers/kernels/samplers.py mask / mask_normalized (dense masks) and
// workers/kernels/mask_atlas.py sample_channel_atlas (the atlas path, same arithmetic as below).
//   m = the K masks at the lookup point: 2·G indirection texelFetch (G = ceil(K / 4): low and high bytes of a 16-bit
//       code per cell and channel), then per channel: code 0 → m_k = 0, code 1 → m_k = 1, code c ≥ 2 → one LINEAR
//       fetch of the R8 channel-block atlas per read (2 reads: offset and at the point), in block c − 2
//   E = Σ_{k < K, m_k > 0} m_k · E(trilinear(cluster_sh_k)(p), n)         3 fetches per cluster with m_k > 0
//   normalized: E / Σ_k m_k w_k, w_k = channel k of trilinear(cluster_weights) (1 fetch per 4 clusters); 0 where
//   that sum is 0.
// A mask channel is 0 wherever its cluster has no probe in the cell (masks.canonicalize), so m_k > 0 marks the
// clusters to sample ("only sample probe volumes whose masks are marked", MD §1).
// Fetches per pixel: mask 2G + 2y + 3·z, normalized 2G + 2y + A + 3·z (7·z with KILN_SH_L2), with A = ceil(K / 4),
// y the channels of the pixel's cell stored in the atlas (code ≥ 2) and z the clusters with m_k > 0 at the pixel.
// The stored channels and the sampled clusters are listed first and then looped over with a data-dependent trip
// count: a GPU wave or a llvmpipe SIMD group runs max(y), max(z) iterations. (llvmpipe runs the body of an `if` for
// every lane, fetches included, even when no lane takes it; only loops exit early.)
// Callers that know K may `#define KILN_MASK_CLUSTERS K` (1..8; the evaluate pass does): the code of the
// codes and weights of clusters 4-7 is then left out when K <= 4. Without it the shader serves any K <= 8.
// Textures (all 3D, CLAMP_TO_EDGE):
//   uMaskIndirection  mask_indirection (RGBA8 UNORM, NEAREST, 2·G·cz slices): cell (i, j, k)'s codes of channels
//                     4g..4g+3, low bytes at slice 2g·cz + k, high bytes at slice (2g + 1)·cz + k
//   uMaskAtlas        mask_atlas (R8 UNORM, LINEAR): S³ channel blocks, slot s at block (s % bx, s / bx % by, s / (bx·by))
//   uClusterSh        the 3·K volumes cluster_sh_{k}_{r,g,b} stacked along z in the order k0 r, k0 g, k0 b,
//                     k1 r, ... (their bytes concatenated): depth 3·K·nz, RGBA16F, LINEAR
//   uClusterShL2      with KILN_SH_L2 (the renderers define it when the bake has cluster_sh_l2_{k}; the default,
//                     docs/architecture.md "Runtime SH evaluation"): the K volumes cluster_sh_l2_{k} (each the
//                     sh_l2 layout: 7 padded sub-volumes, proto/bundle.md 5.2) stacked along z in k order: depth
//                     7·K·(nz + 2), RGBA16F, LINEAR; 7 fetches per cluster with m_k > 0 instead of 3, E by the
//                     linear L2 evaluation (sh.glsl shIrradianceL2Packed). uClusterSh is then not read.
//   uClusterWeights   cluster_weights_0123 (+ _4567) stacked the same way, RGBA16F, LINEAR
// Uniforms from the atlas meta: uMaskS (S, samples_per_cell), uMaskT (block_size, = S), uMaskLo (border_lo, 0);
// uMaskOffset: refined samples (1, gi_modes.json mask_offset_samples) the lookup moves along d = n + giViewDir, per
// axis (g' = g + uMaskOffset·d/S on axes with more than one probe; compress.mask_lookup_texel), read from p's own cell's
// samples only. The normal term puts the footprint one sample in front of the surface: refined samples inside a
// wall see no probe and hold masks filled from both sides, so a footprint half inside a thin wall weights the far
// side's clusters by up to 1/2. The view term (DDGI-P eq 2's idea) moves it towards the camera's side, away from a
// neighbouring wall at a corner. The own cell: a channel is free (0) where its cluster has no probe, and must not
// filter across a face into a cell where that cluster is present.
#include "common.glsl"
#include "sh.glsl"
#include "gi_grid.glsl"
#include "gi_view.glsl"

#ifndef KILN_MASK_CLUSTERS
#define KILN_MASK_CLUSTERS 8
#endif

uniform highp sampler3D uMaskIndirection;
uniform highp sampler3D uMaskAtlas;
#ifdef KILN_SH_L2
uniform highp sampler3D uClusterShL2;
#else
uniform highp sampler3D uClusterSh;
#endif
uniform highp sampler3D uClusterWeights;
uniform int uClusterCount;  // K, 1..8
uniform float uMaskS;
uniform float uMaskT;
uniform float uMaskLo;
uniform float uMaskOffset;
uniform float uMaskSeen;   // proto/gi_modes.json mask_seen_threshold (0.1)
uniform vec2 uMaskBlend;   // proto/gi_modes.json mask_blend (0.25, 0.5)

// The 16-bit codes of channels 4g .. 4g + 3 of cell `c` (mask_atlas.py codes_of): 2 texelFetch.
vec4 giMaskCodes(ivec3 c, int g, int cz) {
  vec4 lo = floor(texelFetch(uMaskIndirection, ivec3(c.xy, c.z + 2 * g * cz), 0) * 255.0 + 0.5);
  vec4 hi = floor(texelFetch(uMaskIndirection, ivec3(c.xy, c.z + (2 * g + 1) * cz), 0) * 255.0 + 0.5);
  return lo + 256.0 * hi;
}

// Channel k of the reads at local texel coordinates l1 (offset) and l0 (at p) of atlas slot `slot` (LINEAR).
vec2 giMaskAtlasReads(int slot, vec3 l1, vec3 l0) {
  vec3 size = vec3(textureSize(uMaskAtlas, 0));
  ivec3 bg = ivec3(size / uMaskT + 0.5);
  vec3 blk = vec3(float(slot % bg.x), float((slot / bg.x) % bg.y), float(slot / (bg.x * bg.y)));
  return vec2(textureLod(uMaskAtlas, (blk * uMaskT + l1) / size, 0.0).r,
              textureLod(uMaskAtlas, (blk * uMaskT + l0) / size, 0.0).r);
}

// The compressed masks of clusters 0-3 (m0) and 4-7 (m1) at the mask lookup point of (p, n)
// (workers/kernels/compress.py module doc, "Sampling"; mask_lookups): uMaskOffset samples along n + giViewDir, blended
// with the read at p itself (both sides, below), the texel coordinates clamped to the S³ samples of p's own cell, so
// the footprint never reads a neighbouring cell. 2·G indirection fetches + 2 atlas fetches per stored channel.
void giMasks(vec3 p, vec3 n, out vec4 m0, out vec4 m1) {
  vec3 live = vec3(greaterThan(uGridCounts, vec3(1.5)));
  vec3 cells = max(uGridCounts - 1.0, vec3(1.0));
  vec3 g = giGridCoord(p) + 0.5 * (1.0 - live);
  vec3 cell = clamp(floor(g), vec3(0.0), cells - 1.0);
  vec3 lo = cell * uMaskS, hi = cell * uMaskS + uMaskS - 1.0;
  // both sides (compress.mask_lookups, lookup_blend): the read moved uMaskOffset samples along n + v (a) and the read
  // at p itself (b); a' = a * min(b / uMaskSeen, 1) (the clusters of a that p sees too), seen = sum(a') / sum(a)
  // over the lookup's channels; m = mix(b, a', s), s rising from 0 at seen uMaskBlend.x to 1 at uMaskBlend.y
  // (compress.lookup_blend): a surface's offset read holds its own side's clusters, which its footprint holds too
  // (a'); an offset that crossed a surface reads what p does not see (b); one that ends inside a thin wall reads
  // its don't-care samples, half the far side, which a' drops
  // t1 biased along n + v, the idea of DDGI-P eq 2
  vec3 t1 = clamp((g + live * (uMaskOffset / uMaskS) * (n + giViewDir)) * uMaskS - 0.5, lo, hi);
  vec3 t0 = clamp(g * uMaskS - 0.5, lo, hi);
  vec3 l1 = t1 - cell * uMaskS + uMaskLo + 0.5;
  vec3 l0 = t0 - cell * uMaskS + uMaskLo + 0.5;
  ivec3 ic = ivec3(cell);
  int cz = int(cells.z);
  vec4 c0 = giMaskCodes(ic, 0, cz);                   // the cell's cubes, one per channel (MD §3.4.2)
  vec4 c1 = vec4(0.0);
#if KILN_MASK_CLUSTERS > 4
  if (uClusterCount > 4) c1 = giMaskCodes(ic, 1, cz);
#endif
  vec4 a0 = vec4(equal(c0, vec4(1.0))), a1 = vec4(equal(c1, vec4(1.0)));   // code 1: m = 1; code 0: m = 0
  vec4 b0 = a0, b1 = a1;
  // the channels stored in the atlas (code >= 2), in increasing k, 3 bits each (no fetches in this loop)
  int count = 0;
  int list = 0;
  for (int k = 0; k < KILN_MASK_CLUSTERS; ++k) {
    float ck = k < 4 ? c0[k] : c1[k - 4];
    if (k < uClusterCount && ck >= 2.0) {
      list |= k << (3 * count);
      count += 1;
    }
  }
  for (int i = 0; i < count; ++i) {
    int k = (list >> (3 * i)) & 7;
    float ck = k < 4 ? c0[k] : c1[k - 4];
    vec2 r = giMaskAtlasReads(int(ck) - 2, l1, l0);
    vec4 e = vec4(equal(ivec4(k & 3), ivec4(0, 1, 2, 3)));
    if (k < 4) { a0 += r.x * e; b0 += r.y * e; } else { a1 += r.x * e; b1 += r.y * e; }
  }
  vec4 v0 = a0 * min(b0 / uMaskSeen, vec4(1.0)), v1 = a1 * min(b1 / uMaskSeen, vec4(1.0));   // a'
  float seen = dot(v0 + v1, vec4(1.0));
  float s = clamp((seen / max(dot(a0 + a1, vec4(1.0)), 1e-6) - uMaskBlend.x) / (uMaskBlend.y - uMaskBlend.x), 0.0, 1.0);
  m0 = mix(b0, v0, s);
  m1 = mix(b1, v1, s);
}

// m_k E_k(n) of cluster k (L1: slots 3k, 3k+1, 3k+2 of uClusterSh, 3 fetches; L2 below: 7). Called in non-uniform control flow
// (the data-dependent loop below), where implicit derivatives are undefined: explicit LOD 0 (no mipmaps).
#ifdef KILN_SH_L2
// L2: sub-volumes 7k .. 7k + 6 of uClusterShL2 (7 fetches); `slots` = 7K.
vec3 giClusterTerm(vec3 texel, int k, float slots, float mk, vec3 n) {
  float s = 7.0 * float(k);
  vec4 s0 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s, slots), 0.0);
  vec4 s1 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s + 1.0, slots), 0.0);
  vec4 s2 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s + 2.0, slots), 0.0);
  vec4 s3 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s + 3.0, slots), 0.0);
  vec4 s4 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s + 4.0, slots), 0.0);
  vec4 s5 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s + 5.0, slots), 0.0);
  vec4 s6 = textureLod(uClusterShL2, giPaddedStackedUVW(texel, s + 6.0, slots), 0.0);
  return mk * shIrradianceL2Packed(s0, s1, s2, s3, s4, s5, s6, n);
}
const float GI_CLUSTER_SLOTS = 7.0;
#else
vec3 giClusterTerm(vec3 texel, int k, float slots, float mk, vec3 n) {
  float s = 3.0 * float(k);
  vec4 r = textureLod(uClusterSh, giStackedUVW(texel, s, slots), 0.0);
  vec4 g = textureLod(uClusterSh, giStackedUVW(texel, s + 1.0, slots), 0.0);
  vec4 b = textureLod(uClusterSh, giStackedUVW(texel, s + 2.0, slots), 0.0);
  return mk * shIrradianceL1(r, g, b, n);
}
const float GI_CLUSTER_SLOTS = 3.0;
#endif

// Σ_k m_k E_k(n) (rgb) and, when `normalized`, Σ_k m_k w_k (returned in den; else 1).
vec3 giMaskSum(vec3 p, vec3 n, bool normalized, out float den) {
  vec4 m0, m1;
  giMasks(p, n, m0, m1);
  vec3 texel = giProbeTexel(p);
  // the clusters to sample, in increasing k, 3 bits each (no fetches in this loop)
  int count = 0;
  int list = 0;
  for (int k = 0; k < KILN_MASK_CLUSTERS; ++k) {
    float mk = k < 4 ? m0[k] : m1[k - 4];
    if (k < uClusterCount && mk > 0.0) {  // sample only the clusters whose masks are marked (MD §1)
      list |= k << (3 * count);
      count += 1;
    }
  }
  float slots = GI_CLUSTER_SLOTS * float(uClusterCount);
  vec3 e = vec3(0.0);
  for (int i = 0; i < count; ++i) {
    int k = (list >> (3 * i)) & 7;
    e += giClusterTerm(texel, k, slots, k < 4 ? m0[k] : m1[k - 4], n);  // m_x · (g ⊗ P)_x, MD eq 3
  }
  den = 1.0;
  if (normalized) {
    float wslots = uClusterCount > 4 ? 2.0 : 1.0;
    den = dot(m0, texture(uClusterWeights, giStackedUVW(texel, 0.0, wslots)));
#if KILN_MASK_CLUSTERS > 4
    if (uClusterCount > 4) den += dot(m1, texture(uClusterWeights, giStackedUVW(texel, 1.0, wslots)));
#endif
  }
  return e;
}
