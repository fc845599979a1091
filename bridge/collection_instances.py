"""Collection instances as receivers (`core.unwrap.instances`): an Empty that shows a collection
(Instancing > Collection) makes each mesh object of the collection a receiver, without a copy.

A `Member` is one (instancer, object) pair. It reads like the mesh object it shows, so the
readers (`mesh_data`, `bake_session`, `fingerprints`, the preview) take it where they take an
object: its name is "<instancer>/<object>", its mesh and materials are the object's, its
transform is the instancer's ∘ the collection's instance offset ∘ the object's (as Blender draws
and Cycles renders the instance), and its `hhd` record joins the instancer's (the atlas, its size,
the outer rectangle: where the instancer's copy of the collection's bundle lies in the atlas)
and the object's (its overrides and its inner rectangle: where it lies in the bundle).
Custom properties set on a Member (the preview's switches) go to the instancer, which the
preview's Attribute nodes read first (type Instancer).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import BakeError

SEPARATOR = "/"


def compose(outer, inner) -> tuple[float, float, float, float]:
    """The rectangle (scale u, scale v, offset u, offset v) of `inner` placed through `outer`:
    uv · inner.scale + inner.offset, then · outer.scale + outer.offset (float64)."""
    o, i = np.asarray(outer, np.float64), np.asarray(inner, np.float64)
    return (float(i[0] * o[0]), float(i[1] * o[1]), float(i[2] * o[0] + o[2]), float(i[3] * o[1] + o[3]))


def shows_collection(obj) -> bool:
    """Whether `obj` is an Empty instancing a collection."""
    return obj.type == 'EMPTY' and obj.instance_type == 'COLLECTION' and obj.instance_collection is not None


class MemberSettings:
    """The `hhd` record of a Member (module doc): atlas and its size on the instancer, overrides
    on the object, the rectangle composed (read only; Unwrap writes the two halves, `store`)."""

    def __init__(self, instancer, obj):
        self._instancer, self._obj = instancer, obj

    @property
    def atlas(self) -> str:
        return self._instancer.hhd.atlas

    @property
    def atlas_width(self) -> int:
        return self._instancer.hhd.atlas_width

    @property
    def atlas_height(self) -> int:
        return self._instancer.hhd.atlas_height

    @property
    def resolution(self) -> int:
        return self._obj.hhd.resolution

    @property
    def texel_density(self) -> float:
        return self._obj.hhd.texel_density

    @property
    def lightmap_rect(self) -> tuple[float, float, float, float]:
        return compose(self._instancer.hhd.lightmap_rect, self._obj.hhd.collection_rect)


class EvaluatedMember:
    """A Member's evaluated object: the object's evaluated mesh and materials, the instance's
    transform."""

    def __init__(self, evaluated, matrix_world):
        self._evaluated, self.matrix_world = evaluated, matrix_world

    def __getattr__(self, name):
        return getattr(self._evaluated, name)


class Member:
    """One mesh object of a collection as one instancer shows it (module doc)."""

    type = 'MESH'

    def __init__(self, instancer, obj):
        self.instancer, self.object = instancer, obj
        self.hhd = MemberSettings(instancer, obj)

    @property
    def name(self) -> str:
        return f"{self.instancer.name}{SEPARATOR}{self.object.name}"

    @property
    def collection(self):
        return self.instancer.instance_collection

    @property
    def data(self):
        return self.object.data

    @property
    def material_slots(self):
        return self.object.material_slots

    @property
    def hide_render(self) -> bool:
        return bool(self.instancer.hide_render or self.object.hide_render)

    @property
    def matrix_world(self):
        from mathutils import Matrix

        offset = Matrix.Translation(-self.collection.instance_offset)
        return self.instancer.matrix_world @ offset @ self.object.matrix_world

    @property
    def original(self):
        return self

    def evaluated_get(self, depsgraph) -> EvaluatedMember:
        instancer = self.instancer.evaluated_get(depsgraph)
        from mathutils import Matrix

        offset = Matrix.Translation(-self.collection.instance_offset)
        evaluated = self.object.evaluated_get(depsgraph)
        return EvaluatedMember(evaluated, instancer.matrix_world @ offset @ evaluated.matrix_world)

    def bundle(self) -> tuple[str, str, str]:
        """(collection, instancer, object) names: `core.unwrap.UnwrapMesh.bundle`."""
        return (self.collection.name, self.instancer.name, self.object.name)

    def store(self, atlas: str, size: tuple[int, int], inner, outer) -> None:
        """Record an unwrap: the atlas and the outer rectangle on the instancer (flagged as showing a
        baked collection), the inner rectangle on the object."""
        self.instancer.hhd.atlas = atlas
        self.instancer.hhd.atlas_width, self.instancer.hhd.atlas_height = size
        self.instancer.hhd.lightmap_rect = outer
        self.instancer.hhd.collection_instance = 1.0
        self.object.hhd.collection_rect = inner

    def __setitem__(self, key, value):
        self.instancer[key] = value

    def __getitem__(self, key):
        return self.instancer[key]

    def __contains__(self, key) -> bool:
        return key in self.instancer

    def __delitem__(self, key):
        del self.instancer[key]

    def __eq__(self, other) -> bool:
        return isinstance(other, Member) and (other.instancer, other.object) == (self.instancer, self.object)

    def __hash__(self) -> int:
        return hash(self.name)

    def __repr__(self) -> str:
        return f"<Member {self.name!r}>"


def members(instancer) -> list[Member]:
    """The Members an instancer shows: its collection's mesh objects (child collections
    included) that render, in name order. Raises BakeError naming a nested instancer (an Empty of
    the collection that shows another collection: not a receiver yet)."""
    objects = instancer.instance_collection.all_objects
    nested = sorted(o.name for o in objects if shows_collection(o))
    if nested:
        raise BakeError(
            f"collection '{instancer.instance_collection.name}' (shown by '{instancer.name}') holds "
            f"{', '.join(repr(n) for n in nested)}, which instance collections themselves: nested collection "
            "instances cannot receive lightmaps yet; use linked duplicates or Object > Apply > Make Instances Real"
        )
    return [
        Member(instancer, o) for o in sorted(objects, key=lambda o: o.name) if o.type == 'MESH' and not o.hide_render
    ]


def receivers(objects) -> list:
    """The receivers among `objects`: the mesh objects and the Members of the Empties that show a
    collection, in name order (deterministic atlas layout)."""
    out = [o for o in objects if o.type == 'MESH']
    for o in objects:
        if shows_collection(o):
            out += members(o)
    return sorted(out, key=lambda o: o.name)


def find(name: str):
    """The receiver called `name`: an object of the .blend, or a Member "<instancer>/<object>";
    None if there is none."""
    import bpy

    if name in bpy.data.objects:
        return bpy.data.objects[name]
    at = name.find(SEPARATOR)
    while at >= 0:
        instancer, obj = bpy.data.objects.get(name[:at]), bpy.data.objects.get(name[at + 1 :])
        if instancer is not None and obj is not None and shows_collection(instancer):
            if obj.name in instancer.instance_collection.all_objects:
                return Member(instancer, obj)
        at = name.find(SEPARATOR, at + 1)
    return None


def receivers_named(names: list[str]) -> list:
    """The receivers `names` stand for, in their order: an Empty that shows a collection stands
    for its Members; a name that is no receiver stays as its name (for the caller's message)."""
    out: list = []
    for name in names:
        obj = find(name)
        if obj is not None and obj.type != 'MESH' and shows_collection(obj):
            out += members(obj)
        else:
            out.append(obj if obj is not None else _Named(name))
    return out


class _Named:
    """A name that is no receiver, carried to the caller's message."""

    def __init__(self, name: str):
        self.name = name
