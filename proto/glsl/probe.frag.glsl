// Probe spheres: colour by state (OFF red, ACTIVE green, SLEEPING blue; DDGI-P §6) or shade each sphere with
// its own probe's SH irradiance (texelFetch: no interpolation between probes). The sphere's normal is world; the SH
// is in the bake frame (gi_view.glsl uGiFrame).
#include "common.glsl"
#include "gi_view.glsl"
#include "sh.glsl"
#include "tonemap.glsl"

uniform int uProbeColoring;  // 0 state, 1 SH irradiance
uniform highp sampler3D uShR;
uniform highp sampler3D uShG;
uniform highp sampler3D uShB;

in vec3 vNormal;
flat in ivec3 vProbe;
flat in int vState;

out vec4 fragColor;

void main() {
  vec3 n = normalize(vNormal);
  if (uProbeColoring == 1) {
    vec3 e = shIrradianceL1(texelFetch(uShR, vProbe, 0), texelFetch(uShG, vProbe, 0), texelFetch(uShB, vProbe, 0),
                            uGiFrame * n);
    fragColor = vec4(displayColor(max(e, 0.0) * INV_PI), 1.0);
    return;
  }
  vec3 c = vState == 0 ? vec3(0.85, 0.15, 0.12) : (vState == 1 ? vec3(0.15, 0.8, 0.25) : vec3(0.25, 0.4, 0.9));
  float shade = 0.45 + 0.55 * max(0.0, dot(n, normalize(vec3(0.4, 0.8, 0.45))));
  fragColor = vec4(c * shade, 1.0);
}
