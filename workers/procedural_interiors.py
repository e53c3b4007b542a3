"""Held-out procedural interiors for the fidelity benchmark: scenes the default config was never tuned on.

Issue 12 ("right by default") asks for light within 0.9-1.1 of Cycles on scenes Kiln has never seen. The scenes of
:mod:`workers.procedural` are the ones the defaults were measured on; these eight differ from them the way a user's
interior would (room sizes, wall thickness, a zero-thickness wall, a sun through a window, a corridor, a building
larger than the default probe budget covers at its rooms' spacing, a lone floor), and are used
ONLY by tests/bench/bench_fidelity.py and tests/data/fidelity/make_references.py (check points and Cycles references
in tests/data/fidelity/<scene>.*). They are kept out of :data:`workers.procedural.SCENES` / ``ALL_SCENES``, which the
unit tests iterate. Same conventions as :mod:`workers.procedural` (metres, +Y up, watertight grid solids from
:func:`workers.procedural_glb.grid_solid`, identity mesh transforms, KHR_lights_punctual: point lights in candela,
directional lights in lux). Materials: walls and ceilings white-ish 0.8, floors a wood-like (0.45, 0.33, 0.22).

``rooms-unequal`` (lit room larger than the dark one, 2 cm shared wall, off-centre door)
    Room A (lit) [0, 6] x [0, 3] x [0, 5]; room B (dark) [6.02, 9.02] x [0, 2.6] x [0, 3]; shared wall x in
    [6, 6.02]; door through it z in [0.3, 1.1], y < 2.0 (0.8 x 2 m, near B's z = 0 end). Outer shell 5 cm.
    One 30 cd point light at (2.0, 2.6, 3.0) in room A.

``sun-window`` (sunlit room, interior door to a closed room, building on a ground slab)
    Room A (lit) [0, 5] x [0, 3] x [0, 4] with a window opening (no glass) in its outer wall x in [-0.1, 0],
    y in [0.9, 2.2], z in [1.0, 3.0]; room B (dark, no window) [5.08, 8.58] x [0, 3] x [0, 4]; shared wall x in
    [5, 5.08] (8 cm) with a door z in [2.7, 3.6], y < 2.1. Outer walls 10 cm, ceiling / floor slab 15 cm; the
    building stands on a ground slab [-4, 11] x [-0.4, -0.15] x [-3, 7] (grey 0.3). A 3 lux sun (KHR directional)
    travelling along normalize(0.6, -0.7, 0.2) (into the window, lighting a patch of A's floor) and a sky of
    radiance (0.3, 0.35, 0.4) from the bake config (:data:`CONFIGS`).

``corridor-l`` (an L-shaped corridor, light at one end)
    Leg 1 [0, 8] x [0, 2.5] x [0, 1.5] along x; leg 2 [6.5, 8] x [0, 2.5] x [0, 8] along z; closed ends; walls
    5 cm (the space inside the L, x < 6.45, z > 1.55, is outside the building: empty, unlit). One 10 cd point light
    at (0.75, 2.2, 0.75) at the far end of leg 1: leg 2 beyond the corner gets no direct light.

``plane-wall`` (two rooms divided by a zero-thickness wall: one double-sided plane, as many modelled interiors are)
    One closed box, interior [0, 8] x [0, 2.8] x [0, 4], 10 cm shell; a divider plane x = 4.5 (material "divider",
    white 0.8, doubleSided) from floor to ceiling with a door opening z in [2.8, 3.7], y < 2.0: room A (lit)
    x < 4.5, room B (dark) x > 4.5. One 25 cd point light at (2.0, 2.4, 1.5) in A.

``thick-wall`` (two rooms with a 40 cm wall between them)
    Room A (lit) [0, 4] x [0, 3] x [0, 4]; room B (dark) [4.4, 8.4] x [0, 3] x [0, 4]; wall x in [4, 4.4] with a
    door through it z in [2.6, 3.5], y < 2.0. Outer shell 10 cm. One 20 cd point light at (1.2, 2.4, 1.2) in A.

``apartments`` (a building larger than the default probe budget covers at the rooms' spacing)
    5 x 3 rooms on each of 3 floors, 4 x 2.8 x 4 m each (:func:`apartment_room`), 10 cm walls and slabs, a door
    0.9 x 2 m from each room to its +x neighbour (z 1.4-2.3 m into the room); solid block [0, 20.6] x [0, 8.8] x
    [0, 12.4]. One 20 cd point light in room (2, 1, 1), 1 m from its low corner in x and z, 2.4 m up: the rooms of
    its row get its light through the doors; the rooms beside it in z and over and under it share only a wall or a
    slab with it (Cycles: exactly 0 there). The default grid is budget-bound (0.52 m where the rooms ask 0.21 m).

``open-floor`` (issue 12's "open lit floor", as a user's first upload would be)
    One single-sided quad [-5, 5] x {0} x [-5, 5] facing +Y, grey 0.5, nothing else; a 3 lux sun travelling along
    normalize(-0.3, -1, -0.2) and a sky of radiance (0.3, 0.35, 0.4) from the bake config (:data:`CONFIGS`). No
    extent along y: the automatic grid once put its one layer of probes in the plane.

``two-storey`` (a lit upper floor over a dark lower one: a thin floor slab, a stairwell opening)
    Lower room D (dark) [0, 5] x [0, 2.6] x [0, 4]; upper room U (lit) [0, 5] x [2.62, 5.0] x [0, 4]; the slab
    between them y in [2.6, 2.62] (2 cm: U's floor is D's ceiling) with a stairwell opening x in [3.9, 4.9],
    z in [0.1, 1.5]; a solid block (a sideboard) [0.5, 1.7] x [0, 0.9] x [3.4, 3.9] in D. Outer shell 8 cm. One
    25 cd point light at (1.5, 4.6, 2.5) in U: the light reaches D only down the stairwell. The leak here is
    vertical: the wall that must stop it is a floor, and the stored light under it is a ceiling's.
"""
from __future__ import annotations

