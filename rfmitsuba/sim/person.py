"""A walking person: body mesh, seeded casual walks, and the Sionna object that carries them.

The body (:func:`person_mesh`) is made of closed pieces -- two legs, a torso,
two arms, a neck and a head -- about 1.7 m tall and 0.45 m wide at the
shoulders, standing with its feet at ``position`` and facing ``heading``
(radians, counter-clockwise from +x). The pieces do not touch each other (a
1 cm gap), so no two faces are coplanar. The body is symmetric front/back and
left/right, so the centre of its bounding box is always above the feet; this is
what makes :func:`place` exact with Sionna's ``SceneObject.position`` (the
bounding-box centre).

:func:`walk` gives a casual walk through the free floor: a person strolling
at 0.5-1 m/s whose heading wanders smoothly and who turns away from walls and
furniture, sampled at ``n`` evenly spaced instants over ``duration_s``. The walk is
simulated in steps of at most :data:`MAX_STEP_S` (1.76 s, the paper's 35
positions a minute); every simulated position keeps ``clearance`` (the body's
radius) from walls and from furniture footprints, and every simulated step is
a clear straight line (:meth:`RoomGeometry.segment_clear` with the body's
height). With the default 35 positions the sampled positions are those steps;
fewer positions are instants of the same finer walk.

Adding the person to a Sionna scene::

    from rfmitsuba import person, plugins
    plugins.register()
    scene = sionna.rt.load_scene(xml, merge_shapes=False)
    obj = person.scene_object(folder, kind="tissue")       # writes folder/person.ply
    scene.edit(add=obj)
    for p, h in zip(*person.walk(geometry, seed=0)[:2]):
        person.place(obj, p, h)                             # ~ms per move, no recompile
        ...solve...
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh

from .. import plugins
from ..core import backend
from ..core.errors import PlacementError
from ..plugins.body_tissue import BodyTissueMaterial
from .geometry import RoomGeometry

HEIGHT = 1.7        # m
WIDTH = 0.45        # m, shoulder to shoulder (arms included)
DEPTH = 0.26        # m, front to back

#: Perturber kinds -> (Mitsuba BSDF plugin, its parameters). ``tissue`` is the person;
#: ``metal`` and ``concrete`` are controls of the same shape (a metal or concrete "statue").
PERTURBER_MATERIALS: dict[str, tuple[str, dict]] = {
    "tissue": ("body-tissue", {"relative_permittivity": 40.0, "conductivity": 1.7, "thickness": 0.2}),
    "metal": ("itu-radio-material", {"type": "metal", "thickness": 0.01}),
    "concrete": ("itu-radio-material", {"type": "concrete", "thickness": 0.2}),
}


def _body_parts(height: float, width: float) -> list[trimesh.Trimesh]:
    """Body pieces at the origin (feet at z = 0, facing +x), before scaling to ``height``/``width``."""
    sz = height / HEIGHT
    sw = width / WIDTH
    g = 0.01
    parts = []

    def box(x0, x1, y0, y1, z0, z1):
        parts.append(trimesh.creation.box(bounds=[[x0 * sw, y0 * sw, z0 * sz], [x1 * sw, y1 * sw, z1 * sz]]))

    # legs: 0.13 wide each with a 0.03 gap between them (symmetric about y = 0)
    box(-0.07, 0.07, 0.015, 0.145, 0.0, 0.80)
    box(-0.07, 0.07, -0.145, -0.015, 0.0, 0.80)
    # torso: 0.33 wide, 0.26 deep
    box(-0.13, 0.13, -0.165, 0.165, 0.80 + g, 1.42)
    # arms: 0.05 wide, hanging beside the torso from the shoulders to the hips
    box(-0.05, 0.05, 0.165 + g, 0.225, 0.78, 1.40)
    box(-0.05, 0.05, -0.225, -0.165 - g, 0.78, 1.40)
    # neck and head
    neck = trimesh.creation.cylinder(radius=0.05 * sw, height=(1.50 - 1.42 - 2 * g) * sz, sections=10)
    neck.apply_translation([0, 0, (1.42 + g) * sz + neck.extents[2] / 2])
    parts.append(neck)
    head = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    head.apply_scale([0.095 * sw, 0.085 * sw, 0.095 * sz])
    head.apply_translation([0, 0, (1.70 - 0.095) * sz])
    parts.append(head)
    return parts


def person_mesh(position=(0.0, 0.0, 0.0), heading_rad: float = 0.0, *, height: float = HEIGHT,
               width: float = WIDTH) -> trimesh.Trimesh:
    """The body mesh with its feet at ``position`` (float [3], metres) facing ``heading_rad`` (radians).

    height: top of the head above the feet, metres; width: shoulder width, metres.
    Returns one :class:`trimesh.Trimesh` made of seven closed, non-touching pieces (~200 triangles).
    """
    position = np.asarray(position, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(position)) and math.isfinite(heading_rad)):
        raise PlacementError(f"person position {position} / heading {heading_rad} must be finite")
    if not (height > 0 and width > 0):
        raise PlacementError(f"person height and width must be positive, got {height}, {width}")
    mesh = trimesh.util.concatenate(_body_parts(height, width))
    m = trimesh.transformations.rotation_matrix(heading_rad, [0, 0, 1])
    m[:3, 3] = position
    mesh.apply_transform(m)
    return mesh


def radius(*, width: float = WIDTH) -> float:
    """Horizontal radius of the body's footprint, metres (half the diagonal of width x depth)."""
    return 0.5 * math.hypot(width, DEPTH * width / WIDTH)


