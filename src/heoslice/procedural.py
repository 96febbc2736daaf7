"""Procedural meshes: the example vase, test fixtures and benchmark parts, made by code.

Every mesh here is a closed, outward-oriented trimesh.Trimesh in mm, so examples,
tests and benchmarks need no third-party files.
"""

from __future__ import annotations

import numpy as np
import trimesh


def vase(height: float = 60.0, radius: float = 18.0, bulge: float = 7.0, wall: float = 2.5,
         floor: float = 4.0, rings_outer: int = 26, rings_inner: int = 22, sections: int = 64) -> trimesh.Trimesh:
    """A thick-walled vase: outer and inner wall of revolution, closed bottom, open top rim.

    Defaults give 3074 vertices and 6144 triangles, about the paper's Table 1 vase
    (3115 points, 6226 triangles), 60 mm tall.
    """
    def profile(z):
        return radius + bulge * np.sin(z / height * np.pi * 1.3)

    z_outer = np.linspace(0.0, height, rings_outer)
    z_inner = np.linspace(height, floor, rings_inner)
    outline = np.vstack([
        [0.0, 0.0],
        np.column_stack([profile(z_outer), z_outer]),
        np.column_stack([profile(z_inner) - wall, z_inner]),
        [0.0, floor],
    ])
    return trimesh.creation.revolve(outline, sections=sections)


