// Probe-grid addressing shared by the GI modes (proto/bundle.md section 5; Python: workers/kernels/samplers.py
// probe_uvw, field_uvw; workers/kernels/grid.py cell_coords). Guards one-probe axes (counts 1, spacing 0):
// there the grid coordinate is 0 (probe volumes read their single texel, refined-grid fields the middle).
#include "probe_grid.glsl"

// Continuous probe index of bake-frame point p (gi_view.glsl uGiFrame): (p - origin) / spacing, or its layer
// coordinate on a rectilinear grid (probe_grid.glsl giGridIndex); 0 on one-probe axes.
vec3 giGridCoord(vec3 p) {
  return giGridIndex(p);
}

// Texel coordinate (texel centres at integer + 0.5) of p in a probe volume, clamped to the border texel
// centres: with LINEAR filtering this equals CLAMP_TO_EDGE, and it never reads outside the volume, so
// several volumes can be stacked along z in one texture (giStackedUVW).
vec3 giProbeTexel(vec3 p) {
  return clamp(giGridCoord(p) + 0.5, vec3(0.5), uGridCounts - 0.5);  // hardware trilinear: the φ_i of MD eq 2-3
}

// uvw in a 3D texture holding `count` probe volumes stacked along z (volume `slot` at z texels
// [slot * nz, (slot + 1) * nz)): the bytes of the volumes concatenated in slot order.
vec3 giStackedUVW(vec3 texel, float slot, float count) {
  return vec3(texel.xy / uGridCounts.xy, (texel.z + slot * uGridCounts.z) / (uGridCounts.z * count));
}

// uvw of sub-volume `slot` in a 3D texture holding `count` padded probe volumes stacked along z (the sh_l2 layout
// of three.js LightProbeGrid, proto/bundle.md 5.1): sub-volume s spans z texels [s (nz + 2), (s + 1)(nz + 2)),
// its data at s (nz + 2) + 1 + k, one padding slice (a copy of the nearest data slice) at each end. `texel` from
// giProbeTexel (clamped to the data's texel centres, so the padding is never weighted).
vec3 giPaddedStackedUVW(vec3 texel, float slot, float count) {
  float slices = uGridCounts.z + 2.0;
  return vec3(texel.xy / uGridCounts.xy, (texel.z + 1.0 + slot * slices) / (slices * count));
}