def write_person_ply(path: str | Path, *, height: float = HEIGHT, width: float = WIDTH) -> Path:
    """Write the body mesh (feet at the origin, facing +x) as binary PLY; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = trimesh.exchange.ply.export_ply(person_mesh(height=height, width=width), encoding="binary")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path


def xml_snippet(*, mesh: str = "meshes/person.ply", kind: str = "tissue", shape_id: str = "person",
                material_id: str | None = None) -> str:
    """Mitsuba XML for a person (material + shape) to paste into a scene file.

    The mesh stands at the origin; add a ``<transform name="to_world">`` to place it, or move
    the loaded object with :func:`place`.
    """
    plugin, params = _perturber(kind)
    material_id = material_id or f"{shape_id}_{kind}"
    lines = [f'<bsdf type="{plugin}" id="{material_id}">']
    for k, v in params.items():
        if isinstance(v, str):
            lines.append(f'    <string name="{k}" value="{v}"/>')
        else:
            lines.append(f'    <float name="{k}" value="{v}"/>')
    lines += ["</bsdf>", f'<shape type="ply" id="{shape_id}">',
              f'    <string name="filename" value="{mesh}"/>',
              '    <boolean name="face_normals" value="true"/>',
              f'    <ref id="{material_id}" name="bsdf"/>', "</shape>"]
    return "\n".join(lines) + "\n"


def _perturber(kind: str) -> tuple[str, dict]:
    if kind not in PERTURBER_MATERIALS:
        raise PlacementError(f"unknown perturber kind {kind!r}; known: {', '.join(PERTURBER_MATERIALS)}")
    return PERTURBER_MATERIALS[kind]


def radio_material(kind: str = "tissue", *, name: str | None = None):
    """A Sionna radio material for perturber ``kind`` (``tissue`` | ``metal`` | ``concrete``)."""
    plugin, params = _perturber(kind)
    name = name or f"person_{kind}"
    if plugin == "body-tissue":

        return BodyTissueMaterial(name=name, **params)
    from sionna.rt import ITURadioMaterial

    return ITURadioMaterial(name=name, itu_type=params["type"], thickness=params["thickness"])


def scene_object(folder: str | Path, *, kind: str = "tissue", name: str = "person",
                 position=None, heading_rad: float = 0.0, height: float = HEIGHT, width: float = WIDTH):
    """A :class:`sionna.rt.SceneObject` of the body for ``scene.edit(add=obj)``.

    Writes ``<folder>/<name>.ply``; the material is named ``<name>_<kind>`` (distinct from the
    object's name, as Sionna requires). With ``position`` (float [3], metres, the feet) the
    object is placed there, else it stands at the origin.
    """

    backend.variant()
    plugins.register()
    from sionna.rt import SceneObject

    ply = write_person_ply(Path(folder) / f"{name}.ply", height=height, width=width)
    obj = SceneObject(fname=str(ply), name=name, radio_material=radio_material(kind, name=f"{name}_{kind}"))
    obj._rfm_height = height  # noqa: SLF001 - remembered for place()
    if position is not None:
        place(obj, position, heading_rad, height=height)
    return obj


def place(obj, position, heading_rad: float = 0.0, *, height: float | None = None) -> None:
    """Move a body object (from :func:`scene_object`) so its feet are at ``position`` (float [3], m)
    and it faces ``heading_rad`` (radians about +z)."""
    import mitsuba as mi

    p = np.asarray(position, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(p)) and math.isfinite(heading_rad)):
        raise PlacementError(f"person position {p} / heading {heading_rad} must be finite")
    h = height if height is not None else getattr(obj, "_rfm_height", HEIGHT)
    obj.orientation = mi.Point3f(float(heading_rad), 0.0, 0.0)
    obj.position = mi.Point3f(float(p[0]), float(p[1]), float(p[2] + 0.5 * h))


# ---------------------------------------------------------------- walks

class Walk(NamedTuple):
    """A sampled walk: positions float64 [n, 3] (feet, metres, z = floor), headings float64 [n]
    (radians, direction of motion), times float64 [n] (seconds from the start)."""

    positions: np.ndarray
    headings: np.ndarray
    times: np.ndarray


def walk(geometry: RoomGeometry, *, n: int = 35, duration_s: float = 60.0, seed: int = 0,
         clearance: float = 0.25, height: float = HEIGHT, speed: tuple[float, float] = (0.5, 1.0),
         max_attempts: int = 50, avoid: np.ndarray | None = None, gap_m: float = 0.0) -> Walk:
    """A seeded casual walk through the free floor (see the module docstring).

    geometry: the room. n: number of sampled positions, evenly spaced in time over
    ``duration_s`` seconds. clearance: the body's radius, metres, kept from walls and
    furniture footprints. speed: (min, max) walking speed, m/s; the speed drifts smoothly
    within it (it drops below the minimum only where a step must be shortened to stay clear).
    The heading wanders smoothly; each step keeps as close to the wanted heading as the room
    allows, preferring directions with free floor ahead.
    The person is simulated in steps of at most :data:`MAX_STEP_S` seconds (the default 35
    positions over 60 s are exactly such steps); when fewer positions are asked for, they are
    taken at evenly spaced times of that finer walk, so a short sample of a walk is a real walk,
    not a few metre-long jumps across the room.
    avoid: None, or float [M, n, 3] other people's feet at the same ``n`` times [m]: every step
    of this walk keeps at least ``gap_m`` [m] horizontally from each of them at that time (their
    positions between two of the times taken on the straight line).
    Returns a :class:`Walk` (positions float64 [n, 3], headings [n], times [n]); unpack as
    ``positions, headings, times = walk(...)``. Raises :class:`PlacementError` if no clear walk
    is found (room too cluttered for the clearance).
    """
    if n < 1 or not (duration_s > 0) or not (0 < speed[0] <= speed[1]):
        raise PlacementError(f"walk needs n >= 1, duration_s > 0 and 0 < speed min <= max; got n={n}, "
                             f"duration_s={duration_s}, speed={speed}")
    n_fine = max(n, math.ceil(duration_s / MAX_STEP_S - 1e-9) + 1)
    pick = np.round(np.linspace(0, n_fine - 1, n)).astype(int)
    ss = np.random.SeedSequence(seed)
    others = None
    if avoid is not None:                        # the others at every simulated time
        a = np.asarray(avoid, np.float64).reshape(-1, n, 3)
        fine, at = np.linspace(0.0, duration_s, n_fine), np.linspace(0.0, duration_s, n_fine)[pick]
        others = np.stack([np.stack([np.interp(fine, at, w[:, c]) for c in range(3)], 1) for w in a])
    for child in ss.spawn(max_attempts):
        w = _simulate(geometry, np.random.default_rng(child), n=n_fine, duration_s=duration_s,
                      clearance=clearance, height=height, speed=speed, others=others, gap_m=gap_m)
        if w is not None:
            return Walk(w.positions[pick], w.headings[pick], w.times[pick])
    raise PlacementError(f"no clear walk found in {max_attempts} attempts (clearance {clearance} m); "
                         f"the free floor of {geometry.path} is too small or fragmented")


#: Longest simulated step of :func:`walk`, seconds (60 s / 34 steps: the paper's 35 positions a minute).
MAX_STEP_S = 60.0 / 34

_OFFSETS = np.deg2rad(np.r_[0, np.repeat(np.arange(15, 181, 15), 2) * np.tile([1, -1], 12)])


def _simulate(g: RoomGeometry, rng: np.random.Generator, *, n, duration_s, clearance, height, speed,
              others=None, gap_m=0.0):
    z = g.floor_z

    def apart(q, i):
        """``q`` keeps ``gap_m`` from every other person at step ``i``."""
        return others is None or bool(np.all(np.hypot(others[:, i, 0] - q[0], others[:, i, 1] - q[1]) >= gap_m))

    def free_spot(i=None):
        c = np.c_[g.lo[:2] + (g.hi[:2] - g.lo[:2]) * rng.random((256, 2)), np.full(256, z)]
        ok = np.flatnonzero(g.free_mask(c, clearance=clearance, body_height=height))
        if i is not None:
            ok = [k for k in ok if apart(c[k], i)]
        return c[ok[0]] if len(ok) else None

    start = free_spot(0)
    if start is None:
        return None
    t = np.linspace(0.0, duration_s, n)
    dt = duration_s / max(n - 1, 1)
    pos = np.empty((n, 3))
    head = np.empty(n)
    pos[0] = start
    h = rng.uniform(-math.pi, math.pi)
    turn = 0.0                                     # rad per step, a smoothed random walk
    v_mid, v_amp = 0.5 * (speed[0] + speed[1]), 0.5 * (speed[1] - speed[0])
    v_phase, v_period = rng.uniform(0, 2 * math.pi), rng.uniform(8.0, 16.0)
    goal, goal_age = None, 0                       # a spot the person strolls towards

    def clear(p, hh, length):
        q = p + length * np.array([math.cos(hh), math.sin(hh), 0.0])
        return g.segment_clear(p, q, clearance=clearance, body_height=height) and apart(q, i + 1), q

    for i in range(n - 1):
        if goal is None or goal_age > 8 or np.hypot(*(goal - pos[i])[:2]) < 1.0:
            goal = free_spot()
            if goal is None:
                return None
            goal_age = 0
        goal_age += 1
        turn = 0.6 * turn + 0.3 * rng.standard_normal()
        to_goal = math.atan2(goal[1] - pos[i][1], goal[0] - pos[i][0])
        # steer towards the goal, at most 60 degrees per step, plus the wander
        steer = float(np.clip(np.angle(np.exp(1j * (to_goal - h))), -math.pi / 3, math.pi / 3))
        want = h + steer + turn
        v = v_mid + v_amp * math.sin(2 * math.pi * t[i] / v_period + v_phase)
        p = pos[i]
        chosen = None
        for scale in (1.0, 0.7, 0.5):
            length = v * dt * scale
            fallback = None
            sign = 1.0 if rng.random() < 0.5 else -1.0   # which way to try first when blocked
            for off in _OFFSETS * sign:
                ok, q = clear(p, want + off, length)
                if not ok:
                    continue
                if clear(p, want + off, 2.0 * length)[0]:   # free floor ahead: take it
                    chosen = (want + off, q)
                    break
                if fallback is None:
                    fallback = (want + off, q)
            chosen = chosen or fallback
            if chosen is not None:
                break
        if chosen is None:
            return None
        new_h, q = chosen
        h = new_h
        head[i] = h
        pos[i + 1] = q
    head[n - 1] = h
    pos[:, 2] = z
    headings = np.angle(np.exp(1j * head))
    try:
        check_walk(g, pos, clearance=clearance, height=height)
    except PlacementError:
        return None
    return Walk(pos, headings, t)


def check_walk(geometry: RoomGeometry, positions, *, clearance: float = 0.0, height: float = HEIGHT) -> None:
    """Raise :class:`PlacementError` if a walk leaves the free floor.

    positions: float [n, 3], metres (feet). Checks every position (finite, inside the room,
    ``clearance`` from walls and furniture footprints) and every straight step between
    consecutive positions; the message names the index and the obstacle.
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise PlacementError(f"walk positions must have shape [n, 3], got {p.shape}")
    geometry.check_points(p, what="person", clearance=clearance, body_height=height)
    for i in range(len(p) - 1):
        blocker = geometry.segment_blocker(p[i], p[i + 1], clearance=clearance, body_height=height)
        if blocker is not None:
            raise PlacementError(f"person step {i} -> {i + 1} from ({p[i][0]:.3f}, {p[i][1]:.3f}) to "
                                 f"({p[i + 1][0]:.3f}, {p[i + 1][1]:.3f}) passes through {blocker}")
