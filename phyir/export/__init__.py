"""Export of a predicted scene for external renderers (docs/export.md): the room as a glTF 2.0 mesh
with its materials, camera and lights, plus the HDR panorama as an equirect EXR.

* :mod:`phyir.export.room_mesh` — the depth panorama triangulated, split at discontinuities;
* :mod:`phyir.export.lights` — the bright sources placed in 3D as spot lights (candela);
* :mod:`phyir.export.gltf` — the binary glTF writer (pygltflib);
* :mod:`phyir.export.bundle` — :func:`export_gltf`: the .glb + .exr output set, written atomically;
* :mod:`phyir.export.blend` — :func:`write_blend`: a ready .blend, built by Blender running
  ``blender_scene.py`` (a script for Blender's Python, not imported by phyir) on that set.
"""
