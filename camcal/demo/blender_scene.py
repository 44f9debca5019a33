"""Render the demo's scenes with Cycles, in a subprocess that has the bpy module.

camcal never imports bpy: :func:`render_shots` writes a JSON job and runs
``python -m camcal.demo.blender_scene JOB.json`` in a child process of the same
interpreter; only that child imports bpy (inside :func:`_main`), so importing
this module is cheap and free of Blender.

The job describes planar quads (a texture or a flat colour, emissive or
diffuse), optional sun and point lamps, and shots: a pinhole camera (camcal's ``K, R,
c, image_size``; no distortion: Cycles has none for perspective cameras),
which quads and lamps it sees, and the EXR file to write (scene-linear float, no view
transform). Cameras are set with the Blender add-on's own intrinsics mapping
(``addon/mapping.py``: ``blender_intrinsics``, ``camera_matrix_local``), so
a world point renders where ``Camera.project`` puts it (checked to < 1e-3 px
by the add-on's tests).

Conventions: world coordinates are camcal's (Blender's world is the same
space); ``x ~ K [R | -R c] X``; pixel (0, 0) is the centre of the top-left
pixel. A quad is given by its four corners in world coordinates in the order
of its texture's top-left, top-right, bottom-right, bottom-left.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from camcal.base.errors import CamcalError

__all__ = ["render_shots", "project_in_blend"]


def render_shots(job: dict, work_dir: str | os.PathLike, threads: int = 0) -> list[Path]:
    """Render every shot of ``job`` with Cycles (CPU) in a bpy subprocess.

    Parameters
    ----------
    job : dict
        ``{"samples": int, "seed": int, "quads": [...], "suns": [...],
        "points": [...], "shots": [...]}``. A quad: ``{"name", "corners":
        (4, 3) world metres, "texture": PNG or EXR path (its values used as
        they are, no colour conversion) or None, "colour": [r, g, b] linear,
        "shader": "emission" | "diffuse", "interpolation": "Closest" |
        "Linear"}``. A sun: ``{"direction": [x, y, z] the light travels
        along, "strength": W/m^2}`` and optionally a ``"name"`` (default
        ``sun0``, ``sun1``...). A point lamp (``"points"``, radius 0: no
        sampling noise): ``{"name", "position": [x, y, z], "power": W}``;
        Cycles' point lamp of power ``P`` lights a Lambertian surface of
        albedo ``a`` at distance ``d`` and incidence ``t`` to the radiance
        ``a P cos(t) / (4 pi^2 d^2)`` (a sun of strength ``S``:
        ``a S cos(t) / pi``). A shot: ``{"camera": {"K", "R", "c",
        "image_size"}, "quads": [names seen], "out": EXR path}`` and
        optionally ``"lights": [names lit]`` (default: every lamp).
    work_dir : path
        Receives the job file ``render_job.json`` and the render log.
    threads : int
        Cycles threads; 0 lets Blender use every core.

    Returns
    -------
    list of Path
        The EXR files, one per shot, in order.

    Raises
    ------
    CamcalError
        When the subprocess fails (its last error line), e.g. no bpy.
    """
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    job_path = work_dir / "render_job.json"
    job_path.write_text(json.dumps(dict(job, threads=threads)))
    log_path = work_dir / "render.log"
    with open(log_path, "w") as log:
        proc = subprocess.run([sys.executable, "-m", "camcal.demo.blender_scene", str(job_path)],
                              stdout=log, stderr=subprocess.STDOUT, text=True)
    if proc.returncode != 0:
        lines = [line for line in log_path.read_text().splitlines() if line.strip()]
        raise CamcalError(f"Blender render failed: {lines[-1] if lines else proc.returncode} (log: {log_path})")
    outputs = [Path(shot["out"]) for shot in job["shots"]]
    missing = [str(p) for p in outputs if not p.is_file()]
    if missing:
        raise CamcalError(f"Blender render wrote no {missing[0]} (log: {log_path})")
    return outputs


def project_in_blend(blend: str | os.PathLike, X, work_dir: str | os.PathLike) -> dict[str, list]:
    """Project world points with Blender's own camera matrices in a saved .blend.

    For every camera object imported by camcal (property ``camcal_camera``),
    the scene's resolution is set to the camera's (the add-on's
    ``apply_resolution``) and ``X`` is projected by ``calc_matrix_camera``
    times the inverse world matrix, in camcal pixels (centre of the
    top-left pixel at (0, 0)).

    Parameters
    ----------
    blend : path
        A .blend written by ``camcal blender import``.
    X : array_like, shape (N, 3)
        World points (the rig's coordinates; up axis Z).
    work_dir : path
        Receives the request and answer JSON files.

    Returns
    -------
    dict
        Camera name -> ``(N, 2)`` pixels as nested lists.
    """
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    request = work_dir / "project_request.json"
    answer = work_dir / "project_answer.json"
    request.write_text(json.dumps({"blend": str(Path(blend).resolve()), "X": [list(map(float, p)) for p in X],
                                   "out": str(answer)}))
    answer.unlink(missing_ok=True)
    proc = subprocess.run([sys.executable, "-m", "camcal.demo.blender_scene", "--project", str(request)],
                          capture_output=True, text=True)
    if proc.returncode != 0 or not answer.is_file():
        lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
        raise CamcalError(f"Blender projection failed: {lines[-1] if lines else proc.returncode}")
    return json.loads(answer.read_text())


def _project_main(request_path: str) -> None:  # pragma: no cover - runs in the bpy subprocess
    import bpy  # noqa: PLC0415
    from mathutils import Vector  # noqa: PLC0415

    from camcal.blender_bridge import load_addon  # noqa: PLC0415

    importer = __import__(f"{load_addon().__name__}.importer", fromlist=["importer"])
    request = json.loads(Path(request_path).read_text())
    bpy.ops.wm.open_mainfile(filepath=request["blend"])
    scene = bpy.context.scene
    out = {}
    for obj in scene.objects:
        if obj.type != "CAMERA" or "camcal_camera" not in obj:
            continue
        importer.apply_resolution(scene, obj)
        render = scene.render
        W, H = render.resolution_x, render.resolution_y
        depsgraph = bpy.context.evaluated_depsgraph_get()
        P = obj.calc_matrix_camera(depsgraph, x=W, y=H, scale_x=render.pixel_aspect_x, scale_y=render.pixel_aspect_y)
        V = obj.matrix_world.inverted()
        pixels = []
        for X in request["X"]:
            clip = P @ V @ Vector((*X, 1.0))
            ndc_x, ndc_y = clip.x / clip.w, clip.y / clip.w
            pixels.append([(ndc_x + 1.0) / 2.0 * W - 0.5, (1.0 - ndc_y) / 2.0 * H - 0.5])
        out[obj["camcal_camera"]] = pixels
    Path(request["out"]).write_text(json.dumps(out))


def _main(job_path: str) -> None:  # pragma: no cover - runs in the bpy subprocess
    """Build the scene and render every shot (the subprocess's entry point)."""
    import bpy  # noqa: PLC0415 - only in the subprocess
    from mathutils import Matrix  # noqa: PLC0415

    from camcal.blender_bridge import load_addon  # noqa: PLC0415

    mapping = __import__(f"{load_addon().__name__}.mapping", fromlist=["mapping"])
    job = json.loads(Path(job_path).read_text())
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(job["samples"])
    scene.cycles.seed = int(job["seed"])
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0
    if job.get("threads"):
        scene.render.threads_mode = "FIXED"
        scene.render.threads = int(job["threads"])
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "32"
    scene.render.film_transparent = False
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[0].default_value = (0, 0, 0, 1)
    scene.world = world

    objects = {}
    for quad in job["quads"]:
        objects[quad["name"]] = _quad(bpy, scene, quad)
    lamps = {}
    for i, sun in enumerate(job.get("suns", [])):
        name = sun.get("name", f"sun{i}")
        light = bpy.data.lights.new(name, "SUN")
        light.energy = float(sun["strength"])
        light.angle = 0.0
        obj = bpy.data.objects.new(name, light)
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = (-_vector(sun["direction"])).to_track_quat("Z", "Y")
        scene.collection.objects.link(obj)
        lamps[name] = obj
    for point in job.get("points", []):
        light = bpy.data.lights.new(point["name"], "POINT")
        light.energy = float(point["power"])
        light.shadow_soft_size = 0.0
        obj = bpy.data.objects.new(point["name"], light)
        obj.location = [float(v) for v in point["position"]]
        scene.collection.objects.link(obj)
        lamps[point["name"]] = obj

    data = bpy.data.cameras.new("camera")
    camera = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    for n, shot in enumerate(job["shots"]):
        cam = shot["camera"]
        b = mapping.blender_intrinsics(cam["K"], cam["image_size"], 36.0, "AUTO")
        data.type = "PERSP"
        data.sensor_fit = b.sensor_fit
        data.sensor_width, data.sensor_height = b.sensor_width, b.sensor_height
        data.lens, data.shift_x, data.shift_y = b.lens, b.shift_x, b.shift_y
        data.clip_start, data.clip_end = 0.01, 1000.0
        camera.matrix_world = Matrix(mapping.camera_matrix_local(cam["R"], cam["c"]))
        scene.render.resolution_x, scene.render.resolution_y = b.resolution_x, b.resolution_y
        scene.render.resolution_percentage = 100
        scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = b.pixel_aspect_x, b.pixel_aspect_y
        seen = set(shot["quads"])
        for name, obj in objects.items():
            obj.hide_render = name not in seen
        lit = set(shot.get("lights", lamps))
        for name, obj in lamps.items():
            obj.hide_render = name not in lit
        out = Path(shot["out"])
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.stem}.tmp.exr")
        scene.render.filepath = str(tmp)
        bpy.ops.render.render(write_still=True)
        os.replace(tmp, out)
        print(f"rendered {n + 1} / {len(job['shots'])}: {out}", flush=True)


def _vector(values):  # pragma: no cover - bpy subprocess
    from mathutils import Vector  # noqa: PLC0415

    return Vector([float(v) for v in values]).normalized()


def _quad(bpy, scene, quad: dict):  # pragma: no cover - bpy subprocess
    """A textured or flat-coloured quad with UVs (0, 1) at its first corner."""
    corners = [tuple(float(v) for v in corner) for corner in quad["corners"]]
    mesh = bpy.data.meshes.new(quad["name"])
    mesh.from_pydata(corners, [], [(3, 2, 1, 0)])
    uv = mesh.uv_layers.new(name="uv")
    uv_of_corner = {0: (0.0, 1.0), 1: (1.0, 1.0), 2: (1.0, 0.0), 3: (0.0, 0.0)}
    for loop in mesh.loops:
        uv.data[loop.index].uv = uv_of_corner[loop.vertex_index]
    material = bpy.data.materials.new(quad["name"])
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    output = nodes.new("ShaderNodeOutputMaterial")
    if quad["shader"] == "emission":
        shader = nodes.new("ShaderNodeEmission")
        shader.inputs["Strength"].default_value = 1.0
    else:
        shader = nodes.new("ShaderNodeBsdfDiffuse")
    colour = shader.inputs["Color"]
    if quad.get("texture"):
        image = bpy.data.images.load(quad["texture"])
        image.colorspace_settings.name = "Non-Color"
        texture = nodes.new("ShaderNodeTexImage")
        texture.image = image
        texture.interpolation = quad.get("interpolation", "Linear")
        texture.extension = "EXTEND"
        links.new(texture.outputs["Color"], colour)
    else:
        colour.default_value = (*[float(v) for v in quad["colour"]], 1.0)
    links.new(shader.outputs[0], output.inputs["Surface"])
    mesh.materials.append(material)
    obj = bpy.data.objects.new(quad["name"], mesh)
    scene.collection.objects.link(obj)
    return obj


if __name__ == "__main__":  # pragma: no cover - ``python -m camcal.demo.blender_scene [--project] JOB.json``
    if sys.argv[1] == "--project":
        _project_main(sys.argv[2])
    else:
        _main(sys.argv[1])
