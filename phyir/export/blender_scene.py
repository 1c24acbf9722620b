"""Build a ready Blender scene from an exported set (``OUT.glb`` + ``OUT_env.exr``, docs/export.md).

This file runs inside Blender, not in phyir: ``phyir export SCENE --blend OUT.blend`` runs it as
``blender --background --factory-startup --python blender_scene.py -- --glb OUT.glb --out OUT.blend``.
From Blender's own UI: open it in the *Scripting* workspace's Text editor (*Text › Open*), set
``GLB`` below to the exported .glb (its EXR is found beside it), and *Text › Run Script*: the scene
``room`` is added to the open file.  It uses only Blender's Python (bpy, the glTF importer, the
standard library), so it runs without phyir installed.

What it builds (one scene, Cycles):

* the glb imported (room, camera, lights, objects) into the collections ``room``, ``lights``,
  ``objects`` — glTF's +y up becomes Blender's +z up, the panorama's centre looks along +y;
* **world**: the EXR as environment, turned -90 degrees about z (Cycles' equirect centre faces +x);
* **room**: a shadow catcher; rays that leave the objects see it as photographed (emission: the EXR
  through the mesh's UVs, or the glb's texture, one ``Mix Shader`` factor apart), camera rays see a
  white diffuse surface, so the catcher shows the light the objects take away and add;
* **lights**: as the export's energy table says — with the EXR emission (the default) the whole
  panorama is in the room already, so the ``lights`` collection is disabled in renders;
* **compositing over the photograph**: the view layer ``photograph`` renders the world alone (its
  Environment pass: the panorama seen through the camera), the view layer ``objects`` the objects
  and the catcher; the compositor multiplies the photograph by the Shadow Catcher pass and lays the
  objects over it (Alpha Over).
"""

import json
import math
import os
import re
import struct
import sys

# From Blender's UI: the exported .glb, e.g. "/home/me/room.glb"; EXR: its panorama when not beside it.
GLB = ""
EXR = ""
EMISSION = "exr"  # "exr": the room emits the EXR, lights off; "glb": the glb's texture + the lights

MARK = "phyir-blend:"  # the lines phyir reads back: "phyir-blend: error: ..." or "phyir-blend: {json}"
LAYERS = ("objects", "photograph")
RESOLUTION_Y = 720
SAMPLES = 128
PHOTO_SAMPLES = 16  # the photograph layer only looks up the world: anti-aliasing is all it needs


class SceneError(Exception):
    """What a user can fix (a missing file, no numpy for Blender's Python): one line, no traceback."""


def parse_args(argv):
    import argparse

    p = argparse.ArgumentParser(prog="blender_scene.py", description=__doc__.splitlines()[0])
    p.add_argument("--glb", required=True)
    p.add_argument("--exr", default=None, help="the panorama (default: the one the glb names, beside it)")
    p.add_argument("--out", default=None, help="the .blend to write (default: build only)")
    p.add_argument("--exr-name", default=None,
                   help="the EXR's path in the .blend, relative to it (default: where it is read from)")
    p.add_argument("--emission", choices=("exr", "glb"), default="exr")
    p.add_argument("--numpy-path", default=None,
                   help="a folder with numpy, used when Blender's Python has none and its version is "
                        "--numpy-python")
    p.add_argument("--numpy-python", default=None, metavar="X.Y")
    return p.parse_args(argv)


def ensure_numpy(path=None, python=None):
    """Blender's glTF importer needs numpy.  A Blender built against the system's Python (Debian's)
    has it only if the system does; ``path`` (numpy of the same Python version) is used then."""
    try:
        import numpy  # noqa: F401
        return
    except ImportError:
        pass
    here = "{}.{}".format(*sys.version_info[:2])
    if path and python == here:
        sys.path.append(path)
        try:
            import numpy  # noqa: F401
            return
        except ImportError:
            sys.path.remove(path)
    other = f" (phyir's numpy is for Python {python})" if path and python != here else ""
    raise SceneError(f"Blender's Python {here} has no numpy, which its glTF importer needs{other}: "
                     f"install it for that Python (Debian: apt-get install python3-numpy)")


def patch_importer_numpy():
    """Blender 3.x's glTF importer (3.4: ``gltf2_blender_mesh.set_poly_smoothing``) writes
    ``np.bool``, an alias numpy removed in 1.24 and brought back in 2.0; with numpy 1.24-1.26 (e.g.
    Debian 12's python3-numpy) the import stops there.  Give that numpy the alias back; Blender 4
    and any numpy that has it are left alone."""
    import bpy
    import numpy as np

    if bpy.app.version < (4, 0, 0) and "bool" not in np.__dict__:
        np.bool = np.bool_
        return True
    return False


