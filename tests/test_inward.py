"""Faces that point into their own object (core/bakepoints/inward.py, issue 60): the parity rule on small
numpy meshes (no Blender). The bakes are in tests/test_inward_blender.py."""

import numpy as np

from hhd_lightmapper.core.bakepoints import SurfaceTriangles, inward
from scenekit import meshes


def _tris(v, f, flip=None):
    """(positions (T, 3, 3), corner normals (T, 3, 3): the face normals of the winding)."""
    f = np.asarray(f).copy()
    if flip is not None:
        f[flip] = f[flip][:, ::-1]
    p = np.asarray(v, float)[f]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return p, np.repeat(n[:, None], 3, axis=1)


def _surface(*parts):
    """SurfaceTriangles of (positions, normals) parts, one object each."""
    p = np.concatenate([x[0] for x in parts])
    n = np.concatenate([x[1] for x in parts])
    obj = np.concatenate([np.full(len(x[0]), k) for k, x in enumerate(parts)])
    t = len(p)
    return SurfaceTriangles(p, n, np.zeros((t, 3, 2)), obj, np.full((t, 3), 0.5))


def test_cube_outward_is_not_flagged_and_flipped_is():
    v, f = meshes.cube(1.0, (0, 0, 0.6))
    assert not inward.inward_triangles(*_tris(v, f)).any()
    assert inward.inward_triangles(*_tris(v, f, flip=slice(None))).all()


def test_half_flipped_mesh_is_found_face_by_face():
    v, f = meshes.cube(1.0)
    flip = np.arange(12) < 6  # bottom, top and one side: half the triangles
    assert (inward.inward_triangles(*_tris(v, f, flip=flip)) == flip).all()


def test_open_plane_is_never_flagged():
    v, f = meshes.plane(2.0)
    for flip in (None, slice(None)):
        assert not inward.inward_triangles(*_tris(v, f, flip=flip)).any()


def test_room_with_a_light_inside_is_not_flagged():
    v, f = meshes.cube(4.0, (0, 0, 2))
    room = _tris(v, f, flip=slice(None))  # inward normals: a room seen from inside
    assert inward.inward_triangles(*room).all()  # no light: the same as a flipped cube
    assert not inward.inward_triangles(*room, lights=np.array([[0.3, 0.2, 3.1]])).any()
    # a light outside it does not make it a room
    assert inward.inward_triangles(*room, lights=np.array([[0.0, 0.0, 9.0]])).all()


def test_thin_two_sided_wall_and_thick_walled_room_are_not_flagged():
    v, f = meshes.cube(1.0)
    wall = _tris(v * [0.01, 3.0, 2.5], f)  # 1 cm thick, outward
    assert not inward.inward_triangles(*wall).any()
    v, f = meshes.plane(3.0)
    sheet = _tris(v[:, [2, 0, 1]], f)  # a wall modelled as two planes back to back
    for twin_faces in (f, [[0, 1, 3], [1, 2, 3]]):  # triangulated alike, or across the other diagonal
        twin = _tris(v[:, [2, 0, 1]], twin_faces, flip=slice(None))
        assert not inward.inward_triangles(*(np.concatenate([a, b]) for a, b in zip(sheet, twin))).any()
    outer = _tris(*meshes.cube(5.0))
    inner = _tris(*meshes.cube(4.6), flip=slice(None))  # the room's walls face into the room
    both = tuple(np.concatenate([a, b]) for a, b in zip(outer, inner))
    assert not inward.inward_triangles(*both).any()


def test_mirrored_object_uses_its_normals_not_its_winding():
    v, f = meshes.cube(1.0)
    p, n = _tris(v, f)
    mirrored = p * [-1.0, 1.0, 1.0]  # the winding turns round; the normals follow the mirror
    assert not inward.inward_triangles(mirrored, n * [-1.0, 1.0, 1.0]).any()
    assert inward.inward_triangles(mirrored, -n * [-1.0, 1.0, 1.0]).all()


