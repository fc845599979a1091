"""What differs between the Blender versions we support (4.2 LTS to 5.3), in one place.

- Node trees: on 4.x a new material or world has no node tree until `use_nodes` is set; on 5.0+
  every material and world always has one, and `Material.use_nodes` / `World.use_nodes` are
  deprecated (a DeprecationWarning on every read or write, "expected to be removed in Blender
  6.0"). `ensure_node_tree` and `node_tree_of` touch the flag only on 4.x.
- EEVEE's engine id: 'BLENDER_EEVEE_NEXT' on 4.2-4.5, 'BLENDER_EEVEE' on 5.0+.
- Exiting a process that imported the 4.x `bpy` module after an add-on registered properties
  can crash (4.2: SIGSEGV while freeing classes) or hang; `exit_process` ends it without
  running those destructors on 4.x.
"""

from __future__ import annotations

import os
import sys

import bpy

#: Blender's version as (major, minor, patch).
VERSION = tuple(bpy.app.version)
#: Node trees are always present and `use_nodes` is deprecated from this version on.
ALWAYS_NODES = (5, 0, 0)


def ensure_node_tree(block):
    """The node tree of a Material or World, created on 4.x if the block has none yet."""
    if VERSION < ALWAYS_NODES and not block.use_nodes:
        block.use_nodes = True
    return block.node_tree


def node_tree_of(block):
    """The node tree that renders `block` (a Material or World), or None if it renders without
    one (4.x with `use_nodes` off)."""
    if VERSION < ALWAYS_NODES and not block.use_nodes:
        return None
    return block.node_tree


def eevee_engine() -> str:
    """The render engine id of EEVEE in the running Blender."""
    return 'BLENDER_EEVEE' if VERSION >= (5, 0, 0) else 'BLENDER_EEVEE_NEXT'


def exit_process(code: int) -> None:
    """End a process that runs the `bpy` module with exit code `code`. On 4.x the interpreter's
    normal shutdown can crash or hang inside Blender's destructors once an add-on has registered
    properties with update callbacks, which would replace the code; flush and leave directly."""
    if VERSION >= (5, 0, 0):
        sys.exit(code)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