def read_glb_json(path):
    """The JSON chunk of a binary glTF."""
    with open(path, "rb") as f:
        head = f.read(20)
        if len(head) < 20 or head[:4] != b"glTF" or head[16:20] != b"JSON":
            raise SceneError(f"{path}: not a binary glTF (.glb)")
        try:
            return json.loads(f.read(struct.unpack("<I", head[12:16])[0]))
        except ValueError as e:
            raise SceneError(f"{path}: a damaged binary glTF ({e})") from None


def environment_of(glb_path, doc):
    name = ((doc.get("extras") or {}).get("phyir") or {}).get("environment")
    if not name:
        raise SceneError(f"{glb_path}: names no environment EXR (not written by phyir export?): give it")
    return os.path.join(os.path.dirname(os.path.abspath(glb_path)), name)


def base_name(name):
    return re.sub(r"\.\d{3}$", "", name)


def new_scene(background):
    """An empty file in the background (``blender --background``), a new scene ``room`` in the UI."""
    import bpy

    if background:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        scene.name = "room"
        return scene
    scene = bpy.data.scenes.new("room")
    bpy.context.window.scene = scene
    return scene


def import_glb(scene, path):
    """Import the glb into ``scene``; its new objects by their glTF names."""
    import bpy

    before = set(bpy.data.objects)
    patched = patch_importer_numpy()
    result = bpy.ops.import_scene.gltf(filepath=path)
    if "FINISHED" not in result:
        raise SceneError(f"{path}: Blender's glTF importer failed ({', '.join(result)})")
    new = {base_name(o.name): o for o in bpy.data.objects if o not in before}
    if "room" not in new or "camera" not in new:
        raise SceneError(f"{path}: no room or camera node (not written by phyir export?)")
    return new, patched


def collect(scene, name, objects):
    """Move ``objects`` into a new collection ``name`` of ``scene``."""
    import bpy

    col = bpy.data.collections.new(name)
    scene.collection.children.link(col)
    for o in objects:
        for c in list(o.users_collection):
            c.objects.unlink(o)
        col.objects.link(o)
    return col


def node(tree, kind, x, y, **props):
    n = tree.nodes.new(kind)
    n.location = (x, y)
    for k, v in props.items():
        setattr(n, k, v)
    return n


def setup_world(scene, image):
    """World = the EXR, turned so that the panorama's centre (Blender +y) looks up its centre column:
    Cycles' equirect lookup has u = 0.5 - atan2(y, x) / 2pi, centred on +x, so the direction is
    turned by -90 degrees about z first."""
    import bpy

    world = bpy.data.worlds.new("panorama")
    world.use_nodes = True
    scene.world = world
    t = world.node_tree
    t.nodes.clear()
    coords = node(t, "ShaderNodeTexCoord", -800, 0)
    mapping = node(t, "ShaderNodeMapping", -600, 0, vector_type="VECTOR", name="Rotation",
                   label="panorama centre -> +y")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, -math.pi / 2)
    env = node(t, "ShaderNodeTexEnvironment", -350, 0, image=image, name="Panorama")
    bg = node(t, "ShaderNodeBackground", -50, 0)
    out = node(t, "ShaderNodeOutputWorld", 150, 0)
    t.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    t.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    t.links.new(env.outputs["Color"], bg.inputs["Color"])
    t.links.new(bg.outputs["Background"], out.inputs["Surface"])
    return world