import numpy as np

from workers.procedural_glb import EPS, Box3, Light, Material, SceneSpec, encode_glb, quads_to_primitive, solid_mesh

__all__ = ["INTERIOR_SCENES", "CONFIGS", "make_interior", "apartment_room"]

INTERIOR_SCENES: dict[str, str] = {
    "rooms-unequal": "lit 6 x 3 x 5 m room beside a dark 3 x 2.6 x 3 m room, 2 cm shared wall, off-centre door, "
                     "30 cd point light",
    "sun-window": "sunlit 5 x 3 x 4 m room (window opening, sun + sky) with an interior door to a closed "
                  "3.5 x 3 x 4 m room; building on a ground slab",
    "corridor-l": "L-shaped corridor 1.5 m wide, 2.5 m high, legs 8 m; a 10 cd point light at one end",
    "thick-wall": "two 4 x 3 x 4 m rooms, 40 cm wall with a door through it, 20 cd point light in one",
    "plane-wall": "two rooms (4.5 and 3.5 x 2.8 x 4 m) divided by one double-sided plane with a door, 25 cd point "
                  "light in one",
    "two-storey": "lit 5 x 2.38 x 4 m upper floor over a dark 5 x 2.6 x 4 m lower one, 2 cm floor slab with a "
                  "1 x 1.4 m stairwell opening, 25 cd point light upstairs",
    "open-floor": "a lone 10 x 10 m ground plane (one single-sided quad, no thickness) under a sun and a sky",
    "apartments": "a block of 5 x 3 rooms on 3 floors (4 x 2.8 x 4 m, 10 cm walls and slabs, doors along each row), "
                  "the middle room lit by a 20 cd point light: the default budget binds",
}

# Bake-config additions of each scene (the bench bakes the default config plus this; the Cycles reference gets the
# same sky): only the sun room has a sky.
CONFIGS: dict[str, dict] = {"sun-window": {"scene": {"sky": [0.3, 0.35, 0.4]}},
                            "open-floor": {"scene": {"sky": [0.3, 0.35, 0.4]}}}

_WALL = (0.8, 0.8, 0.8)
_FLOOR = (0.45, 0.33, 0.22)


def _floor_or_wall(c, axis, sign) -> str:
    """Upward-facing faces are floors (wood), everything else wall (white)."""
    return "floor" if axis == 1 and sign > 0 else "wall"


def _materials() -> list[Material]:
    return [Material("wall", _WALL), Material("floor", _FLOOR)]


def _bounds(ops) -> Box3:
    solids = [b for s, b in ops if s]
    return (tuple(min(b[0][a] for b in solids) for a in range(3)),
            tuple(max(b[1][a] for b in solids) for a in range(3)))