def test_find_names_objects_counts_faces_and_flips():
    v, f = meshes.cube(1.0, (0, 0, 0.6))
    floor = _tris(*meshes.plane(10.0))
    surface = _surface(floor, _tris(v, f, flip=slice(None)), _tris(v + [3, 0, 0], f))
    surface.polygon = np.concatenate([np.arange(2), np.arange(12) // 2, np.arange(12) // 2])
    found = inward.find(surface, ["Floor", "Flipped", "Good"])
    assert [(x.name, x.faces, len(x.triangles)) for x in found] == [("Flipped", 6, 12)]
    assert "'Flipped' has 6 faces whose normals point inwards" in found[0].message()
    flipped = inward.flip(surface, found[0].triangles)
    assert not inward.find(flipped, ["Floor", "Flipped", "Good"])
    assert np.array_equal(flipped.normals[2:14], -surface.normals[2:14])


def test_flip_scene_turns_the_winding_of_the_flipped_faces_only():
    from hhd_lightmapper.core.scene import BakeScene

    v, f = meshes.cube(1.0)
    cube, _ = _tris(v, f, flip=slice(None))
    floor, _ = _tris(*meshes.plane(10.0))
    scene = BakeScene(
        np.concatenate([floor, cube]), np.full((14, 3), 0.5), texture_uv=np.arange(14 * 6.0).reshape(14, 3, 2)
    )
    out = inward.flip_scene(scene, cube[:, [1, 2, 0]])  # corners in another order: the same faces
    assert np.array_equal(out.triangles[:2], scene.triangles[:2])
    assert np.array_equal(out.triangles[2:], scene.triangles[2:][:, [0, 2, 1]])
    assert np.array_equal(out.texture_uv[2:], scene.texture_uv[2:][:, [0, 2, 1]])
    assert inward.flip_scene(scene, np.zeros((0, 3, 3))) is scene


def test_flip_scene_matches_faces_by_exact_corners_in_a_large_scene():
    """The faces matched (narrowed by corner bounds first) are exactly those whose corner multiset
    equals a flipped face's, against a plain set of sorted corner tuples: corners shuffled, -0.0
    for 0.0, near misses (one coordinate a float step away, the same bounds from other corners)
    and duplicates of a flipped face."""
    from hhd_lightmapper.core.scene import BakeScene

    rng = np.random.default_rng(7)
    tris = rng.integers(-3, 4, size=(20000, 3, 3)).astype(np.float64) * 0.5
    flipped = tris[rng.choice(len(tris), 40, replace=False)].copy()
    near = flipped[:10].copy()
    near[:, 0, 0] = np.nextafter(near[:, 0, 0], np.inf)  # one float step: not the same face
    swapped = flipped[10:20].copy()  # the same per-axis bounds, other corners: not the same face
    swapped[:, 0, 0], swapped[:, 1, 0] = flipped[10:20, 1, 0], flipped[10:20, 0, 0]
    signed = np.where(flipped[20:30] == 0.0, -0.0, flipped[20:30])  # -0.0: the same face
    extra = np.concatenate([near, swapped, signed, flipped[30:][:, [2, 0, 1]]])
    scene = BakeScene(np.concatenate([tris, extra]), np.full((len(tris) + len(extra), 3), 0.5))
    out = inward.flip_scene(scene, flipped[:, [1, 2, 0]])

    def key(t):
        return tuple(sorted(tuple(c + 0.0) for c in t))

    wanted = {key(t) for t in flipped}
    expected = np.array([key(t) in wanted for t in scene.triangles])
    changed = ~np.all(out.triangles == scene.triangles, axis=(1, 2))
    degenerate = np.all(scene.triangles[:, 1] == scene.triangles[:, 2], axis=1)  # swapping 1 and 2 changes nothing
    assert np.array_equal(changed, expected & ~degenerate)
    assert expected[len(tris) + 20 :].all() and not expected[len(tris) : len(tris) + 10].any()


def test_a_room_lit_by_an_emitter_inside_or_its_own_glowing_panel_is_not_flagged():
    from hhd_lightmapper.core.scene import BakeScene

    v, f = meshes.cube(4.0, (0, 0, 2))
    room, n = _tris(v, f, flip=slice(None))
    lamp, _ = _tris(*meshes.cube(0.2, (0.5, 0.5, 3.0)))
    for emissive in (np.arange(12, 24), np.arange(2)):  # a glowing box inside; the room's own floor
        triangles = np.concatenate([room, lamp])
        emission = np.zeros((24, 3))
        emission[emissive] = 5.0
        scene = BakeScene(triangles, np.full((24, 3), 0.5), emission=emission)
        assert not inward.inward_triangles(room, n, inward.light_points(scene)).any()


def test_parts_poking_into_each_other_are_judged_each_by_itself():
    """Two outward cubes of one object overlapping (a handle sunk into a drawer): the faces of
    each inside the other are not flagged; either cube flipped alone is found."""
    v, f = meshes.cube(1.0)
    a, b = _tris(v, f), _tris(v + [0.6, 0.3, 0.2], f)
    both = tuple(np.concatenate([x, y]) for x, y in zip(a, b))
    assert not inward.inward_triangles(*both).any()
    b_flipped = _tris(v + [0.6, 0.3, 0.2], f, flip=slice(None))
    found = inward.inward_triangles(*(np.concatenate([x, y]) for x, y in zip(a, b_flipped)))
    assert not found[:12].any() and found[12:].all()


def test_a_dense_sphere_half_flipped_is_found_by_patches():
    """A sphere of thousands of triangles with its upper half flipped: two patches (faces facing
    alike across shared edges), judged by a few faces each; every triangle of the flipped half
    is found, none of the other."""
    v, f = meshes.uv_sphere(rings=48, segments=48)
    p = np.asarray(v, float)[f]
    flip = p.mean(axis=1)[:, 2] > 0.0
    found = inward.inward_triangles(*_tris(v, f, flip=flip))
    assert len(f) > 4000 and flip.sum() > 1000
    assert np.array_equal(found, flip)


def components_by_propagation(n: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """`inward._components` in numpy (the code it replaced): minimum-label propagation with
    full pointer jumping after each step."""
    label = np.arange(n)
    while True:
        low = np.minimum(label[left], label[right])
        new = label.copy()
        np.minimum.at(new, left, low)
        np.minimum.at(new, right, low)
        while True:  # jump until every label is a root
            jumped = new[new]
            if np.array_equal(jumped, new):
                break
            new = jumped
        if np.array_equal(new, label):
            return label
        label = new


def test_components_label_each_node_with_its_components_smallest_node():
    """The compiled union-find against the numpy label propagation it replaced: chains, stars,
    self-loops, repeated pairs and isolated nodes, in random order."""
    rng = np.random.default_rng(7)
    for n, m in [(1, 0), (5, 0), (10, 3), (200, 150), (5000, 4000), (5000, 20000)]:
        left, right = rng.integers(0, n, m), rng.integers(0, n, m)
        if n == 200:  # one long chain given backwards: the worst case for label propagation
            left, right = np.arange(n - 1)[::-1] + 1, np.arange(n - 1)[::-1]
        got = inward._components(n, left, right)
        want = components_by_propagation(n, left, right)
        assert np.array_equal(got, want)
        assert (got <= np.arange(n)).all()


def test_find_on_two_threads_gives_what_one_thread_gives():
    v, f = meshes.cube(1.0, (0, 0, 0.6))
    cubes = [_tris(v + [3.0 * k, 0, 0], f, flip=slice(None) if k % 2 else None) for k in range(6)]
    sizes = [_tris(*meshes.plane(10.0))] + cubes
    surface = _surface(*sizes)
    names = ["Floor"] + [f"Cube {k}" for k in range(6)]
    one = inward.find(surface, names, threads=1)
    two = inward.find(surface, names, threads=2)
    assert [x.name for x in one] == [x.name for x in two] == ["Cube 1", "Cube 3", "Cube 5"]
    assert all(np.array_equal(a.triangles, b.triangles) for a, b in zip(one, two))
