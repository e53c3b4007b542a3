// Probe spheres coloured by Mask Decomposition cluster (MD Fig 2): vState carries the cluster index g
// (bundle.md 5.2 `clusters`), 8 + g for an OFF probe (drawn dark). A fixed palette of 8 distinct colours
// (web-only debug shader: probe.vert.glsl passes aProbeState through as vState).
in vec3 vNormal;
flat in ivec3 vProbe;
flat in int vState;

out vec4 fragColor;

const vec3 PALETTE[8] = vec3[8](
  vec3(0.90, 0.10, 0.29), vec3(0.24, 0.71, 0.29), vec3(0.26, 0.39, 0.85), vec3(1.00, 0.88, 0.10),
  vec3(0.96, 0.51, 0.19), vec3(0.57, 0.12, 0.71), vec3(0.27, 0.94, 0.94), vec3(0.94, 0.20, 0.90));

void main() {
  vec3 n = normalize(vNormal);
  int g = vState;
  bool off = g >= 8;
  vec3 c = PALETTE[clamp(off ? g - 8 : g, 0, 7)];
  float shade = 0.45 + 0.55 * max(0.0, dot(n, normalize(vec3(0.4, 0.8, 0.45))));
  fragColor = vec4((off ? c * 0.3 : c) * shade, 1.0);
}