def _rooms_unequal() -> SceneSpec:
    t = 0.05
    ops = [
        (True, ((-t, -t, -t), (6.02, 3.0 + t, 5.0 + t))),          # shell of A (its x = 6 side is the shared wall)
        (True, ((6.0, -t, -t), (9.02 + t, 2.6 + t, 3.0 + t))),      # shell of B
        (False, ((0.0, 0.0, 0.0), (6.0, 3.0, 5.0))),                # room A
        (False, ((6.02, 0.0, 0.0), (9.02, 2.6, 3.0))),              # room B
        (False, ((6.0, 0.0, 0.3), (6.02, 2.0, 1.1))),               # door
    ]
    return SceneSpec(name="rooms-unequal", materials=_materials(),
                     meshes=[solid_mesh("rooms", ops, _floor_or_wall)],
                     lights=[Light("room-a", "point", 30.0, position=(2.0, 2.6, 3.0))], bake_box=_bounds(ops))


def _sun_window() -> SceneSpec:
    t, s = 0.10, 0.15
    ground: Box3 = ((-4.0, -0.4, -3.0), (11.0, -s, 7.0))
    ops = [
        (True, ground),
        (True, ((-t, -s, -t), (8.58 + t, 3.0 + s, 4.0 + t))),      # the building's shell
        (False, ((0.0, 0.0, 0.0), (5.0, 3.0, 4.0))),                # room A
        (False, ((5.08, 0.0, 0.0), (8.58, 3.0, 4.0))),              # room B
        (False, ((5.0, 0.0, 2.7), (5.08, 2.1, 3.6))),               # interior door
        (False, ((-t, 0.9, 1.0), (0.0, 2.2, 3.0))),                 # window opening
    ]

    def material_of(c, axis, sign):
        # the ground's faces (its top at y = -s, its sides and bottom); the building's bottom is fused with it
        return "ground" if c[1] < -s + EPS else _floor_or_wall(c, axis, sign)

    return SceneSpec(name="sun-window", materials=[*_materials(), Material("ground", (0.3, 0.3, 0.3))],
                     meshes=[solid_mesh("building", ops, material_of)],
                     lights=[Light("sun", "directional", 3.0, direction=(0.6, -0.7, 0.2))], bake_box=_bounds(ops))


def _corridor_l() -> SceneSpec:
    t = 0.05
    ops = [
        (True, ((-t, -t, -t), (8.0 + t, 2.5 + t, 1.5 + t))),
        (True, ((6.5 - t, -t, -t), (8.0 + t, 2.5 + t, 8.0 + t))),
        (False, ((0.0, 0.0, 0.0), (8.0, 2.5, 1.5))),                # leg 1
        (False, ((6.5, 0.0, 0.0), (8.0, 2.5, 8.0))),                # leg 2
    ]
    return SceneSpec(name="corridor-l", materials=_materials(), meshes=[solid_mesh("corridor", ops, _floor_or_wall)],
                     lights=[Light("end", "point", 10.0, position=(0.75, 2.2, 0.75))], bake_box=_bounds(ops))


def _thick_wall() -> SceneSpec:
    t = 0.10
    ops = [
        (True, ((-t, -t, -t), (8.4 + t, 3.0 + t, 4.0 + t))),
        (False, ((0.0, 0.0, 0.0), (4.0, 3.0, 4.0))),
        (False, ((4.4, 0.0, 0.0), (8.4, 3.0, 4.0))),
        (False, ((4.0, 0.0, 2.6), (4.4, 2.0, 3.5))),                # door through the 40 cm wall
    ]
    return SceneSpec(name="thick-wall", materials=_materials(), meshes=[solid_mesh("rooms", ops, _floor_or_wall)],
                     lights=[Light("room-a", "point", 20.0, position=(1.2, 2.4, 1.2))], bake_box=_bounds(ops))


