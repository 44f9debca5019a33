"""The scene's compositor node tree across Blender versions.

Blender 4.x embeds it (``scene.node_tree`` with ``use_nodes``); 5.0-5.2 hold a
node group of its own (``scene.compositing_node_group``); 5.3 keeps it in a
list of compositor effects (``scene.compositor_effects``, the active one's
``node_group``) and warns that ``compositing_node_group`` goes in 6.0.
"""

from __future__ import annotations

import bpy

__all__ = ["compositor_tree", "new_compositor_tree", "tree_is_a_node_group"]


def tree_is_a_node_group(scene) -> bool:
    """Blender 5.x: the compositor tree is a data-block of its own (removed apart from the scene)."""
    return "compositing_node_group" in scene.bl_rna.properties  # hasattr would read it: a warning in 5.3


def compositor_tree(scene):
    """The tree the scene composites with, or None."""
    effects = getattr(scene, "compositor_effects", None)
    if effects is not None:  # Blender 5.3
        return effects.active.node_group if effects.active is not None else None
    if tree_is_a_node_group(scene):  # Blender 5.0-5.2
        return scene.compositing_node_group
    return scene.node_tree  # Blender 4.x


def new_compositor_tree(scene, name):
    """An empty compositor tree for ``scene`` and its output node (Group Output in 5.x, Composite in 4.x)."""
    if tree_is_a_node_group(scene):
        tree = bpy.data.node_groups.new(name, "CompositorNodeTree")
        effects = getattr(scene, "compositor_effects", None)
        if effects is not None:
            effects.new(name).node_group = tree  # a new effect is the active one
        else:
            scene.compositing_node_group = tree
        tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        out = tree.nodes.new("NodeGroupOutput")
    else:
        scene.use_nodes = True
        tree = scene.node_tree
        tree.nodes.clear()
        out = tree.nodes.new("CompositorNodeComposite")
    scene.render.use_compositing = True
    return tree, out
