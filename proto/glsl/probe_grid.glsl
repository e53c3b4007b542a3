// The probe grid (proto/bundle.md section 5): probe (i, j, k) sits at origin + spacing · (i, j, k) — or, on a
// rectilinear grid (`grid.layers`), at (layers_x[i], layers_y[j], layers_z[k]) — at the centre of texel (i, j, k) of a
// probe volume (width x, height y, depth z).
uniform vec3 uGridOrigin;   // metres, bake frame (gi_view.glsl uGiFrame; = world without grid.frame)
uniform vec3 uGridSpacing;  // metres (a rectilinear grid: (last layer - first) / (counts - 1))
uniform vec3 uGridCounts;   // probes along x, y, z
uniform bool uGridRectilinear;   // the grid has layers (set by the renderers; the code is chosen by the #define below)

#ifdef KILN_GRID_RECTILINEAR
// A rectilinear grid: the renderers #define KILN_GRID_RECTILINEAR for a bake with grid.layers (a uniform grid's
// shaders hold none of this: a run-time branch cost llvmpipe 17-33% of a uniform bake's pass).
uniform highp sampler2D uGridLayers;   // R32F, width >= max(counts), height 3: texel (i, a) = layer i of axis a (metres)

// Continuous layer index of coordinate x along axis a of a rectilinear grid: i + (x - L_i) / (L_{i+1} - L_i) for the
// i in [0, n - 2] with L_i <= x < L_{i+1} (i = 0 below the first layer, n - 2 at or past the last: linear
// extrapolation, as (x - origin) / spacing extrapolates a uniform grid). Binary search: log2(n) fetches.
float giLayerCoord(float x, int a, int n) {
  int lo = 0;
  int hi = n - 1;
  while (hi - lo > 1) {
    int mid = (lo + hi) / 2;
    if (texelFetch(uGridLayers, ivec2(mid, a), 0).r <= x) lo = mid; else hi = mid;
  }
  float x0 = texelFetch(uGridLayers, ivec2(lo, a), 0).r;
  float x1 = texelFetch(uGridLayers, ivec2(lo + 1, a), 0).r;
  return float(lo) + (x - x0) / max(x1 - x0, 1e-30);
}
#endif

// Continuous probe index of bake-frame point p, unclamped: (p - origin) / spacing on a uniform grid, the layer
// coordinate on a rectilinear one (trilinear weights over the cell's 8 probes are then those of the world position
// between its layers: hardware trilinear at this texel coordinate is the rectilinear grid's trilinear interpolation).
// One-probe axes: 0. Python: workers/kernels/grid.py grid_coord.
vec3 giGridIndex(vec3 p) {
#ifdef KILN_GRID_RECTILINEAR
  vec3 g = vec3(uGridCounts.x > 1.5 ? giLayerCoord(p.x, 0, int(uGridCounts.x + 0.5)) : 0.0,
                uGridCounts.y > 1.5 ? giLayerCoord(p.y, 1, int(uGridCounts.y + 0.5)) : 0.0,
                uGridCounts.z > 1.5 ? giLayerCoord(p.z, 2, int(uGridCounts.z + 0.5)) : 0.0);
#else
  vec3 g = (p - uGridOrigin) / max(uGridSpacing, vec3(1e-30));
#endif
  return mix(vec3(0.0), g, greaterThan(uGridCounts, vec3(1.5)));
}

// Texture coordinate of bake-frame point p for hardware-trilinear sampling of a probe volume.
vec3 probeGridUVW(vec3 p) {
  return (giGridIndex(p) + 0.5) / uGridCounts;
}