def sphere(radius: float = 10.0, subdivisions: int = 4, center=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """An icosphere (20 * 4**subdivisions triangles)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(center)
    return mesh


def uv_sphere(radius: float = 25.0, count: tuple[int, int] = (64, 64)) -> trimesh.Trimesh:
    """A latitude-longitude sphere: about 2 * count[0] * count[1] triangles (benchmarks scale it up)."""
    return trimesh.creation.uv_sphere(radius=radius, count=list(count))


def torus(major: float = 20.0, minor: float = 6.0, sections: int = 64, rings: int = 32) -> trimesh.Trimesh:
    """A torus around the z axis: every layer through it is an annulus (outer ring with one hole)."""
    return trimesh.creation.torus(major_radius=major, minor_radius=minor,
                                  major_sections=sections, minor_sections=rings)


def box(extents=(10.0, 10.0, 10.0), origin=(0.0, 0.0, 0.0), z_cuts=()) -> trimesh.Trimesh:
    """An axis-aligned box with its minimum corner at origin; ``z_cuts`` adds vertex rings at those heights.

    Putting cuts exactly on slicing planes exercises vertices lying on a plane.
    """
    low = np.asarray(origin, dtype=float)
    high = low + np.asarray(extents, dtype=float)
    levels = np.unique(np.concatenate([[low[2], high[2]], [z for z in z_cuts if low[2] < z < high[2]]]))
    corners = np.array([[low[0], low[1]], [high[0], low[1]], [high[0], high[1]], [low[0], high[1]]])
    vertices = np.array([[x, y, z] for z in levels for x, y in corners])
    faces = []
    for level in range(len(levels) - 1):
        a = 4 * level
        b = a + 4
        for side in range(4):
            s0, s1 = side, (side + 1) % 4
            faces += [[a + s0, a + s1, b + s1], [a + s0, b + s1, b + s0]]
    top = 4 * (len(levels) - 1)
    faces += [[0, 2, 1], [0, 3, 2], [top, top + 1, top + 2], [top, top + 2, top + 3]]
    return trimesh.Trimesh(vertices, np.array(faces), process=False)


def inverted(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same surface with normals pointing inward (a cavity boundary)."""
    return trimesh.Trimesh(mesh.vertices.copy(), mesh.faces[:, ::-1].copy(), process=False)


def concatenate(*meshes: trimesh.Trimesh) -> trimesh.Trimesh:
    """Several shells in one mesh, without merging anything."""
    return trimesh.util.concatenate(list(meshes))


def shell_with_island(outer: float = 20.0, cavity: float = 12.0, island: float = 5.0,
                      subdivisions: int = 4) -> trimesh.Trimesh:
    """A hollow ball with a separate solid ball floating in its cavity.

    Every layer through the island shows an outer ring, a hole, and an island
    inside the hole, which is a profile family of its own.
    """
    return concatenate(sphere(outer, subdivisions), inverted(sphere(cavity, subdivisions)),
                       sphere(island, subdivisions))


def nested_shells(outer: float = 20.0, inner: float = 6.0, offset=(4.0, 0.0, 0.0),
                  subdivisions: int = 4) -> trimesh.Trimesh:
    """Two overlapping closed, outward shells: an organ and a lesion inside it.

    The lesion is not a hole: the loops wind twice around it, and the region stays solid.
    """
    return concatenate(sphere(outer, subdivisions), sphere(inner, subdivisions, center=offset))


def thin_wall(thickness: float = 0.02, height: float = 5.0, length: float = 20.0) -> trimesh.Trimesh:
    """A wall thinner than a 600 dpi pixel (0.0423 mm): few or no pixel centres inside."""
    return box((length, thickness, height), origin=(-length / 2, -thickness / 2, 0.0))


def holes_and_islands(size: tuple[float, float, float], segments: int) -> trimesh.Trimesh:
    """A plate with a 3 x 2 grid of through holes, a free pin (island) standing in each hole,
    and a closed spherical cavity holding a free ball: every layer has holes and islands,
    and the layers through the cavity have an island inside a hole inside the plate.

    Built with manifold3d booleans (imported here: only this part needs them); size is (x, y, z)
    in mm. The benchmark's part with holes and islands; away from the cavity its layers are
    an extrusion's, all alike.
    """
    import manifold3d

    sx, sy, sz = size
    hole_r, pin_r = 0.075 * sx, 0.03 * sx
    plate = manifold3d.Manifold.cube([sx, sy, sz])
    pins = []
    for x in (0.19 * sx, 0.44 * sx, 0.69 * sx):
        for y in (0.3 * sy, 0.7 * sy):
            hole = manifold3d.Manifold.cylinder(sz + 2.0, hole_r, circular_segments=segments)
            plate -= hole.translate([x, y, -1.0])
            pins.append(manifold3d.Manifold.cylinder(sz, pin_r, circular_segments=segments).translate([x, y, 0.0]))
    cavity_r = min(0.07 * sx, 0.3 * sz, 0.2 * sy)
    centre = [0.875 * sx, 0.5 * sy, 0.5 * sz]
    plate -= manifold3d.Manifold.sphere(cavity_r, segments).translate(centre)
    part = plate
    for pin in pins:
        part += pin
    part += manifold3d.Manifold.sphere(0.5 * cavity_r, segments).translate(centre)
    mesh = part.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def liver_phantom(scale: float = 1.0, subdivisions: int = 5,
                  lesion_height: float | None = None) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """A smooth liver-like blob (about 116 x 125 x 190 mm at scale 1) and a lesion shell (radius 18 mm x scale)
    inside it.

    ``lesion_height`` (mm) puts the lesion's centre that high above the organ's lowest point, over it (the
    figure of a low layer, e.g. Fig. 9's layer 83 at 8.25 mm, cuts both); None keeps it 5 mm above the
    organ's middle. The organ is the same either way. Returns (organ, lesion), each closed and outward-oriented.
    """
    organ = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = organ.vertices
    lobe = 1.0 + 0.18 * np.sin(2.1 * v[:, 0] + 0.7) * np.cos(1.7 * v[:, 1]) + 0.1 * v[:, 2] ** 2
    organ.vertices = v * lobe[:, None] * (np.array([80.0, 82.5, 100.0]) / 1.3) * scale
    lower = organ.vertices[:, 2].min()
    organ.vertices[:, 2] -= lower
    lesion = trimesh.creation.icosphere(subdivisions=max(subdivisions - 2, 2), radius=18.0 * scale)
    if lesion_height is None:
        lesion.apply_translation(np.array([20.0, 10.0, -lower + 5.0]) * np.array([scale, scale, 1.0]))
    else:
        lowest = organ.vertices[np.argmin(organ.vertices[:, 2])]
        lesion.apply_translation((lowest[0], lowest[1], float(lesion_height)))
    return organ, lesion
