"""Virtual (image) sources of a room: the specular paths' geometry, from the scene's planes.

A specular path that reflects off planes ``P_1 ... P_n`` between a transmitter at ``y`` and a
receiver at ``x`` has the length ``|x - M(y)|``, where ``M = R_n o ... o R_1`` is the
composition of the mirror maps of those planes (the image method). Each mirror map is an
affine isometry ``R(y) = (I - 2 n n^T) y + 2 d n`` of a plane ``n . y = d``, so each image map
is ``M(y) = A y + b`` with ``A`` orthogonal. Seen from ``x``, the path arrives from the
direction of the image point ``M(y)``.

:func:`image_maps` enumerates these maps for

* the room's six bounding planes (floor, ceiling, four walls), every sequence up to
  ``room_order`` reflections (no plane twice in a row), and
* the faces of every piece of furniture (its axis-aligned box, from
  :meth:`rfmitsuba.sim.geometry.RoomGeometry.furniture_bounds`): one furniture reflection,
  alone or followed / preceded by one room reflection (``furniture_order`` = 2),

and drops maps that coincide (the same ``A`` and ``b`` reached by two orders of
perpendicular planes). Whether a path exists for a given pair of positions (the reflection
points fall on the finite faces, nothing blocks it) is *not* decided here: the image-source field
(:mod:`rfmitsuba.models.coherent`) learns each image's visibility from data, and the coherent
Gaussian field asks :mod:`rfmitsuba.sim.visibility`, which ray-casts the path rebuilt from the
image's planes (:attr:`ImageMaps.planes`).

Units: metres. Arrays: ``A`` float64 [S, 3, 3], ``b`` float64 [S, 3], ``order`` int64 [S],
``planes`` float64 [S, O, 4].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import ConfigError


@dataclass
class ImageMaps:
    """S affine image maps ``M_i(y) = A_i y + b_i`` (metres) and their reflection counts.

    Attributes:
        A: float64 [S, 3, 3], orthogonal linear parts.
        b: float64 [S, 3], offsets, metres.
        order: int64 [S], number of reflections (0 = the direct path).
        label: list of S strings naming the planes, e.g. ``"x=0.00|z=2.80"``.
        planes: float64 [S, O, 4] or None: the planes reflected in, in the order the path meets
            them from the transmitter, each as (unit normal [3], offset [m]) of ``n . y = d``;
            rows past an image's ``order`` are NaN (O = the largest order, at least 1). None for
            maps saved before planes were kept.
    """

    A: np.ndarray
    b: np.ndarray
    order: np.ndarray
    label: list
    planes: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.b)

    def apply(self, y: np.ndarray) -> np.ndarray:
        """Image points of ``y`` (float [..., 3] metres): float64 [..., S, 3]."""
        y = np.asarray(y, np.float64)
        return np.einsum("sij,...j->...si", self.A, y) + self.b

    def to_arrays(self) -> dict:
        out = {"A": self.A, "b": self.b, "order": self.order, "label": np.asarray(self.label, dtype=str)}
        if self.planes is not None:
            out["planes"] = self.planes
        return out

    @classmethod
    def from_arrays(cls, d: dict) -> "ImageMaps":
        A = np.asarray(d["A"], np.float64)
        b = np.asarray(d["b"], np.float64)
        order = np.asarray(d["order"], np.int64)
        label = [str(s) for s in np.asarray(d["label"]).tolist()]
        planes = np.asarray(d["planes"], np.float64) if "planes" in d else None
        if A.shape != (len(b), 3, 3) or b.shape != (len(b), 3) or order.shape != (len(b),) or len(label) != len(b) \
                or (planes is not None and (planes.ndim != 3 or planes.shape[0] != len(b) or planes.shape[2] != 4)):
            raise ConfigError(f"image maps: inconsistent shapes A {A.shape}, b {b.shape}, order {order.shape}, "
                              f"{len(label)} labels, planes {None if planes is None else planes.shape}")
        return cls(A=A, b=b, order=order, label=label, planes=planes)


@dataclass(frozen=True)
class Plane:
    """A plane ``normal . y = offset`` (unit normal, metres) with a short name."""

    normal: tuple
    offset: float
    name: str

    def matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """(A float64 [3, 3], b float64 [3]) of the mirror map across this plane."""
        n = np.asarray(self.normal, np.float64)
        return np.eye(3) - 2.0 * np.outer(n, n), 2.0 * self.offset * n


def box_planes(lo, hi, *, prefix: str = "") -> list[Plane]:
    """The six planes of an axis-aligned box ``lo..hi`` (float [3] metres)."""
    out = []
    for axis, name in enumerate("xyz"):
        n = [0.0, 0.0, 0.0]
        n[axis] = 1.0
        for v in (float(lo[axis]), float(hi[axis])):
            out.append(Plane(tuple(n), v, f"{prefix}{name}={v:.2f}"))
    return out


def image_maps(room: list[Plane], furniture: list[Plane] = (), *, room_order: int = 2,
               furniture_order: int = 2, tol: float = 1e-6, distinct_paths: bool = False) -> ImageMaps:
    """Enumerate the image maps of a room (see the module docstring).

    Args:
        room: the room's planes (usually :func:`box_planes` of its interior).
        furniture: the furniture's planes.
        room_order: most reflections on room planes alone (0 = direct path only).
        furniture_order: 0 (no furniture images), 1 (one furniture reflection) or 2 (one
            furniture reflection combined with one room reflection, before or after it).
        tol: maps whose ``A`` and ``b`` agree within ``tol`` are the same image.
        distinct_paths: keep every plane sequence as its own image, even where two sequences give
            the same map (reflections across perpendicular planes commute: the image point is the
            same, but the paths meet the planes in a different order and at most one of them
            exists for a pair of positions). Ray-cast visibility needs this.
    Returns:
        :class:`ImageMaps`, the direct path first, then by increasing order.
    """
    if room_order < 0 or furniture_order not in (0, 1, 2):
        raise ConfigError(f"room_order must be >= 0 and furniture_order 0, 1 or 2; got {room_order}, {furniture_order}")
    mats = {p: p.matrix() for p in list(room) + list(furniture)}
    A0, b0 = np.eye(3), np.zeros(3)
    seqs: list[tuple[tuple, np.ndarray, np.ndarray]] = [((), A0, b0)]
    frontier = [((), A0, b0)]
    for _ in range(room_order):
        nxt = []
        for seq, A, b in frontier:
            for p in room:
                if seq and seq[-1] == p:
                    continue
                Ap, bp = mats[p]
                nxt.append((seq + (p,), Ap @ A, Ap @ b + bp))
        seqs += nxt
        frontier = nxt
    if furniture_order >= 1:
        for f in furniture:
            Af, bf = mats[f]
            seqs.append(((f,), Af, bf))
            if furniture_order >= 2:
                for p in room:
                    Ap, bp = mats[p]
                    seqs.append(((f, p), Ap @ Af, Ap @ bf + bp))  # furniture first, then the room plane
                    seqs.append(((p, f), Af @ Ap, Af @ bp + bf))  # room plane first
    A_out, b_out, order, label, seq_out = [], [], [], [], []
    seen = []
    for seq, A, b in seqs:
        key = np.concatenate([A.ravel(), b])
        if not distinct_paths and any(np.max(np.abs(key - k)) < tol for k in seen):
            continue
        seen.append(key)
        A_out.append(A)
        b_out.append(b)
        order.append(len(seq))
        label.append("|".join(p.name for p in seq) or "direct")
        seq_out.append(seq)
    planes = np.full((len(seq_out), max(1, max(order)), 4), np.nan)
    for i, seq in enumerate(seq_out):
        for j, p in enumerate(seq):
            planes[i, j, :3], planes[i, j, 3] = p.normal, p.offset
    return ImageMaps(A=np.asarray(A_out), b=np.asarray(b_out), order=np.asarray(order, np.int64), label=label,
                     planes=planes)


def face_planes(vertices: np.ndarray, faces: np.ndarray, *, min_area: float, prefix: str = "",
                decimals: int = 3) -> list[Plane]:
    """The planes a triangle mesh's faces lie in, with at least ``min_area`` (m^2) of faces each.

    Triangles are grouped by their plane (outward unit normal and offset, rounded to ``decimals``);
    a group's area is the sum of its triangles'. A box gives its six faces; a bed gives its
    mattress top as well as its frame.

    Args:
        vertices: float [V, 3] metres; faces: int [F, 3].
    Returns:
        The planes, largest area first, named ``prefix`` + e.g. ``z=0.50``.
    """
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    cr = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area = 0.5 * np.linalg.norm(cr, axis=1)
    keep = area > 1e-12
    n = cr[keep] / (2.0 * area[keep, None])
    d = np.einsum("ij,ij->i", n, v[f[keep, 0]])
    key = np.round(np.c_[n, d], decimals) + 0.0                      # + 0.0: no negative zeros
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    tot = np.bincount(inv.ravel(), weights=area[keep], minlength=len(uniq))
    out = []
    for i in np.argsort(-tot, kind="stable"):
        if tot[i] < min_area:
            break
        nn = uniq[i, :3] / np.linalg.norm(uniq[i, :3])
        axis = int(np.argmax(np.abs(nn)))
        name = f"{'xyz'[axis]}={uniq[i, 3] * np.sign(nn[axis]) + 0.0:.2f}" if abs(nn[axis]) > 0.999 else \
            f"n=({nn[0]:.2f},{nn[1]:.2f},{nn[2]:.2f})|d={uniq[i, 3]:.2f}"
        out.append(Plane(tuple(float(c) for c in nn), float(uniq[i, 3]), f"{prefix}{name}"))
    return out


def scene_image_maps(geometry, *, room_order: int = 2, furniture_order: int = 2,
                     min_face_area: float = 0.05, distinct_paths: bool = False,
                     furniture_planes: str = "box") -> ImageMaps:
    """Image maps of a :class:`~rfmitsuba.sim.geometry.RoomGeometry`: its interior box and the
    furniture's planes with at least ``min_face_area`` (m^2) of face each: the faces of each
    piece's axis-aligned box (``furniture_planes = "box"``) or the planes its mesh's triangles
    lie in (``"faces"``: also inner surfaces such as a mattress below a bed's frame, slanted
    faces, and doors and windows set back from their wall; :func:`face_planes`). Faces within 5 cm
    of a room plane, parallel to it, are left out (the room plane's image stands for them), and
    so, for ``"faces"``, are faces within 5 cm of a furniture plane already kept.
    ``distinct_paths`` as :func:`image_maps`."""
    if furniture_planes not in ("box", "faces"):
        raise ConfigError(f"furniture_planes must be 'box' or 'faces', got {furniture_planes!r}")
    lo, hi = geometry.bounds
    room = box_planes(lo, hi)
    room_set = {(p.normal, round(p.offset, 4)) for p in room}
    furn: list[Plane] = []
    have = set(room_set)
    if furniture_planes == "box":
        cands = []
        for name, (flo, fhi) in sorted(geometry.furniture_bounds().items()):
            ext = np.asarray(fhi) - np.asarray(flo)
            for p in box_planes(flo, fhi, prefix=f"{name}:"):
                axis = int(np.argmax(np.abs(p.normal)))
                cands.append((p, float(np.prod(np.delete(ext, axis)))))
    else:
        pieces: dict[str, list] = {}
        for sh in geometry.shapes:
            if sh.kind in ("furniture", "door", "window"):   # a door is often set back from its wall
                pieces.setdefault(sh.object, []).append(sh.mesh)
        cands = []
        for name in sorted(pieces):
            verts, tris, off = [], [], 0
            for m in pieces[name]:
                verts.append(np.asarray(m.vertices))
                tris.append(np.asarray(m.faces) + off)
                off += len(m.vertices)
            for p in face_planes(np.concatenate(verts), np.concatenate(tris), min_area=min_face_area,
                                 prefix=f"{name}:"):
                cands.append((p, np.inf))
        # faces that look at the room's centre first: of two parallel faces 5 cm apart, the
        # visible one is kept (a door's front, not its back)
        centre = 0.5 * (np.asarray(lo, np.float64) + np.asarray(hi, np.float64))
        cands.sort(key=lambda c: float(np.dot(c[0].normal, centre) - c[0].offset) <= 0.0)
    for p, area in cands:
        key = (p.normal, round(p.offset, 4))
        flip = (tuple(-c + 0.0 for c in p.normal), round(-p.offset, 4))
        # faces flush against a room plane (within 5 cm) are hidden behind the furniture
        # (or, for mesh faces, against a furniture plane already kept: the far side of a thin door)
        flush = any(abs(abs(np.dot(q.normal, p.normal)) - 1.0) < 1e-6
                    and abs(q.offset - np.dot(q.normal, p.normal) * p.offset) < 0.05
                    for q in (room if furniture_planes == "box" else room + furn))
        if area < min_face_area or key in have or flip in have or flush:
            continue
        have.add(key)
        furn.append(p)
    return image_maps(room, furn, room_order=room_order, furniture_order=furniture_order,
                      distinct_paths=distinct_paths)
