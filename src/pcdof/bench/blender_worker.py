"""The worker of :mod:`pcdof.bench.blender`: Blender's Defocus node, run by an interpreter that has ``bpy``.

A script of its own that imports nothing from pcdof (``bpy`` pins numpy below 2, so it often lives in an
environment of its own). It reads one request per line on stdin, a JSON object naming a folder that holds
``lin.npy`` ((H, W, 3) float32 linear colour) and ``depth.npy`` ((H, W) float32 metres) and the node's
settings; it writes ``out.npy`` there and answers with one JSON line on stdout: ``{"ok": seconds}`` or
``{"error": text}``. Its first line is ``{"ready": Blender's version}``. Blender's own prints go to stderr.
"""

import json
import os
import sys
import tempfile
import time

import numpy as np


def _compositor(bpy, scene):
    """The scene's compositing node tree, empty, and the socket its result goes to (Blender 4 and 5)."""
    if hasattr(scene, "compositing_node_group"):  # Blender 5: a node group with an image output
        tree = bpy.data.node_groups.new("pcdof", "CompositorNodeTree")
        tree.interface.new_socket(name="Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        scene.compositing_node_group = tree
        return tree, tree.nodes.new("NodeGroupOutput").inputs["Image"]
    scene.use_nodes = True  # Blender 4: the scene's own tree and a Composite node
    tree = scene.node_tree
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    return tree, tree.nodes.new("CompositorNodeComposite").inputs["Image"]


def defocus(lin, depth_m, s):
    """The Defocus node on *lin* (H, W, 3) and *depth_m* (H, W) with the settings *s*: (image, seconds)."""
    import bpy

    h, w = depth_m.shape
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
    scene.render.engine = "BLENDER_WORKBENCH"  # nothing to render: the compositor reads images only
    scene.render.compositor_device = "CPU"
    scene.render.use_compositing = True
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(s["threads"])
    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = s["sensor_width_mm"]
    cam_data.lens = s["focal_length_mm"]
    cam_data.dof.use_dof = True
    cam_data.dof.focus_distance = s["focus_distance_m"]
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    tree, output = _compositor(bpy, scene)

    def image_node(name, rgb):
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :3] = rgb
        im = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
        im.colorspace_settings.name = "Non-Color"  # the values as given: linear light, metres
        im.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())  # Blender's rows run bottom up
        node = tree.nodes.new("CompositorNodeImage")
        node.image = im
        return node

    colour, depth = image_node("colour", lin), image_node("depth", depth_m[..., None])
    node = tree.nodes.new("CompositorNodeDefocus")
    node.use_zbuffer = True
    for name in ("use_preview", "use_gamma_correction"):  # Blender 4 (5 has neither)
        if hasattr(node, name):
            setattr(node, name, False)
    node.f_stop, node.blur_max, node.z_scale = s["f_stop"], s["blur_max"], 1.0
    node.bokeh, node.angle = s["bokeh"], s["angle"]
    tree.links.new(colour.outputs["Image"], node.inputs["Image"])
    tree.links.new(depth.outputs["Image"], node.inputs["Z"])
    tree.links.new(node.outputs["Image"], output)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    seconds = time.perf_counter() - t0
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth, settings.exr_codec = "OPEN_EXR", "32", "NONE"
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "defocus.exr")
        bpy.data.images["Render Result"].save_render(path)
        result = bpy.data.images.load(path)
        result.colorspace_settings.name = "Non-Color"
        px = np.empty(h * w * 4, np.float32)
        result.pixels.foreach_get(px)
        bpy.data.images.remove(result)
    return np.ascontiguousarray(px.reshape(h, w, 4)[::-1, :, :3]), seconds


def main():
    answers = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # Blender prints a line per frame on stdout: keep it out of the answers

    def answer(**kw):
        answers.write(json.dumps(kw) + "\n")

    try:
        import bpy
    except Exception as exc:  # reported to the caller
        answer(error=f"import bpy failed: {exc}")
        return 1
    answer(ready=bpy.app.version_string)
    for line in sys.stdin:
        try:
            req = json.loads(line)
            folder = req["folder"]
            image, seconds = defocus(np.load(os.path.join(folder, "lin.npy")),
                                     np.load(os.path.join(folder, "depth.npy")), req["settings"])
            np.save(os.path.join(folder, "out.npy"), image.astype(np.float32))
            answer(ok=seconds)
        except Exception as exc:  # reported to the caller
            answer(error=f"{type(exc).__name__}: {exc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