def room_material(exr_image, glb_image, glb_strength, emission):
    """Emission for the rays that light the objects, white diffuse for camera rays (the catcher).

    ``Emission Source`` (a Mix Shader): factor 0 = the EXR (whole panorama; lights off), 1 = the glb's
    texture x its strength (the panorama without its bright sources; lights on)."""
    import bpy

    mat = bpy.data.materials.new("room_catcher")
    mat.use_nodes = True
    t = mat.node_tree
    t.nodes.clear()
    uv = node(t, "ShaderNodeUVMap", -1000, 0, uv_map="UVMap")
    exr = node(t, "ShaderNodeTexImage", -750, 150, image=exr_image, extension="EXTEND", name="EXR")
    e_exr = node(t, "ShaderNodeEmission", -450, 150, name="Emission EXR")
    t.links.new(uv.outputs["UV"], exr.inputs["Vector"])
    t.links.new(exr.outputs["Color"], e_exr.inputs["Color"])
    e_exr.inputs["Strength"].default_value = 1.0
    e_glb = node(t, "ShaderNodeEmission", -450, -100, name="Emission glb")
    e_glb.inputs["Strength"].default_value = glb_strength
    if glb_image is not None:
        tex = node(t, "ShaderNodeTexImage", -750, -100, image=glb_image, extension="EXTEND", name="glb")
        t.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        t.links.new(tex.outputs["Color"], e_glb.inputs["Color"])
    source = node(t, "ShaderNodeMixShader", -200, 50, name="Emission Source",
                  label="Emission source: 0 EXR (lights off), 1 glb texture (lights on)")
    source.inputs["Fac"].default_value = 1.0 if emission == "glb" else 0.0
    t.links.new(e_exr.outputs["Emission"], source.inputs[1])
    t.links.new(e_glb.outputs["Emission"], source.inputs[2])
    path = node(t, "ShaderNodeLightPath", -200, 300)
    white = node(t, "ShaderNodeBsdfDiffuse", -200, -250, name="Catcher")
    white.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    split = node(t, "ShaderNodeMixShader", 50, 50, name="Camera Rays", label="camera rays: the catcher")
    t.links.new(path.outputs["Is Camera Ray"], split.inputs["Fac"])
    t.links.new(source.outputs["Shader"], split.inputs[1])
    t.links.new(white.outputs["BSDF"], split.inputs[2])
    out = node(t, "ShaderNodeOutputMaterial", 300, 50)
    t.links.new(split.outputs["Shader"], out.inputs["Surface"])
    return mat


def glb_emission(doc, room_obj):
    """The glb's emissive texture (the image the importer made) and strength x factor."""
    mat = next(m for m in doc.get("materials", []) if m.get("name") == "room_photo")
    strength = mat.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1)
    strength *= max(mat.get("emissiveFactor", [1.0]))
    image = None
    for slot in room_obj.material_slots:
        if slot.material and slot.material.use_nodes:
            image = next((n.image for n in slot.material.node_tree.nodes
                          if n.bl_idname == "ShaderNodeTexImage" and n.image is not None), image)
    return image, float(strength)


def setup_room(room, mat):
    room.data.materials.clear()
    room.data.materials.append(mat)
    room.is_shadow_catcher = True


def setup_render(scene, camera, aspect):
    scene.render.engine = "CYCLES"
    scene.camera = camera
    scene.cycles.device = "CPU"
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = False
    scene.render.film_transparent = True  # the catcher and the world: transparent in ``objects``
    scene.render.resolution_y = RESOLUTION_Y
    scene.render.resolution_x = int(round(RESOLUTION_Y * aspect))
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"  # the photograph as it is, not a film curve


def setup_layers(scene, hidden_in_photo):
    """View layers ``objects`` (the catcher's passes) and ``photograph`` (the world alone)."""
    objects = scene.view_layers[0]
    objects.name = LAYERS[0]
    objects.cycles.use_pass_shadow_catcher = True
    photo = scene.view_layers.new(LAYERS[1])
    photo.use_pass_environment = True
    photo.samples = PHOTO_SAMPLES
    for col in hidden_in_photo:
        photo.layer_collection.children[col.name].exclude = True
    return objects, photo


def socket(sockets, identifier):
    """A socket by its identifier (the Mix node has several sockets of one name, one per type)."""
    return next(s for s in sockets if s.identifier == identifier)


