// Shadow-map pass: distance to the light (point/spot: radial; directional: along the travel direction, from
// the plane through uShadowOrigin) divided by uShadowFar, packed into RGBA8 (shadows.glsl unpackDepth).
uniform vec3 uShadowOrigin;     // light position (point/spot) or a point on the near plane (directional)
uniform vec3 uShadowDirection;  // directional travel direction; zero for radial distance
uniform float uShadowFar;

in vec3 vWorldPos;
out vec4 fragColor;

vec4 packDepth(float v) {
  vec4 e = fract(clamp(v, 0.0, 0.999999) * vec4(1.0, 255.0, 65025.0, 16581375.0));
  return e - e.yzww * vec4(1.0 / 255.0, 1.0 / 255.0, 1.0 / 255.0, 0.0);
}

void main() {
  vec3 v = vWorldPos - uShadowOrigin;
  float d = dot(uShadowDirection, uShadowDirection) > 0.0 ? dot(v, uShadowDirection) : length(v);
  fragColor = packDepth(d / uShadowFar);
}
