// GI mode "direct": no indirect light (the baseline every other mode adds to).
vec3 giIndirectIrradiance(vec3 p, vec3 n) {
  return vec3(0.0);
}
