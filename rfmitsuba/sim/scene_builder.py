"""Author indoor rooms for Sionna RT: a typed description -> Mitsuba XML + PLY meshes.

A room is a short Python (or TOML) description: the interior size, the wall,
floor and ceiling materials, openings (doors, windows) and furniture made of
boxes. :func:`write_scene` turns it into a Mitsuba 3 scene that Sionna RT 2.2
loads with ``sionna.rt.load_scene(path, merge_shapes=False)``::

    from rfmitsuba import scene_builder as sb
    desc = sb.RoomDescription(
        name="office", size=(5.0, 4.0, 2.8),
        materials=[sb.Material("wall_concrete", "concrete", 0.2),
                   sb.Material("door_wood", "wood", 0.04),
                   sb.Material("window_glass", "glass", 0.01),
                   sb.Material("furniture_wood", "wood", 0.02)],
        wall_material="wall_concrete", floor_material="wall_concrete",
        ceiling_material="wall_concrete",
        openings=[sb.Opening("door", "south", offset=0.5, width=0.9, height=2.05,
                             material="door_wood"),
                  sb.Opening("window", "north", offset=2.0, width=1.2, height=1.2,
                             sill=0.9, material="window_glass", panel_thickness=0.01)],
        furniture=[sb.table("desk", "furniture_wood", origin=(3.5, 2.8), size=(1.2, 0.7, 0.75))],
    )
    xml_path = sb.write_scene(desc, "scenes/office")

Frame and units: metres, z up. The room interior is the box
``[0, Lx] x [0, Ly] x [0, Lz]`` with ``(Lx, Ly, Lz) = size``; the floor's top
face is z = 0. Walls lie outside the interior: ``south`` is y < 0, ``north``
y > Ly, ``west`` x < 0, ``east`` x > Lx. Openings are placed along their wall
by ``offset`` from the wall's low end (x = 0 for south/north, y = 0 for
west/east).

Shape-id convention (read back by :mod:`rfmitsuba.sim.geometry`): every shape id
is the object name Sionna shows (no ``mesh-`` prefix is written; one would be
stripped on reading). Structure shapes are named by prefix:

- ``wall*`` (``wall_south``, ``wall_north``, ``wall_west``, ``wall_east``):
  walls, each built from boxes around its openings, so an opening is a real
  hole and nothing is coplanar with the panel that fills it;
- ``floor*``, ``ceiling*``: slabs below z = 0 and above z = Lz;
- ``door*``, ``window*``: the panels in the openings, thinner than the wall
  and centred in it, with a small gap (``Opening.gap``) to the opening's edges;
- anything else is furniture. A furniture piece made of parts with one
  material is one shape named by its id; parts of different materials become
  one shape per material, named ``<id>__<material id>`` (two underscores), so
  the object id is the text before ``__``.

Materials are ``<bsdf type="itu-radio-material">`` with an ITU type
(``concrete``, ``brick``, ``plasterboard``, ``wood``, ``glass``, ``metal``, ...)
or ``<bsdf type="body-tissue">`` (:mod:`rfmitsuba.plugins.body_tissue`).
Material ids and shape ids share Sionna's namespace and must differ; the
builder checks it. A material's ``thickness`` is the slab thickness of Sionna's
single-layer slab model, applied at every face a ray meets: a closed box is
crossed through two faces, so use the thickness of a panel (a wardrobe door, a
glass pane), and the wall's thickness for walls (reflections then match a wall
of that thickness; transmission through a solid wall box is counted twice).
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from ..core.errors import SceneError

#: ITU-R P.2040 material types known to Sionna RT 2.2 (``sionna.rt.radio_materials.itu``;
#: tests/test_scene_builder.py checks this list against the installed Sionna).
ITU_TYPES = (
    "vacuum", "concrete", "brick", "plasterboard", "wood", "glass", "clear_acrylic",
    "ceiling_board", "chipboard", "plywood", "marble", "floorboard", "vinyl_tile",
    "carpet_tile", "asphalt_concrete", "metal", "very_dry_ground", "medium_dry_ground",
    "wet_ground",
)
#: Material types besides the ITU ones (plugins of :mod:`rfmitsuba.plugins`).
PLUGIN_TYPES = ("body-tissue",)
#: Shape-id prefixes of structure (not furniture), see the module docstring.
STRUCTURE_PREFIXES = ("wall", "floor", "ceiling", "door", "window")
#: Separator between object id and material id in multi-material furniture shape ids.
PART_SEP = "__"
WALLS = ("south", "north", "west", "east")

_ID = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


@dataclass
class Material:
    """A radio material.

    id: unique name in the scene (letters, digits, ``_``; not a shape id).
    type: an ITU type from :data:`ITU_TYPES` or ``"body-tissue"``.
    thickness: slab thickness, metres (> 0).
    """

    id: str
    type: str
    thickness: float = 0.1


@dataclass
class Box:
    """One axis-aligned box of a furniture piece, in the piece's local frame.

    origin: (x, y, z) of the box's low corner, metres, relative to the piece's ``position``.
    size: (dx, dy, dz) extents, metres (> 0).
    material: material id, or ``None`` for the piece's material.
    name: optional part name (documentation only, e.g. ``"mattress"``).
    """

    origin: tuple[float, float, float]
    size: tuple[float, float, float]
    material: str | None = None
    name: str = ""


@dataclass
class Furniture:
    """A furniture piece: boxes in a local frame, placed on the floor plan.

    id: object id (letters, digits, ``_``; not starting with a structure prefix, no ``__``).
    material: default material id of its boxes.
    parts: the boxes (local frame: x, y horizontal, z up, metres).
    position: (x, y) world position of the local origin, metres (z = floor).
    yaw_deg: rotation about the vertical axis through ``position``, degrees, counter-clockwise.
    """

    id: str
    material: str
    parts: list[Box]
    position: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0


@dataclass
class Opening:
    """A door or window: a hole in a wall, filled by a thinner panel.

    id: shape id, must start with ``door`` or ``window``.
    wall: ``"south"`` (y = 0), ``"north"`` (y = Ly), ``"west"`` (x = 0) or ``"east"`` (x = Lx).
    offset: distance along the wall from its low end (x = 0 or y = 0) to the opening, metres.
    width, height: opening size, metres; sill: height of its bottom above the floor, metres.
    material: material id of the panel.
    panel_thickness: panel thickness across the wall, metres (< wall thickness).
    gap: clearance between the panel and the opening's edges, metres.
    """

    id: str
    wall: Literal["south", "north", "west", "east"]
    offset: float
    width: float
    height: float
    material: str
    sill: float = 0.0
    panel_thickness: float = 0.04
    gap: float = 0.005


@dataclass
class RoomDescription:
    """A rectangular room (see the module docstring for frame and conventions).

    name: scene name (file stem of the XML).
    size: interior (Lx, Ly, Lz), metres.
    materials: every material the room uses.
    wall_material, floor_material, ceiling_material: material ids.
    wall_thickness: metres; slab_thickness: floor and ceiling slab thickness, metres.
    wall_materials: per-wall override, e.g. ``{"north": "brick_wall"}``.
    openings, furniture: see :class:`Opening`, :class:`Furniture`.
    """

    name: str
    size: tuple[float, float, float]
    materials: list[Material]
    wall_material: str
    floor_material: str
    ceiling_material: str
    wall_thickness: float = 0.2
    slab_thickness: float = 0.2
    wall_materials: dict[str, str] = field(default_factory=dict)
    openings: list[Opening] = field(default_factory=list)
    furniture: list[Furniture] = field(default_factory=list)


# ---------------------------------------------------------------- furniture helpers

def block(id: str, material: str, *, origin: tuple[float, float], size: tuple[float, float, float],
          yaw_deg: float = 0.0, z: float = 0.0) -> Furniture:
    """A one-box piece (wardrobe, cabinet, fridge): low corner at ``origin`` (x, y), metres, bottom at ``z``."""
    return Furniture(id, material, [Box((0.0, 0.0, z), tuple(size))], tuple(origin), yaw_deg)


def table(id: str, material: str, *, origin: tuple[float, float], size: tuple[float, float, float],
          top: float = 0.04, leg: float = 0.05, yaw_deg: float = 0.0) -> Furniture:
    """A table: a top of thickness ``top`` on four square legs of side ``leg``; ``size`` = (dx, dy, height), metres."""
    dx, dy, h = size
    parts = [Box((0.0, 0.0, h - top), (dx, dy, top), name="top")]
    for i, (x, y) in enumerate([(0, 0), (dx - leg, 0), (0, dy - leg), (dx - leg, dy - leg)]):
        parts.append(Box((x, y, 0.0), (leg, leg, h - top), name=f"leg{i}"))
    return Furniture(id, material, parts, tuple(origin), yaw_deg)


def chair(id: str, material: str, *, origin: tuple[float, float], size: tuple[float, float] = (0.45, 0.45),
          seat_height: float = 0.45, back_height: float = 0.9, yaw_deg: float = 0.0) -> Furniture:
    """A chair: seat, four legs and a back along the local y = dy side (the sitter faces local -y)."""
    dx, dy = size
    seat, leg, back = 0.04, 0.04, 0.04
    parts = [Box((0.0, 0.0, seat_height - seat), (dx, dy, seat), name="seat"),
             Box((0.0, dy - back, seat_height), (dx, back, back_height - seat_height), name="back")]
    for i, (x, y) in enumerate([(0, 0), (dx - leg, 0), (0, dy - leg), (dx - leg, dy - leg)]):
        parts.append(Box((x, y, 0.0), (leg, leg, seat_height - seat), name=f"leg{i}"))
    return Furniture(id, material, parts, tuple(origin), yaw_deg)


def bed(id: str, frame_material: str, mattress_material: str, *, origin: tuple[float, float],
        size: tuple[float, float] = (1.6, 2.0), frame_height: float = 0.3, mattress: float = 0.2,
        headboard: float = 0.9, yaw_deg: float = 0.0) -> Furniture:
    """A bed: frame, mattress and a headboard along the local y = 0 side; ``size`` = (dx, dy), metres."""
    dx, dy = size
    hb = 0.06
    parts = [Box((0.0, hb, 0.0), (dx, dy - hb, frame_height), name="frame"),
             Box((0.0, 0.0, 0.0), (dx, hb, headboard), name="headboard"),
             Box((0.02, hb + 0.02, frame_height), (dx - 0.04, dy - hb - 0.04, mattress),
                 material=mattress_material, name="mattress")]
    return Furniture(id, frame_material, parts, tuple(origin), yaw_deg)


def sofa(id: str, frame_material: str, cushion_material: str, *, origin: tuple[float, float],
         size: tuple[float, float] = (2.0, 0.9), seat_height: float = 0.42, back_height: float = 0.85,
         yaw_deg: float = 0.0) -> Furniture:
    """A sofa: base, seat cushion, a back along local y = dy and two arms; the sitter faces local -y."""
    dx, dy = size
    arm, back = 0.15, 0.2
    base = 0.2
    parts = [Box((arm, 0.0, 0.0), (dx - 2 * arm, dy - back, base), name="base"),
             Box((arm, 0.0, base), (dx - 2 * arm, dy - back, seat_height - base),
                 material=cushion_material, name="cushion"),
             Box((0.0, dy - back, 0.0), (dx, back, back_height), name="back"),
             Box((0.0, 0.0, 0.0), (arm, dy - back, 0.6), name="arm_left"),
             Box((dx - arm, 0.0, 0.0), (arm, dy - back, 0.6), name="arm_right")]
    return Furniture(id, frame_material, parts, tuple(origin), yaw_deg)


def shelf(id: str, material: str, *, origin: tuple[float, float], size: tuple[float, float, float],
          boards: int = 4, board: float = 0.02, yaw_deg: float = 0.0) -> Furniture:
    """An open bookshelf: two sides, a back along local y = dy, and ``boards`` shelves; ``size`` = (dx, dy, dz)."""
    dx, dy, dz = size
    parts = [Box((0.0, 0.0, 0.0), (board, dy, dz), name="side_left"),
             Box((dx - board, 0.0, 0.0), (board, dy, dz), name="side_right"),
             Box((board, dy - board, 0.0), (dx - 2 * board, board, dz), name="back")]
    for i in range(boards):
        z = i * (dz - board) / max(boards - 1, 1)
        parts.append(Box((board, 0.0, z), (dx - 2 * board, dy - board, board), name=f"board{i}"))
    return Furniture(id, material, parts, tuple(origin), yaw_deg)


# ---------------------------------------------------------------- validation

def _finite_pos(v: float, what: str) -> None:
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise SceneError(f"{what} must be a positive finite number of metres, got {v!r}")


def shape_ids(desc: RoomDescription) -> list[str]:
    """Every shape id :func:`write_scene` writes for ``desc``, in file order."""
    ids = [f"wall_{w}" for w in WALLS] + ["floor", "ceiling"]
    ids += [o.id for o in desc.openings]
    for f in desc.furniture:
        ids += [sid for sid, _ in _furniture_groups(f)]
    return ids


def _furniture_groups(f: Furniture) -> list[tuple[str, str]]:
    mats: list[str] = []
    for p in f.parts:
        m = p.material or f.material
        if m not in mats:
            mats.append(m)
    if len(mats) == 1:
        return [(f.id, mats[0])]
    return [(f"{f.id}{PART_SEP}{m}", m) for m in mats]


def validate(desc: RoomDescription) -> None:
    """Check a description; raises :class:`SceneError` naming the first problem."""
    if not isinstance(desc.name, str) or not _ID.match(desc.name):
        raise SceneError(f"room name {desc.name!r} must be letters, digits and '_' (starting with a letter)")
    if len(desc.size) != 3:
        raise SceneError(f"room {desc.name}: size must be (Lx, Ly, Lz), got {desc.size!r}")
    for v, n in zip(desc.size, "xyz"):
        _finite_pos(v, f"room {desc.name}: size {n}")
    _finite_pos(desc.wall_thickness, f"room {desc.name}: wall_thickness")
    _finite_pos(desc.slab_thickness, f"room {desc.name}: slab_thickness")
    mats = {}
    for m in desc.materials:
        if not _ID.match(m.id):
            raise SceneError(f"material id {m.id!r} must be letters, digits and '_' (starting with a letter)")
        if m.id in mats:
            raise SceneError(f"material id {m.id!r} is defined twice")
        if m.type not in ITU_TYPES and m.type not in PLUGIN_TYPES:
            raise SceneError(f"material {m.id!r}: unknown type {m.type!r}; known: "
                             f"{', '.join(ITU_TYPES + PLUGIN_TYPES)}")
        if m.id in ITU_TYPES:
            raise SceneError(f"material id {m.id!r} is an ITU type name; Sionna reserves those, "
                             f"use e.g. {m.id + '_wall'!r}")
        _finite_pos(m.thickness, f"material {m.id}: thickness")
        mats[m.id] = m

    def need(mid: str, who: str) -> None:
        if mid not in mats:
            raise SceneError(f"{who} uses material {mid!r}, which is not among the room's materials "
                             f"({', '.join(mats) or 'none'})")

    need(desc.wall_material, "the walls")
    need(desc.floor_material, "the floor")
    need(desc.ceiling_material, "the ceiling")
    for w, m in desc.wall_materials.items():
        if w not in WALLS:
            raise SceneError(f"wall_materials: unknown wall {w!r}; walls are {', '.join(WALLS)}")
        need(m, f"wall {w}")
    lx, ly, lz = desc.size
    t = desc.wall_thickness
    for o in desc.openings:
        if not _ID.match(o.id) or not (o.id.startswith("door") or o.id.startswith("window")):
            raise SceneError(f"opening id {o.id!r} must start with 'door' or 'window' (letters, digits, '_')")
        if o.wall not in WALLS:
            raise SceneError(f"opening {o.id}: unknown wall {o.wall!r}; walls are {', '.join(WALLS)}")
        need(o.material, f"opening {o.id}")
        for v, n in ((o.width, "width"), (o.height, "height"), (o.panel_thickness, "panel_thickness")):
            _finite_pos(v, f"opening {o.id}: {n}")
        if not (math.isfinite(o.offset) and math.isfinite(o.sill) and math.isfinite(o.gap)):
            raise SceneError(f"opening {o.id}: offset, sill and gap must be finite")
        length = lx if o.wall in ("south", "north") else ly
        if o.offset < 0 or o.offset + o.width > length:
            raise SceneError(f"opening {o.id}: [{o.offset}, {o.offset + o.width}] m does not fit in the "
                             f"{o.wall} wall of length {length} m")
        if o.sill < 0 or o.sill + o.height > lz:
            raise SceneError(f"opening {o.id}: sill {o.sill} m + height {o.height} m exceeds the room height {lz} m")
        if o.panel_thickness >= t:
            raise SceneError(f"opening {o.id}: panel_thickness {o.panel_thickness} m must be below the wall "
                             f"thickness {t} m")
        if not 0 <= o.gap < min(o.width, o.height) / 4:
            raise SceneError(f"opening {o.id}: gap {o.gap} m must be >= 0 and small against the opening")
    for w in WALLS:
        ops = sorted((o for o in desc.openings if o.wall == w), key=lambda o: o.offset)
        for a, b in zip(ops, ops[1:]):
            if b.offset < a.offset + a.width + 1e-6:
                raise SceneError(f"openings {a.id} and {b.id} overlap in the {w} wall")
    ids = set()
    for f in desc.furniture:
        if not _ID.match(f.id) or PART_SEP in f.id or f.id.startswith(STRUCTURE_PREFIXES):
            raise SceneError(f"furniture id {f.id!r} must be letters, digits and '_' without '__', and must not "
                             f"start with {', '.join(STRUCTURE_PREFIXES)}")
        if f.id in ids:
            raise SceneError(f"furniture id {f.id!r} is used twice")
        ids.add(f.id)
        need(f.material, f"furniture {f.id}")
        if not f.parts:
            raise SceneError(f"furniture {f.id} has no parts")
        for i, p in enumerate(f.parts):
            for v in p.size:
                _finite_pos(v, f"furniture {f.id} part {i} size")
            if not all(math.isfinite(v) for v in p.origin):
                raise SceneError(f"furniture {f.id} part {i}: origin must be finite")
            if p.material is not None:
                need(p.material, f"furniture {f.id} part {p.name or i}")
        lo, hi = _furniture_mesh(f).bounds
        if lo[0] < -1e-9 or lo[1] < -1e-9 or lo[2] < -1e-9 or hi[0] > lx + 1e-9 or hi[1] > ly + 1e-9 \
                or hi[2] > lz + 1e-9:
            raise SceneError(f"furniture {f.id} spans {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()} m, "
                             f"outside the room interior [0, 0, 0]..{list(desc.size)} m")
    sids = shape_ids(desc)
    dup = {s for s in sids if sids.count(s) > 1}
    if dup:
        raise SceneError(f"shape id(s) {', '.join(sorted(dup))} used more than once")
    clash = set(sids) & set(mats)
    if clash:
        raise SceneError(f"id(s) {', '.join(sorted(clash))} name both a shape and a material; Sionna keeps "
                         f"objects and materials in one namespace")
    # furniture pieces must not interpenetrate (touching is fine); checked for right-angle yaws
    boxes = []
    for f in desc.furniture:
        if abs(f.yaw_deg / 90.0 - round(f.yaw_deg / 90.0)) < 1e-9:
            for p in f.parts:
                boxes.append((f.id, *_box_mesh(f, p).bounds))
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            if a[0] == b[0]:
                continue
            ov = np.minimum(a[2], b[2]) - np.maximum(a[1], b[1])
            if np.all(ov > 1e-6):
                raise SceneError(f"furniture {a[0]} and {b[0]} overlap")


# ---------------------------------------------------------------- meshes

def _box(lo, hi) -> trimesh.Trimesh:
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    return trimesh.creation.box(bounds=np.stack([lo, hi]))


def _yaw(f: Furniture) -> np.ndarray:
    a = math.radians(f.yaw_deg)
    c, s = math.cos(a), math.sin(a)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[0, 3], m[1, 3] = f.position
    return m


def _box_mesh(f: Furniture, p: Box) -> trimesh.Trimesh:
    b = _box(p.origin, np.add(p.origin, p.size))
    b.apply_transform(_yaw(f))
    return b


def _furniture_mesh(f: Furniture, material: str | None = None) -> trimesh.Trimesh:
    parts = [_box_mesh(f, p) for p in f.parts if material is None or (p.material or f.material) == material]
    return trimesh.util.concatenate(parts)


def _wall_boxes(desc: RoomDescription, wall: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boxes (lo, hi) of one wall with holes for its openings."""
    lx, ly, lz = desc.size
    t = desc.wall_thickness
    along_x = wall in ("south", "north")
    if along_x:
        s0, s1 = -t, lx + t                        # the x walls include the corners
        c0, c1 = (-t, 0.0) if wall == "south" else (ly, ly + t)
    else:
        s0, s1 = 0.0, ly
        c0, c1 = (-t, 0.0) if wall == "west" else (lx, lx + t)
    ops = sorted((o for o in desc.openings if o.wall == wall), key=lambda o: o.offset)
    spans = []                                    # (s_lo, s_hi, z_lo, z_hi) in wall coordinates
    cur = s0
    for o in ops:
        a, b = o.offset, o.offset + o.width
        if a > cur:
            spans.append((cur, a, 0.0, lz))
        if o.sill > 0:
            spans.append((a, b, 0.0, o.sill))
        if o.sill + o.height < lz:
            spans.append((a, b, o.sill + o.height, lz))
        cur = b
    if cur < s1:
        spans.append((cur, s1, 0.0, lz))
    out = []
    for a, b, z0, z1 in spans:
        if along_x:
            out.append((np.array([a, c0, z0]), np.array([b, c1, z1])))
        else:
            out.append((np.array([c0, a, z0]), np.array([c1, b, z1])))
    return out


