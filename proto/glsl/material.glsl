// glTF materials as every ray stage reads them (workers/kernels/materials.py is the reference; a test
// checks this file against it): the diffuse GI albedo of a base colour, metallic and roughness.
//   diffuse     = base · (1 − m)                                    [glTF] Appendix B
//   + specular  = Unity's meta pass, F0 · roughness² / 2             (UnityLightmappingAlbedo)
// uSpecularGI selects the specular term: 0 none, 1 metals (base · m · r² / 2, the default),
// 2 all (F0 = mix(0.04, base, m)). uMaxAlbedo > 0 clamps each channel (scene.max_albedo).
uniform int uSpecularGI;
uniform float uMaxAlbedo;

vec3 giAlbedo(vec3 base, float metallic, float roughness) {
  float a = roughness * roughness;
  vec3 albedo = base * (1.0 - metallic);
  if (uSpecularGI == 1) albedo += base * metallic * a * 0.5;
  else if (uSpecularGI == 2) albedo += mix(vec3(0.04), base, metallic) * a * 0.5;
  if (uMaxAlbedo > 0.0) albedo = min(albedo, vec3(uMaxAlbedo));
  return albedo;
}
