// Direct irradiance from KHR_lights_punctual lights (Python reference: workers/kernels/shading.py
// direct_irradiance). Units: point/spot intensity in candela, directional in lux; colour is a linear multiplier.
//   point / spot: E = colour · I · max(0, n·l) / d² · W(d) · A(l),  W(d) = clamp(1 - (d/range)^4, 0, 1)^2
//   spot:         A = t², t = clamp((cos θ - cos θ_outer) / max(1e-3, cos θ_inner - cos θ_outer), 0, 1)
//   directional:  E = colour · I · max(0, n·(-ω)),  ω the direction the light travels
// Shadows: lightVisibility(i, p, n) in [0, 1]; define KILN_LIGHT_VISIBILITY and provide it to add shadows.
#ifndef MAX_LIGHTS
#define MAX_LIGHTS 8
#endif

uniform int uLightCount;
uniform vec4 uLightPosType[MAX_LIGHTS];   // xyz position (metres), w type: 0 point, 1 spot, 2 directional
uniform vec4 uLightDirRange[MAX_LIGHTS];  // xyz unit travel direction, w range in metres (0 = infinite)
uniform vec4 uLightColor[MAX_LIGHTS];     // rgb colour · intensity, w unused
uniform vec4 uLightCone[MAX_LIGHTS];      // x cos(inner), y cos(outer)

#ifdef KILN_LIGHT_VISIBILITY
float lightVisibility(int i, vec3 p, vec3 n);
#else
float lightVisibility(int i, vec3 p, vec3 n) { return 1.0; }
#endif

vec3 directIrradiance(vec3 p, vec3 n) {
  vec3 e = vec3(0.0);
  for (int i = 0; i < MAX_LIGHTS; ++i) {
    if (i >= uLightCount) break;
    vec4 pt = uLightPosType[i];
    vec4 dr = uLightDirRange[i];
    float scale;
    if (pt.w > 1.5) {  // directional
      scale = max(0.0, dot(n, -dr.xyz));
    } else {
      vec3 toLight = pt.xyz - p;
      float d2 = max(dot(toLight, toLight), 1e-8);
      float d = sqrt(d2);
      vec3 l = toLight / d;
      scale = max(0.0, dot(n, l)) / d2;  // I·max(0, n·l)/d²: candela -> lux
      if (dr.w > 0.0) {
        float w = clamp(1.0 - pow(d / dr.w, 4.0), 0.0, 1.0);
        scale *= w * w;  // range window W(d)
      }
      if (pt.w > 0.5) {  // spot: KHR angular attenuation
        float cosT = dot(-l, dr.xyz);
        float t = clamp((cosT - uLightCone[i].y) / max(1e-3, uLightCone[i].x - uLightCone[i].y), 0.0, 1.0);
        scale *= t * t;
      }
    }
    if (scale > 0.0) e += uLightColor[i].rgb * scale * lightVisibility(i, p, n);
  }
  return e;
}