def _opening_panel(desc: RoomDescription, o: Opening) -> trimesh.Trimesh:
    lx, ly, _ = desc.size
    t = desc.wall_thickness
    g = o.gap
    a, b = o.offset + g, o.offset + o.width - g
    z0, z1 = o.sill + g, o.sill + o.height - g
    mid = {"south": -t / 2, "north": ly + t / 2, "west": -t / 2, "east": lx + t / 2}[o.wall]
    c0, c1 = mid - o.panel_thickness / 2, mid + o.panel_thickness / 2
    if o.wall in ("south", "north"):
        return _box([a, c0, z0], [b, c1, z1])
    return _box([c0, a, z0], [c1, b, z1])


def room_meshes(desc: RoomDescription) -> list[tuple[str, str, trimesh.Trimesh]]:
    """Every shape of the room as (shape id, material id, mesh in world coordinates), in file order."""
    validate(desc)
    lx, ly, lz = desc.size
    t, ts = desc.wall_thickness, desc.slab_thickness
    out = []
    for w in WALLS:
        boxes = [_box(lo, hi) for lo, hi in _wall_boxes(desc, w)]
        out.append((f"wall_{w}", desc.wall_materials.get(w, desc.wall_material), trimesh.util.concatenate(boxes)))
    out.append(("floor", desc.floor_material, _box([-t, -t, -ts], [lx + t, ly + t, 0.0])))
    out.append(("ceiling", desc.ceiling_material, _box([-t, -t, lz], [lx + t, ly + t, lz + ts])))
    for o in desc.openings:
        out.append((o.id, o.material, _opening_panel(desc, o)))
    for f in desc.furniture:
        for sid, mat in _furniture_groups(f):
            out.append((sid, mat, _furniture_mesh(f, mat)))
    return out


