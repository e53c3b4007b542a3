// Scene surfaces: world-space position and normal for the fragment shader.
uniform mat4 modelMatrix;
uniform mat4 viewMatrix;
uniform mat4 projectionMatrix;

in vec3 position;
in vec3 normal;
in vec2 uv;
in vec4 color;                     // COLOR_0 (three.js names it "color"; a VEC3 one reads alpha 1; read only
                                   // where the fragment shader's uHasVertexColor says the mesh has one)

out vec3 vWorldPos;
out vec3 vWorldNormal;
out vec2 vUv;
out vec4 vColor;

void main() {
  vec4 world = modelMatrix * vec4(position, 1.0);
  vWorldPos = world.xyz;
  vWorldNormal = transpose(inverse(mat3(modelMatrix))) * normal;
  vUv = uv;
  vColor = color;
  gl_Position = projectionMatrix * viewMatrix * world;
}
