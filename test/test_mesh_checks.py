"""check_mesh on hand-made meshes with known answers."""

import json

import numpy as np
import pytest
import trimesh

from sfs_ros.core.meshing.mesh_checks import (
    _closed_topology,
    _open_topology,
    _referenced,
    check_mesh,
)
from sfs_ros.core.outline import edge_faces

from tolerances import ROUND_OFF

#: Unit cube corners, index = x + 2 y + 4 z.
CUBE_VERTICES = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=float)
#: Two triangles per side, counter-clockwise seen from outside.
CUBE_FACES = np.array([
    [0, 2, 3], [0, 3, 1],  # z = 0, normal -z
    [4, 5, 7], [4, 7, 6],  # z = 1, normal +z
    [0, 1, 5], [0, 5, 4],  # y = 0, normal -y
    [2, 6, 7], [2, 7, 3],  # y = 1, normal +y
    [0, 4, 6], [0, 6, 2],  # x = 0, normal -x
    [1, 3, 7], [1, 7, 5],  # x = 1, normal +x
], dtype=np.int64)


def test_tetrahedron():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    r = check_mesh(vertices, faces)
    assert (r.n_vertices, r.n_faces) == (4, 4)
    assert r.watertight and r.edge_manifold and r.vertex_manifold and r.consistently_oriented
    assert r.outward is True
    assert (r.n_boundary_loops, r.n_components, r.euler_characteristic, r.genus) == (0, 1, 2, 0)
    assert r.volume_m3 == pytest.approx(1.0 / 6.0, abs=ROUND_OFF)
    # Three right triangles of area 1/2 and an equilateral one of side sqrt(2).
    assert r.area_m2 == pytest.approx(1.5 + np.sqrt(3.0) / 2.0, abs=ROUND_OFF)
    assert (r.degenerate_faces, r.duplicate_faces) == (0, 0)


def test_cube():
    r = check_mesh(CUBE_VERTICES, CUBE_FACES)
    assert r.watertight and r.vertex_manifold and r.consistently_oriented and r.outward is True
    assert (r.euler_characteristic, r.genus, r.n_components) == (2, 0, 1)
    assert r.volume_m3 == pytest.approx(1.0, abs=ROUND_OFF)
    assert r.area_m2 == pytest.approx(6.0, abs=ROUND_OFF)


def test_inside_out_cube_is_not_outward():
    r = check_mesh(CUBE_VERTICES, CUBE_FACES[:, ::-1])
    assert r.watertight and r.consistently_oriented
    assert r.outward is False
    assert r.volume_m3 == pytest.approx(-1.0, abs=ROUND_OFF)


def test_cube_with_one_side_removed_has_one_hole():
    r = check_mesh(CUBE_VERTICES, CUBE_FACES[2:])
    assert not r.watertight and r.edge_manifold and r.consistently_oriented
    assert r.vertex_manifold  # boundary vertices are open fans
    assert r.n_boundary_loops == 1
    # A disc: V - E + F = 8 - 17 + 10.
    assert r.euler_characteristic == 1
    assert r.outward is None and r.genus is None


def test_open_tube_has_two_holes():
    r = check_mesh(CUBE_VERTICES, CUBE_FACES[4:])  # no z = 0 and z = 1 sides
    assert r.n_boundary_loops == 2 and r.euler_characteristic == 0


def test_cube_with_one_face_flipped_is_not_consistently_oriented():
    faces = CUBE_FACES.copy()
    faces[5] = faces[5, ::-1]
    r = check_mesh(CUBE_VERTICES, faces)
    assert r.watertight and r.edge_manifold and r.vertex_manifold
    assert not r.consistently_oriented
    assert r.outward is None and r.genus is None


def test_two_cubes_sharing_a_vertex_are_not_vertex_manifold():
    # Second cube [1, 2]^3; its corner 0 is the first cube's corner 7.
    vertices = np.vstack([CUBE_VERTICES, CUBE_VERTICES[1:] + 1.0])
    index = np.r_[7, np.arange(8, 15)]
    faces = np.vstack([CUBE_FACES, index[CUBE_FACES]])
    r = check_mesh(vertices, faces)
    assert r.watertight and r.edge_manifold and r.consistently_oriented
    assert not r.vertex_manifold
    assert r.n_components == 1  # joined through the shared vertex
    assert r.genus is None
    assert r.volume_m3 == pytest.approx(2.0, abs=ROUND_OFF)


def test_two_separate_cubes():
    vertices = np.vstack([CUBE_VERTICES, CUBE_VERTICES + 3.0])
    faces = np.vstack([CUBE_FACES, CUBE_FACES + 8])
    r = check_mesh(vertices, faces)
    assert r.vertex_manifold and r.n_components == 2
    # Two spheres: chi = 4, total genus 0.
    assert (r.euler_characteristic, r.genus) == (4, 0)


def test_fin_on_an_edge_is_not_edge_manifold():
    # A third triangle on the cube edge (0, 1): that edge is in three faces.
    vertices = np.vstack([CUBE_VERTICES, [[0.5, -1.0, -1.0]]])
    faces = np.vstack([CUBE_FACES, [[0, 1, 8]]])
    r = check_mesh(vertices, faces)
    assert not r.watertight and not r.edge_manifold
    assert not r.vertex_manifold and not r.consistently_oriented
    assert r.n_boundary_loops == 1  # the fin's two free edges


