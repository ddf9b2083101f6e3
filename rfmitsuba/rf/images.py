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
points fall on the finite faces, nothing blocks it) is *not* decided here: the coherent field
(:mod:`rfmitsuba.models.coherent`) learns each image's visibility and reflection gain from data.

Units: metres. Arrays: ``A`` float64 [S, 3, 3], ``b`` float64 [S, 3], ``order`` int64 [S].
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
    """

    A: np.ndarray
    b: np.ndarray
    order: np.ndarray
    label: list

    def __len__(self) -> int:
        return len(self.b)

    def apply(self, y: np.ndarray) -> np.ndarray:
        """Image points of ``y`` (float [..., 3] metres): float64 [..., S, 3]."""
        y = np.asarray(y, np.float64)
        return np.einsum("sij,...j->...si", self.A, y) + self.b

    def to_arrays(self) -> dict:
        return {"A": self.A, "b": self.b, "order": self.order, "label": np.asarray(self.label, dtype=str)}

    @classmethod
    def from_arrays(cls, d: dict) -> "ImageMaps":
        A = np.asarray(d["A"], np.float64)
        b = np.asarray(d["b"], np.float64)
        order = np.asarray(d["order"], np.int64)
        label = [str(s) for s in np.asarray(d["label"]).tolist()]
        if A.shape != (len(b), 3, 3) or b.shape != (len(b), 3) or order.shape != (len(b),) or len(label) != len(b):
            raise ConfigError(f"image maps: inconsistent shapes A {A.shape}, b {b.shape}, order {order.shape}, "
                              f"{len(label)} labels")
        return cls(A=A, b=b, order=order, label=label)


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
               furniture_order: int = 2, tol: float = 1e-6) -> ImageMaps:
    """Enumerate the image maps of a room (see the module docstring).

    Args:
        room: the room's planes (usually :func:`box_planes` of its interior).
        furniture: the furniture's planes.
        room_order: most reflections on room planes alone (0 = direct path only).
        furniture_order: 0 (no furniture images), 1 (one furniture reflection) or 2 (one
            furniture reflection combined with one room reflection, before or after it).
        tol: maps whose ``A`` and ``b`` agree within ``tol`` are the same image.
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
    A_out, b_out, order, label = [], [], [], []
    seen = []
    for seq, A, b in seqs:
        key = np.concatenate([A.ravel(), b])
        if any(np.max(np.abs(key - k)) < tol for k in seen):
            continue
        seen.append(key)
        A_out.append(A)
        b_out.append(b)
        order.append(len(seq))
        label.append("|".join(p.name for p in seq) or "direct")
    return ImageMaps(A=np.asarray(A_out), b=np.asarray(b_out), order=np.asarray(order, np.int64), label=label)


def scene_image_maps(geometry, *, room_order: int = 2, furniture_order: int = 2,
                     min_face_area: float = 0.05) -> ImageMaps:
    """Image maps of a :class:`~rfmitsuba.sim.geometry.RoomGeometry`: its interior box and the faces
    of every piece of furniture whose face area is at least ``min_face_area`` (m^2)."""
    lo, hi = geometry.bounds
    room = box_planes(lo, hi)
    room_set = {(p.normal, round(p.offset, 4)) for p in room}
    furn: list[Plane] = []
    have = set(room_set)
    for name, (flo, fhi) in sorted(geometry.furniture_bounds().items()):
        ext = np.asarray(fhi) - np.asarray(flo)
        for p in box_planes(flo, fhi, prefix=f"{name}:"):
            axis = int(np.argmax(np.abs(p.normal)))
            area = float(np.prod(np.delete(ext, axis)))
            key = (p.normal, round(p.offset, 4))
            # faces flush against a room plane (within 5 cm) are hidden behind the furniture
            flush = any(q.normal == p.normal and abs(q.offset - p.offset) < 0.05 for q in room)
            if area < min_face_area or key in have or flush:
                continue
            have.add(key)
            furn.append(p)
    return image_maps(room, furn, room_order=room_order, furniture_order=furniture_order)
