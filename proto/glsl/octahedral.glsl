// Octahedral direction encoding with the fold on +Z (Cigolle et al. 2014: the probe maps of DDGI-I §3.1;
// RTXGI DDGIGetOctahedralCoordinates).
// Python reference: workers/kernels/octahedral.py (oct_encode, oct_decode); layout: proto/bundle.md 5.1.

vec2 octSignNotZero(vec2 v) {
  return vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
}

// Direction (non-zero, any length) -> uv in [-1, 1]^2.
vec2 octEncode(vec3 d) {
  vec2 p = d.xy / (abs(d.x) + abs(d.y) + abs(d.z));  // onto the octahedron |x|+|y|+|z| = 1
  return d.z < 0.0 ? (1.0 - abs(p.yx)) * octSignNotZero(p) : p;  // lower hemisphere: fold the corners out
}

// uv in [-1, 1]^2 -> unit direction.
vec3 octDecode(vec2 uv) {
  uv = clamp(uv, -1.0, 1.0);
  float z = 1.0 - abs(uv.x) - abs(uv.y);
  vec2 xy = z < 0.0 ? (1.0 - abs(uv.yx)) * octSignNotZero(uv) : uv;  // unfold the corners
  return normalize(vec3(xy, z));
}

// Texture coordinate (0..1) in an atlas of tiles of (n + 2)^2 texels (1-texel border), probe (i, j, k):
// the tile starts at row j·t and column (k·nx + i)·t (proto/bundle.md 5.1, "Atlas tiling").
vec2 octAtlasUV(vec3 dir, ivec3 probe, int nx, int n, vec2 atlasSize) {
  float t = float(n + 2);
  vec2 tileOrigin = vec2(float(probe.z * nx + probe.x), float(probe.y)) * t;
  vec2 texel = tileOrigin + 1.0 + (octEncode(dir) + 1.0) * 0.5 * float(n);  // interior starts 1 texel in
  return texel / atlasSize;
}

// The same texel for an atlas whose tile columns wrap after `columns` tiles (0: no wrap, octAtlasUV's layout): tile
// c = k·nx + i goes to column c mod columns of row block c div columns, the blocks stacked below one another (ny
// tiles high each). A renderer re-packs an atlas wider than its device's MAX_TEXTURE_SIZE this way
// (workers/render/shading.py wrap_atlas: the 53 x 8 x 53 automatic grid of sealed-box is 28,090 texels wide,
// 16,384 on llvmpipe and most GPUs); the tiles and their borders are unchanged, so filtering is too.
vec2 octAtlasUVWrapped(vec3 dir, ivec3 probe, ivec3 counts, int n, int columns, vec2 atlasSize) {
  int c = probe.z * counts.x + probe.x;
  int col = columns > 0 ? c - (c / columns) * columns : c;
  int row = probe.y + (columns > 0 ? (c / columns) * counts.y : 0);
  float t = float(n + 2);
  vec2 texel = vec2(float(col), float(row)) * t + 1.0 + (octEncode(dir) + 1.0) * 0.5 * float(n);
  return texel / atlasSize;
}
