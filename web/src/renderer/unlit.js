/**
 * Unlit meshes (KHR_materials_unlit: sky domes, backgrounds): three's GLTFLoader gives them a MeshBasicMaterial.
 * The bake leaves them out (workers/gltf/reader.py, as Blender's importer lets every ray but the camera's through
 * them), so the viewer draws them as the file says, without GI, and leaves them out of the shadow maps and of the
 * bounds those cover (a sky dome's radius would spread a sun's map over a kilometre).
 */
import { Box3 } from 'three';

/** Whether every material of `obj` (a mesh) is unlit; `kilnOriginal` is the glTF's material where ours replaced it. */
export function isUnlitMesh(obj) {
  if (!obj || !obj.isMesh || !obj.material) return false;
  const mats = Array.isArray(obj.material) ? obj.material : [obj.material];
  return mats.length > 0 && mats.every((m) => !!(m.userData?.kilnOriginal || m).isMeshBasicMaterial);
}

/** The bounds of the meshes of `root` that are not unlit (empty when there is none). */
export function litBounds(root) {
  const box = new Box3();
  if (!root) return box;
  root.updateWorldMatrix(true, true);
  root.traverse((o) => { if (o.isMesh && !isUnlitMesh(o)) box.union(new Box3().setFromObject(o, false)); });
  return box;
}
