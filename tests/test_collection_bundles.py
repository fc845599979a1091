"""Collection instances in the core unwrap (`core.unwrap.instances.Bundle`, no bpy): the members of a
collection are placed together once per instancer. Two members (a box and a wedge) shown by
three instancers, beside a linked duplicate of the box: every member's rectangle is its
instancer's outer rectangle composed with an inner rectangle that is the same for every
instancer, on whole texels; the copies do not overlap; a one-instancer collection is instanced
too; instancers showing different members are refused by name."""

import numpy as np
import pytest

from hhd_lightmapper.core import unwrap
from hhd_lightmapper.core.errors import BakeError

BOX_T = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
     [3, 0, 4], [3, 4, 7]]
)  # fmt: skip
WEDGE_T = np.array([[0, 2, 1], [3, 4, 5], [0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [2, 0, 3], [2, 3, 5]])


def box(offset, size=(0.6, 0.4, 0.3)):
    corners = np.array([[x, y, z] for z in (0, 1) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1))], float)
    return corners * size + offset


def wedge(offset):
    p = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.4], [0.5, 0, 0.4], [0, 0.5, 0.4]], float)
    return p + offset


def meshes(shown=None):
    out = []
    for k, e in enumerate(("E1", "E2", "E3")):
        origin = np.array([3.0 * k, 0.0, 0.0])
        for member, positions, tris, mesh in (("Box", box, BOX_T, "BoxMesh"), ("Wedge", wedge, WEDGE_T, "WedgeMesh")):
            if shown is not None and (e, member) not in shown:
                continue
            out.append(
                unwrap.UnwrapMesh(f"{e}/{member}", positions(origin), tris, instance_of=mesh, bundle=("Set", e, member))
            )
    out.append(unwrap.UnwrapMesh("LooseBox", box(np.array([0.0, 4.0, 0.0])), BOX_T, instance_of="BoxMesh"))
    out.append(unwrap.UnwrapMesh("Floor", box(np.array([-2.0, -2.0, -0.1]), (10.0, 10.0, 0.1)), BOX_T))
    return out


def test_members_are_placed_together_per_instancer():
    result = unwrap.unwrap(meshes(), unwrap.UnwrapSettings(resolution=256, padding=2))
    by_name = {o.name: o for o in result.objects}
    atlas = by_name["E1/Box"].atlas
    assert result.instanced[atlas] and by_name["Floor"].atlas != atlas
    w, h = result.atlas_sizes[atlas]
    inner = {}
    for name, o in by_name.items():
        if "/" not in name:
            continue
        e, member = name.split("/")
        s_o, s_i = np.array(o.outer), np.array(o.inner)
        composed = np.concatenate([s_i[:2] * s_o[:2], s_i[2:] * s_o[:2] + s_o[2:]])
        assert np.allclose(composed, o.instance, atol=1e-9), name
        inner.setdefault(member, set()).add(tuple(o.inner))
        corner = np.array(o.instance[2:]) * (w, h)
        assert np.allclose(corner, np.round(corner), atol=1e-6)  # whole texels
        assert np.allclose(o.uv, o.layer * np.array(o.instance[:2]) + np.array(o.instance[2:]), atol=1e-6)
    assert all(len(v) == 1 for v in inner.values())  # one inner rectangle per member, whatever the instancer
    assert by_name["LooseBox"].inner is None and by_name["LooseBox"].instance is not None
    assert np.array_equal(by_name["LooseBox"].layer, by_name["E2/Box"].layer)  # one layout per mesh
    boxes = [o.rect for o in result.objects if o.atlas == atlas]
    for i, a in enumerate(boxes):  # the copies' texel rectangles never overlap
        for b in boxes[i + 1 :]:
            assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1], (a, b)


def test_one_instancer_is_an_instance_and_different_members_are_refused():
    one = unwrap.unwrap(meshes({("E1", "Box"), ("E1", "Wedge")}), unwrap.UnwrapSettings(resolution=256, padding=2))
    assert {o.name: o.inner is not None for o in one.objects}["E1/Wedge"]
    with pytest.raises(BakeError, match="instances of collection 'Set' show different objects"):
        unwrap.unwrap(
            meshes({("E1", "Box"), ("E1", "Wedge"), ("E2", "Box")}), unwrap.UnwrapSettings(resolution=256, padding=2)
        )