def _fmt(v: float) -> str:
    return np.format_float_positional(float(v), precision=6, trim="-")


def _ply_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Deterministic ASCII PLY (vertices rounded to 0.1 mm, shared per box)."""
    v = np.round(np.asarray(mesh.vertices, float), 6) + 0.0   # + 0.0 turns -0.0 into 0.0
    f = np.asarray(mesh.faces, np.int64)
    lines = ["ply", "format ascii 1.0", "comment rfmitsuba scene_builder",
             f"element vertex {len(v)}", "property float x", "property float y", "property float z",
             f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(_fmt(c) for c in row) for row in v]
    lines += ["3 " + " ".join(str(int(i)) for i in row) for row in f]
    return ("\n".join(lines) + "\n").encode("ascii")


def scene_xml(desc: RoomDescription, *, mesh_dir: str = "meshes") -> str:
    """The Mitsuba XML text of a room (meshes referenced as ``<mesh_dir>/<shape id>.ply``)."""
    meshes = room_meshes(desc)
    root = ET.Element("scene", {"version": "2.1.0"})
    root.append(ET.Comment(f" rfmitsuba room '{desc.name}': interior [0, 0, 0]..[{', '.join(_fmt(v) for v in desc.size)}] m,"
                           f" z up; written by rfmitsuba.sim.scene_builder "))
    used = [m for m in desc.materials if any(mat == m.id for _, mat, _ in meshes)]
    for m in used:
        if m.type == "body-tissue":
            b = ET.SubElement(root, "bsdf", {"type": "body-tissue", "id": m.id})
        else:
            b = ET.SubElement(root, "bsdf", {"type": "itu-radio-material", "id": m.id})
            ET.SubElement(b, "string", {"name": "type", "value": m.type})
        ET.SubElement(b, "float", {"name": "thickness", "value": _fmt(m.thickness)})
    for sid, mat, _ in meshes:
        s = ET.SubElement(root, "shape", {"type": "ply", "id": sid})
        ET.SubElement(s, "string", {"name": "filename", "value": f"{mesh_dir}/{sid}.ply"})
        ET.SubElement(s, "boolean", {"name": "face_normals", "value": "true"})
        ET.SubElement(s, "ref", {"id": mat, "name": "bsdf"})
    ET.indent(root, space="    ")
    return ET.tostring(root, encoding="unicode") + "\n"


def write_scene(desc: RoomDescription, folder: str | Path, *, name: str | None = None,
                overwrite: bool = False) -> Path:
    """Write ``<folder>/<name>.xml`` and ``<folder>/meshes/<shape id>.ply``; returns the XML path.

    desc: the room; name: file stem (default ``desc.name``).
    overwrite: replace an existing scene of that name (otherwise :class:`SceneError`).
    Files are written to temporary names first, then renamed.
    """
    name = name or desc.name
    if not _ID.match(name):
        raise SceneError(f"scene name {name!r} must be letters, digits and '_' (starting with a letter)")
    folder = Path(folder)
    xml_path = folder / f"{name}.xml"
    if xml_path.exists() and not overwrite:
        raise SceneError(f"{xml_path} exists; pass overwrite=True to replace it")
    text = scene_xml(desc)                      # validates first: nothing is written for a bad description
    meshes = room_meshes(desc)
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    for sid, _, mesh in meshes:
        _atomic_write(folder / "meshes" / f"{sid}.ply", _ply_bytes(mesh))
    _atomic_write(xml_path, text.encode("utf-8"))
    return xml_path


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)


def triangle_count(desc: RoomDescription) -> int:
    """Number of triangles of the whole room."""
    return int(sum(len(m.faces) for _, _, m in room_meshes(desc)))
