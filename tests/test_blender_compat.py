"""Version differences (blender_compat) and the rule that our code raises no DeprecationWarning.

pyproject.toml turns a DeprecationWarning raised from our modules into an error for the whole
suite; these tests check that Blender really warns where we expect (so the rule has teeth) and
that our helpers do not."""

import re
import warnings
from pathlib import Path

import pytest

pytestmark = pytest.mark.bpy
ROOT = Path(__file__).resolve().parent.parent


def deprecations(action) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        action()
    return [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]


def test_node_tree_helpers_work_and_raise_no_deprecation():
    import bpy

    from hhd_lightmapper import blender_compat as bc

    mat = bpy.data.materials.new("compat")
    world = bpy.data.worlds.new("compat")
    try:
        assert deprecations(lambda: bc.ensure_node_tree(mat)) == []
        assert deprecations(lambda: bc.ensure_node_tree(world)) == []
        assert "Principled BSDF" in mat.node_tree.nodes and "Background" in world.node_tree.nodes
        assert deprecations(lambda: bc.node_tree_of(mat)) == []
        assert bc.node_tree_of(mat) is mat.node_tree
        if bc.VERSION >= bc.ALWAYS_NODES:
            # Blender's own verdict: the flag we avoid is deprecated here, so the rule has teeth
            assert deprecations(lambda: setattr(mat, "use_nodes", True))
        else:
            mat.use_nodes = False
            assert bc.node_tree_of(mat) is None  # 4.x renders it without nodes
    finally:
        bpy.data.materials.remove(mat)
        bpy.data.worlds.remove(world)


def test_eevee_engine_id_is_accepted_by_this_blender():
    import bpy

    from hhd_lightmapper import blender_compat as bc

    scene = bpy.context.scene
    before = scene.render.engine
    scene.render.engine = bc.eevee_engine()
    assert scene.render.engine == bc.eevee_engine()
    scene.render.engine = before


def test_no_deprecated_flag_outside_the_compat_module():
    """`.use_nodes` is read or written only in blender_compat.py (and by this test)."""
    offenders = []
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        if rel.parts[0].startswith((".venv", "build", "dist", "wheels")) or rel.name in (
            "blender_compat.py",
            Path(__file__).name,
        ):
            continue
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"\.use_nodes\b", line):
                offenders.append(f"{rel}:{i}: {line.strip()}")
    assert offenders == []
