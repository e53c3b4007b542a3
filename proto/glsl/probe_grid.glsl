// The probe grid (proto/bundle.md section 5): probe (i, j, k) sits at origin + spacing · (i, j, k), at the
// centre of texel (i, j, k) of a probe volume (width x, height y, depth z).
uniform vec3 uGridOrigin;   // metres, bake frame (gi_view.glsl uGiFrame; = world without grid.frame)
uniform vec3 uGridSpacing;  // metres
uniform vec3 uGridCounts;   // probes along x, y, z

// Texture coordinate of bake-frame point p for hardware-trilinear sampling of a probe volume.
vec3 probeGridUVW(vec3 p) {
  return ((p - uGridOrigin) / uGridSpacing + 0.5) / uGridCounts;
}