def compositor_tree(scene):
    """The scene's compositing node tree: ``scene.node_tree`` up to Blender 4, a node group with an
    ``Image`` output from Blender 5 on."""
    import bpy

    scene.render.use_compositing = True
    if hasattr(scene, "node_tree"):
        scene.use_nodes = True
        scene.node_tree.nodes.clear()
        return scene.node_tree, False
    tree = bpy.data.node_groups.new("photograph_composite", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    scene.compositing_node_group = tree
    return tree, True


def setup_compositor(scene):
    """photograph.Env x objects.Shadow Catcher, then objects.Image over it (Alpha Over)."""
    t, group = compositor_tree(scene)
    objects = node(t, "CompositorNodeRLayers", -500, 200, scene=scene, layer=LAYERS[0], name="objects")
    photo = node(t, "CompositorNodeRLayers", -500, -250, scene=scene, layer=LAYERS[1], name="photograph")
    label = "photograph x Shadow Catcher"
    over = node(t, "CompositorNodeAlphaOver", 100, 50, name="Objects Over")
    if group:  # Blender 5: the general Mix node; Alpha Over's inputs are named; a group output
        shadow = node(t, "ShaderNodeMix", -150, -50, data_type="RGBA", blend_type="MULTIPLY", name="Shadows",
                      label=label)
        socket(shadow.inputs, "Factor_Float").default_value = 1.0
        a, b = socket(shadow.inputs, "A_Color"), socket(shadow.inputs, "B_Color")
        result = socket(shadow.outputs, "Result_Color")
        back, front = over.inputs["Background"], over.inputs["Foreground"]
        out = node(t, "NodeGroupOutput", 350, 50).inputs["Image"]
    else:
        shadow = node(t, "CompositorNodeMixRGB", -150, -50, blend_type="MULTIPLY", name="Shadows",
                      label=label)
        shadow.inputs["Fac"].default_value = 1.0
        a, b, result = shadow.inputs[1], shadow.inputs[2], shadow.outputs["Image"]
        back, front = over.inputs[1], over.inputs[2]
        out = node(t, "CompositorNodeComposite", 350, 50).inputs["Image"]
    view = node(t, "CompositorNodeViewer", 350, -150)
    t.links.new(next(o for o in photo.outputs if o.name in ("Env", "Environment")), a)  # 3.x-4.x, 5
    t.links.new(objects.outputs["Shadow Catcher"], b)
    t.links.new(result, back)
    t.links.new(objects.outputs["Image"], front)
    t.links.new(over.outputs["Image"], out)
    t.links.new(over.outputs["Image"], view.inputs["Image"])


def build(glb, exr=None, out=None, exr_name=None, emission="exr"):
    """Build the scene (see the module doc) and save it to ``out`` if given; a summary dict."""
    import bpy
    import numpy

    if not os.path.isfile(glb):
        raise SceneError(f"{glb}: no such file")
    doc = read_glb_json(glb)
    exr = exr or environment_of(glb, doc)
    if not os.path.isfile(exr):
        raise SceneError(f"{exr}: no such file (the panorama EXR of {glb})")
    scene = new_scene(bpy.app.background)
    new, patched = import_glb(scene, glb)
    room, camera = new["room"], new["camera"]
    lights = [o for k, o in new.items() if k == "lights" or (o.type == "LIGHT")]
    objects = [o for k, o in new.items() if k.startswith("object_")]
    cols = [collect(scene, "room", [room]), collect(scene, "objects", objects),
            collect(scene, "lights", lights)]
    cols[2].hide_render = emission == "exr"  # the energy table: EXR emission carries the lamps' light

    image = bpy.data.images.load(os.path.abspath(exr), check_existing=False)
    image.name = os.path.basename(exr_name or exr)
    setup_world(scene, image)
    glb_image, strength = glb_emission(doc, room)
    setup_room(room, room_material(image, glb_image, strength, emission))
    cams = doc.get("cameras") or [{}]
    setup_render(scene, camera, cams[0].get("perspective", {}).get("aspectRatio") or 1.5)
    setup_layers(scene, cols)
    setup_compositor(scene)
    for img in bpy.data.images:  # one self-contained file: the glb's textures and the EXR inside
        if img.source == "FILE" and img.packed_file is None:
            img.pack()
    if exr_name:  # where Blender looks for the EXR (or unpacks it to), relative to the .blend
        image.filepath_raw = "//" + exr_name.replace(os.sep, "/")
    if out:
        if bpy.app.background:  # no OUT.blend1 of the (empty) file being replaced
            bpy.context.preferences.filepaths.save_version = 0
        result = bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(out), compress=True,
                                              relative_remap=False)
        if "FINISHED" not in result:
            raise SceneError(f"{out}: Blender could not save the file")
    return {"blender": bpy.app.version_string, "room": room.name, "camera": camera.name,
            "lights": sum(o.type == "LIGHT" for o in lights), "lights_render": emission == "glb",
            "objects": [o.name for o in objects], "numpy": numpy.__version__, "numpy_alias_patched": patched}


def main(argv=None):
    """From ``blender --python THIS -- ARGS`` (the arguments after ``--``), or from the UI (``GLB``)."""
    argv = sys.argv[sys.argv.index("--") + 1:] if argv is None and "--" in sys.argv else argv
    if argv is None:
        if not GLB:
            raise SceneError("set GLB at the top of this script to the exported .glb, then run it again")
        args = parse_args(["--glb", GLB, *(["--exr", EXR] if EXR else []), "--emission", EMISSION])
    else:
        args = parse_args(argv)
    ensure_numpy(args.numpy_path, args.numpy_python)
    return build(args.glb, args.exr, args.out, args.exr_name, args.emission)


if __name__ == "__main__":
    import bpy

    try:
        summary = main()
    except SceneError as e:
        print(f"{MARK} error: {e}", file=sys.stderr, flush=True)
        if bpy.app.background:
            sys.exit(1)
        raise
    print(f"{MARK} {json.dumps(summary)}", flush=True)
