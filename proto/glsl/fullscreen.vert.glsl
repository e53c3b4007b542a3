// One triangle covering the viewport (no vertex buffer: gl_VertexID 0, 1, 2), for screen-space passes.
void main() {
  vec2 q = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(q * 2.0 - 1.0, 0.0, 1.0);
}
