// Probe spheres (debug view): one instance per probe, at its relocated position.
uniform mat4 modelMatrix;
uniform mat4 viewMatrix;
uniform mat4 projectionMatrix;
uniform float uProbeRadius;  // metres

in vec3 position;        // unit sphere
in vec3 aProbePosition;  // world space, metres (the viewer maps the bake-frame positions with uGiFrame^T)
in vec3 aProbeIndex;     // (i, j, k)
in float aProbeState;    // 0 off, 1 active, 2 sleeping

out vec3 vNormal;
flat out ivec3 vProbe;
flat out int vState;

void main() {
  vNormal = position;
  vProbe = ivec3(aProbeIndex + 0.5);
  vState = int(aProbeState + 0.5);
  vec4 world = modelMatrix * vec4(aProbePosition + position * uProbeRadius, 1.0);
  gl_Position = projectionMatrix * viewMatrix * world;
}