def _plane_wall() -> SceneSpec:
    t, x = 0.10, 4.5
    ops = [(True, ((-t, -t, -t), (8.0 + t, 2.8 + t, 4.0 + t))), (False, ((0.0, 0.0, 0.0), (8.0, 2.8, 4.0)))]

    def quad(y0, y1, z0, z1):   # in the plane x, counter-clockwise seen from -x (double-sided: either way)
        return np.array([[x, y0, z0], [x, y0, z1], [x, y1, z1], [x, y1, z0]], np.float64)

    divider = [quad(0.0, 2.8, 0.0, 2.8), quad(0.0, 2.8, 3.7, 4.0), quad(2.0, 2.8, 2.8, 3.7)]
    name, prims = solid_mesh("shell", ops, _floor_or_wall)
    return SceneSpec(name="plane-wall",
                     materials=[*_materials(), Material("divider", _WALL, double_sided=True)],
                     meshes=[(name, prims), ("divider", {"divider": quads_to_primitive(divider)})],
                     lights=[Light("room-a", "point", 25.0, position=(2.0, 2.4, 1.5))], bake_box=_bounds(ops))


def _two_storey() -> SceneSpec:
    t = 0.08
    ops = [
        (True, ((-t, -t, -t), (5.0 + t, 5.0 + t, 4.0 + t))),
        (False, ((0.0, 0.0, 0.0), (5.0, 2.6, 4.0))),                # room D (dark, downstairs)
        (False, ((0.0, 2.62, 0.0), (5.0, 5.0, 4.0))),               # room U (lit, upstairs)
        (False, ((3.9, 2.6, 0.1), (4.9, 2.62, 1.5))),               # stairwell opening through the 2 cm slab
        (True, ((0.5, 0.0, 3.4), (1.7, 0.9, 3.9))),                 # a sideboard in D
    ]
    return SceneSpec(name="two-storey", materials=_materials(), meshes=[solid_mesh("storeys", ops, _floor_or_wall)],
                     lights=[Light("upstairs", "point", 25.0, position=(1.5, 4.6, 2.5))], bake_box=_bounds(ops))


APARTMENT_ROOMS = (5, 3, 3)
"""Rooms of ``apartments`` along x, y (floors), z."""
APARTMENT_ROOM = (4.0, 2.8, 4.0)
APARTMENT_WALL = 0.10


def apartment_room(i: int, j: int, k: int) -> tuple[float, float, float]:
    """The low corner of room (i, j, k) of ``apartments`` (metres)."""
    (w, h, d), t = APARTMENT_ROOM, APARTMENT_WALL
    return (t + i * (w + t), t + j * (h + t), t + k * (d + t))


def _apartments() -> SceneSpec:
    (nx, ny, nz), (w, h, d), t = APARTMENT_ROOMS, APARTMENT_ROOM, APARTMENT_WALL
    ops = [(True, ((0.0, 0.0, 0.0), (nx * (w + t) + t, ny * (h + t) + t, nz * (d + t) + t)))]
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                x, y, z = apartment_room(i, j, k)
                ops.append((False, ((x, y, z), (x + w, y + h, z + d))))
                if i + 1 < nx:                                      # a door to the +x neighbour, off-centre
                    ops.append((False, ((x + w, y, z + 1.4), (x + w + t, y + 2.0, z + 2.3))))
    x, y, z = apartment_room(2, 1, 1)
    return SceneSpec(name="apartments", materials=_materials(), meshes=[solid_mesh("block", ops, _floor_or_wall)],
                     lights=[Light("lamp", "point", 20.0, position=(x + 1.0, y + 2.4, z + 1.0))], bake_box=ops[0][1])


def _open_floor() -> SceneSpec:
    ground = [np.array([[-5.0, 0.0, 5.0], [5.0, 0.0, 5.0], [5.0, 0.0, -5.0], [-5.0, 0.0, -5.0]])]   # CCW from +Y
    return SceneSpec(name="open-floor", materials=[Material("ground", (0.5, 0.5, 0.5))],
                     meshes=[("floor", {"ground": quads_to_primitive(ground)})],
                     lights=[Light("sun", "directional", 3.0, direction=(-0.3, -1.0, -0.2))],
                     bake_box=((-5.0, 0.0, -5.0), (5.0, 2.5, 5.0)))


_BUILDERS = {"rooms-unequal": _rooms_unequal, "sun-window": _sun_window, "corridor-l": _corridor_l,
             "thick-wall": _thick_wall, "plane-wall": _plane_wall, "two-storey": _two_storey,
             "apartments": _apartments, "open-floor": _open_floor}


def make_interior(name: str) -> bytes:
    """The GLB bytes of held-out interior ``name`` (a key of :data:`INTERIOR_SCENES`); deterministic."""
    try:
        builder = _BUILDERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown interior {name!r}; valid names: {', '.join(sorted(INTERIOR_SCENES))}") from None
    return encode_glb(builder())
