// Shadow maps for the direct light (lights.glsl's lightVisibility hook): a distance cube map per point/spot
// light and an orthographic distance map per directional light, rendered with shadow_depth.*.glsl.
// Distances are stored as d / uShadowFar[i], packed into RGBA8 (shadow_depth.frag.glsl packDepth), so any
// WebGL2 device can render them. Slots: cube maps 0-3, directional maps 0-1; lights beyond are unshadowed.
// Lookups use a normal offset (against acne on surfaces facing away from the light) and 5 taps (soft edge).
#define KILN_SHADOW_CUBES 4
#define KILN_SHADOW_DIRS 2

uniform samplerCube uShadowCube0;
uniform samplerCube uShadowCube1;
uniform samplerCube uShadowCube2;
uniform samplerCube uShadowCube3;
uniform sampler2D uShadowDir0;
uniform sampler2D uShadowDir1;
uniform vec4 uShadowInfo[MAX_LIGHTS];     // x slot (-1 none), y far (metres), z normal offset (metres), w texel angle
uniform mat4 uShadowMatrix[MAX_LIGHTS];   // directional: world -> light clip space

float unpackDepth(vec4 c) {
  return dot(c, vec4(1.0, 1.0 / 255.0, 1.0 / 65025.0, 1.0 / 16581375.0));
}

float shadowCubeFetch(int slot, vec3 dir) {
  if (slot == 0) return unpackDepth(texture(uShadowCube0, dir));
  if (slot == 1) return unpackDepth(texture(uShadowCube1, dir));
  if (slot == 2) return unpackDepth(texture(uShadowCube2, dir));
  return unpackDepth(texture(uShadowCube3, dir));
}

float shadowDirFetch(int slot, vec2 uv) {
  if (slot == 0) return unpackDepth(texture(uShadowDir0, uv));
  return unpackDepth(texture(uShadowDir1, uv));
}

float lightVisibility(int i, vec3 p, vec3 n) {
  vec4 info = uShadowInfo[i];
  int slot = int(info.x);
  if (slot < 0) return 1.0;
  vec3 q = p + n * info.z;  // normal offset
  if (uLightPosType[i].w > 1.5) {  // directional: orthographic map, depth along the travel direction
    vec4 c = uShadowMatrix[i] * vec4(q, 1.0);
    vec3 s = c.xyz / c.w * 0.5 + 0.5;
    if (any(lessThan(s.xy, vec2(0.0))) || any(greaterThan(s.xy, vec2(1.0)))) return 1.0;
    float lit = 0.0;
    vec2 texel = vec2(info.w);
    for (int k = 0; k < 5; ++k) {
      vec2 o = k == 0 ? vec2(0.0) : vec2(k == 1 ? 1.0 : k == 2 ? -1.0 : 0.0, k == 3 ? 1.0 : k == 4 ? -1.0 : 0.0);
      lit += s.z - 0.002 <= shadowDirFetch(slot, s.xy + o * texel) ? 1.0 : 0.0;
    }
    return lit / 5.0;
  }
  vec3 v = q - uLightPosType[i].xyz;
  float d = length(v) / info.y;
  vec3 dir = v / max(length(v), 1e-6);
  vec3 t = normalize(cross(dir, abs(dir.y) < 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0)));
  vec3 b = cross(dir, t);
  float r = info.w;  // about one texel, in radians
  float lit = 0.0;
  for (int k = 0; k < 5; ++k) {
    vec3 o = k == 0 ? vec3(0.0) : (k == 1 ? t : k == 2 ? -t : k == 3 ? b : -b) * r;
    lit += d - 0.003 <= shadowCubeFetch(slot, dir + o) ? 1.0 : 0.0;
  }
  return lit / 5.0;
}