def test_duplicate_and_degenerate_faces_are_counted():
    vertices = np.vstack([CUBE_VERTICES, [[0.5, 0.0, 0.0]]])
    faces = np.vstack([
        CUBE_FACES,
        CUBE_FACES[3, ::-1],  # same vertex set as face 3, reversed
        [[0, 0, 1]],          # repeated index
        [[0, 1, 8]],          # collinear: zero area
    ])
    r = check_mesh(vertices, faces)
    assert r.duplicate_faces == 1
    assert r.degenerate_faces == 2



def test_duplicates_are_counted_in_any_vertex_order():
    # Every face of a fan around vertex 0 (one large group of faces sharing their
    # smallest index), each repeated in the other five orders of its three indices: the
    # count is what a set of sorted index triples gives.
    rng = np.random.default_rng(3)
    rim = 1 + rng.permutation(400)
    fan = np.column_stack([np.zeros(400, np.int64), rim, np.roll(rim, 1)])
    orders = [[0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]]
    faces = np.vstack([fan] + [fan[rng.permutation(400)][:, order] for order in orders]
                      + [fan[:7]])
    vertices = rng.normal(size=(401, 3))
    expected = len(faces) - len({tuple(sorted(face)) for face in faces.tolist()})
    assert expected == 5 * 400 + 7
    assert check_mesh(vertices, faces).duplicate_faces == expected

def test_torus_genus_one_and_agrees_with_trimesh():
    mesh = trimesh.creation.torus(major_radius=0.05, minor_radius=0.012)
    r = check_mesh(mesh.vertices, mesh.faces)
    assert r.watertight and r.vertex_manifold and r.consistently_oriented and r.outward is True
    assert (r.euler_characteristic, r.genus, r.n_components) == (0, 1, 1)
    assert r.euler_characteristic == mesh.euler_number
    assert r.volume_m3 == pytest.approx(mesh.volume, rel=ROUND_OFF)
    assert r.area_m2 == pytest.approx(mesh.area, rel=ROUND_OFF)
    # The polygonal torus is inscribed in the smooth one, 2 pi^2 R r^2: below it.
    assert r.volume_m3 < 2.0 * np.pi ** 2 * 0.05 * 0.012 ** 2


def closed_meshes():
    """Closed, consistently oriented meshes: a cube, two cubes sharing a vertex (not
    vertex-manifold), two apart, a torus, a noisy sphere with its faces shuffled, and a
    cube beside a triangle closed by its own reverse (a duplicate face)."""
    shared = np.vstack([CUBE_VERTICES, CUBE_VERTICES[1:] + 1.0])
    torus = trimesh.creation.torus(major_radius=0.05, minor_radius=0.012)
    sphere = trimesh.creation.icosphere(subdivisions=4)
    rng = np.random.default_rng(5)
    return [(CUBE_VERTICES, CUBE_FACES),
            (shared, np.vstack([CUBE_FACES, np.r_[7, np.arange(8, 15)][CUBE_FACES]])),
            (np.vstack([CUBE_VERTICES, CUBE_VERTICES + 3.0]),
             np.vstack([CUBE_FACES, CUBE_FACES + 8])),
            (torus.vertices, torus.faces.astype(np.int64)),
            (sphere.vertices + rng.normal(0, 0.01, sphere.vertices.shape),
             np.roll(sphere.faces[rng.permutation(len(sphere.faces))], 1, axis=1)),
            (np.vstack([CUBE_VERTICES, [[3.0, 0, 0], [4.0, 0, 0], [3.0, 1.0, 0]]]),
             np.vstack([CUBE_FACES, [[8, 9, 10], [10, 9, 8]]]))]


@pytest.mark.parametrize("index", range(6))
def test_a_closed_mesh_checked_from_its_paired_edges_as_from_its_sorted_half_edges(index):
    # The closed path (edges paired by outline.edge_faces) against the general one on the
    # same mesh: the same topology, field by field.
    vertices, faces = closed_meshes()[index]
    faces = np.ascontiguousarray(faces, np.int64)
    paired = edge_faces(faces, len(vertices))
    assert paired is not None
    referenced = _referenced(faces, len(vertices))
    assert _closed_topology(faces, len(vertices), referenced, *paired) == \
        _open_topology(faces, len(vertices), referenced)
    given = check_mesh(vertices, faces, edges=paired)
    assert given == check_mesh(vertices, faces)
    assert given.vertex_manifold == (index != 1)
    assert given.duplicate_faces == (index == 5)


def test_as_dict_is_json_ready():
    r = check_mesh(CUBE_VERTICES, CUBE_FACES[2:])
    d = json.loads(json.dumps(r.as_dict()))
    assert d["n_boundary_loops"] == 1 and d["genus"] is None and d["outward"] is None
    assert d["volume_m3"] == pytest.approx(r.volume_m3)


@pytest.mark.parametrize("vertices, faces, match", [
    (np.zeros((4, 2)), [[0, 1, 2]], "vertices"),
    ([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]], "finite"),
    (CUBE_VERTICES, np.zeros((0, 3), dtype=int), "m >= 1"),
    (CUBE_VERTICES, [[0, 1, 8]], r"\[0, 8\)"),
    (CUBE_VERTICES, [[0.0, 1.0, 2.0]], "integer"),
])
def test_invalid_input(vertices, faces, match):
    with pytest.raises(ValueError, match=match):
        check_mesh(vertices, faces)
