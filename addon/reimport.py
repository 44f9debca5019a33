"""Import a rig in place: a second import of the same rig file replaces the first instead of adding to it.

:func:`import_in_place` wraps :func:`.importer.import_rig`. The rig root
records its file (``camcal_rig_path``); an earlier import of the same file in
the scene is removed first, with everything the importer made for it (its
collection's objects and their data, the root's animation, each camera's lens
clip, its ``<camera> distorted`` and ``<camera> overscan`` scenes, their
overscan camera, compositor and lens clip), then the rig is imported again
under the same collection name, in the same parent collections, and objects
of the user's that were parented to the old rig (to its root, a camera or the
points) are parented to their new counterparts. Clips the user brought
(tagged ``camcal_source_clip``, as the solve operator tags the Movie Clip it
solved) are kept.
"""

from __future__ import annotations

import os

import bpy

from . import compositor, importer, rigfile

__all__ = ["SOURCE_CLIP", "previous_imports", "remove_import", "import_in_place"]

#: Custom property of a Movie Clip the user brought (never removed with an import).
SOURCE_CLIP = "camcal_source_clip"


def _same_file(a, b):
    return os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b))


def previous_imports(scene, path):
    """The rig roots in ``scene`` imported from the rig file ``path``."""
    return [obj for obj in scene.collection.all_objects
            if "camcal_rig_path" in obj and _same_file(obj["camcal_rig_path"], path)]


def _role(obj):
    """What an imported object is, to find its counterpart in a new import: root, camera <name> or points."""
    if "camcal_rig_path" in obj:
        return ("root",)
    if "camcal_camera" in obj:
        return ("camera", obj["camcal_camera"])
    if "camcal_points" in obj:
        return ("points",)
    return None


def _collection_of(scene, root):
    """The rig's collection: the one holding its root (the importer makes one per rig)."""
    return next((c for c in root.users_collection if c != scene.collection), None)


def _owned(root, collection):
    """Every datablock an import made for the rig of ``root``."""
    ids = set()
    objects = set(collection.all_objects) if collection is not None else {root}  # the user's children stay
    for obj in list(objects):
        data = obj.data
        if obj.type != "CAMERA" or data is None or "camcal_image_size" not in data:
            continue
        clip = bpy.data.movieclips.get(data.get("camcal_clip", ""))
        if clip is not None and SOURCE_CLIP not in clip:
            ids.add(clip)
        distorted = bpy.data.scenes.get(data.get("camcal_distorted_scene", ""))
        if distorted is None:
            continue
        ids.add(distorted)
        if distorted.camera is not None:
            objects.add(distorted.camera)
        embedded = getattr(distorted, "node_tree", None)  # Blender 4.x
        tree = compositor.compositor_tree(distorted)
        if tree is None:
            continue
        if tree != embedded:
            ids.add(tree)  # Blender 5: the compositor is a node group of its own
        for node in tree.nodes:
            if node.type == "R_LAYERS" and node.scene is not None and node.scene is not distorted:
                ids.add(node.scene)
            if getattr(node, "clip", None) is not None and SOURCE_CLIP not in node.clip:
                ids.add(node.clip)
    for obj in objects:
        ids.add(obj)
        if obj.data is not None:
            ids.add(obj.data)
        if obj.animation_data is not None and obj.animation_data.action is not None:
            ids.add(obj.animation_data.action)
    if collection is not None:
        ids.add(collection)
    return ids


def remove_import(scene, root):
    """Remove the import of ``root``'s rig; returns what a new import needs to take its place.

    Returns
    -------
    dict
        ``name`` of its collection, its ``parents`` (collections), the
        user's ``children`` as ``(object, role of its old parent)``.
    """
    collection = _collection_of(scene, root)
    ids = _owned(root, collection)
    parents = []
    if collection is not None:
        parents = [c for c in (scene.collection, *bpy.data.collections) if collection.name in c.children]
    children = [(obj, _role(obj.parent)) for obj in bpy.data.objects
                if obj not in ids and obj.parent is not None and obj.parent in ids and _role(obj.parent)]
    name = collection.name if collection is not None else None
    bpy.data.batch_remove(ids=list(ids))
    return {"name": name, "parents": parents, "children": children}


def _take_place(result, place):
    """Put a new import where the removed one was: its name, its parent collections, the user's children."""
    collection = result.collection
    if place["name"] is not None:
        collection.name = place["name"]
    if place["parents"]:
        for parent in place["parents"]:
            if collection.name not in parent.children:
                parent.children.link(collection)
        if result.scene.collection not in place["parents"]:
            result.scene.collection.children.unlink(collection)
    new = {_role(obj): obj for obj in collection.all_objects if _role(obj)}
    for child, role in place["children"]:
        if role in new:
            inverse = child.matrix_parent_inverse.copy()
            child.parent = new[role]
            child.matrix_parent_inverse = inverse


def import_in_place(context_or_scene, path, *, source=None, replace=True, **options):
    """:func:`.importer.import_rig`, replacing an earlier import of the same rig file in the scene.

    Parameters
    ----------
    context_or_scene : bpy.types.Context or bpy.types.Scene
    path : str
        The ``*.rig.json`` file to import.
    source : str, optional
        The rig file to record as the import's identity (``camcal_rig_path``)
        when ``path`` is a stand-in for it (``camcal blender import`` imports
        a copy whose lenses Blender can hold); default ``path``.
    replace : bool
        Replace an earlier import of ``source`` (False: add a second one).
    **options
        Keyword options of :func:`.importer.import_rig`.

    Returns
    -------
    (importer.ImportResult, bool)
        The import, and whether it replaced an earlier one.

    Raises
    ------
    RigFileError
        A bad rig file (read before anything is removed).
    """
    scene = context_or_scene if isinstance(context_or_scene, bpy.types.Scene) else context_or_scene.scene
    record = os.path.abspath(source or path)
    rigfile.load_rig(path)  # a bad file fails before the earlier import is removed
    places = [remove_import(scene, root) for root in previous_imports(scene, record)] if replace else []
    result = importer.import_rig(scene, path, **options)
    result.root["camcal_rig_path"] = record
    if places:
        _take_place(result, places[0])
    return result, bool(places)
