"""Room geometry read from a Mitsuba scene XML: bounds, free space, placement checks.

:class:`RoomGeometry` answers the questions antenna sampling and person walks
ask -- is this point inside the room, inside a piece of furniture, is the
straight line between two points clear -- with NumPy only (no JIT, no Sionna).

Reading the XML: ``<shape type="ply">`` and ``<shape type="obj">`` with
``<string name="filename">`` (relative to the XML's folder) and an optional
``<transform name="to_world">`` made of ``matrix``, ``translate``, ``scale``
and ``rotate`` entries; ``<default>`` values are substituted for ``$name``.
Other shape types (``cube``, ``rectangle``, ``sphere``, ...) and ``<include>``
raise :class:`SceneError`, as do malformed XML and missing or unreadable
meshes; each message names the file.

Id convention (the one :mod:`rfmitsuba.sim.scene_builder` writes; a leading
``mesh-`` is dropped first, as Sionna does):

- ids starting with ``wall``, ``floor``, ``ceiling``, ``door`` or ``window`` are
  the room's structure;
- every other shape is furniture; in an id ``<object>__<rest>`` the object is
  the text before ``__`` (multi-material pieces).

The room is taken to be an axis-aligned box: its interior (:attr:`bounds`)
runs from the top of the floor shapes to the bottom of the ceiling shapes, and
horizontally between the inner faces of the walls (a wall counts on the side of
the floor's centre it lies on). Furniture is represented by the convex hulls of
the connected pieces of its mesh (exact for boxes, conservative otherwise);
clearances enlarge each hull's faces outward by the clearance (a box grows by
the clearance on every side). All distances are metres.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trimesh

from ..core.errors import PlacementError, SceneError
from ..data.scene_xml import Shape, read_shapes

_BIG = 1e9


def _box_planes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes of the axis-aligned bounding box of ``points`` [M, k] (fallback for flat pieces)."""
    k = points.shape[1]
    n = np.concatenate([np.eye(k), -np.eye(k)])
    d = np.concatenate([points.max(0), -points.min(0)])
    return n, d


def _hull_planes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit outward normals [P,3] and offsets [P] of the convex hull of ``points`` (n.x <= d inside)."""
    try:
        hull = trimesh.convex.convex_hull(points)
    except Exception:  # noqa: BLE001 - flat or degenerate piece
        return _box_planes(points)
    if not hull.is_volume:
        return _box_planes(points)
    n = np.asarray(hull.face_normals, float)
    d = np.einsum("ij,ij->i", n, hull.triangles[:, 0, :])
    key = np.round(np.c_[n, d], 6)
    _, idx = np.unique(key, axis=0, return_index=True)
    idx = np.sort(idx)
    return n[idx], d[idx]


def _hull_planes_2d(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit outward normals [P,2] and offsets [P] of the 2-D convex hull of ``points`` [M,2]."""
    from scipy.spatial import ConvexHull

    pts = np.unique(np.round(points, 9), axis=0)
    try:
        hull = ConvexHull(pts)
    except Exception:  # noqa: BLE001 - collinear footprint (a vertical panel seen edge-on)
        return _box_planes(points)
    eq = hull.equations          # [P, 3]: n.x + c <= 0 inside, n unit
    return eq[:, :2].copy(), -eq[:, 2].copy()


def _pad(rows: list[np.ndarray], width: int, fill: float) -> np.ndarray:
    k = max(len(r) for r in rows)
    out = np.full((len(rows), k) + rows[0].shape[1:], fill)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


class RoomGeometry:
    """Geometry of one room scene. Build with :meth:`from_xml`.

    Attributes:
        path: the XML file.
        shapes: every :class:`Shape`.
        lo, hi: float64 [3] interior corners, metres.
    """

    def __init__(self, shapes: list[Shape], *, path: Path | None = None):
        self.path = path
        self.shapes = shapes
        self.lo, self.hi = self._interior(shapes)
        pieces = []
        for s in shapes:
            if s.kind != "furniture":
                continue
            for comp in s.mesh.split(only_watertight=False):
                v = np.asarray(comp.vertices, float)
                pieces.append((s.object, v))
        self.piece_object = [p[0] for p in pieces]
        self.objects = sorted(set(self.piece_object))
        if pieces:
            planes = [_hull_planes(v) for _, v in pieces]
            planes2 = [_hull_planes_2d(v[:, :2]) for _, v in pieces]
            self._n = _pad([p[0] for p in planes], 0, 0.0)                # [C, P, 3]
            self._d = _pad([p[1] for p in planes], 0, _BIG)               # [C, P]
            self._n2 = _pad([p[0] for p in planes2], 0, 0.0)              # [C, Q, 2]
            self._d2 = _pad([p[1] for p in planes2], 0, _BIG)             # [C, Q]
            self._zr = np.array([[v[:, 2].min(), v[:, 2].max()] for _, v in pieces])   # [C, 2]
            self._bb = np.array([[v.min(0), v.max(0)] for _, v in pieces])              # [C, 2, 3]
        else:
            self._n = np.zeros((0, 1, 3))
            self._d = np.zeros((0, 1))
            self._n2 = np.zeros((0, 1, 2))
            self._d2 = np.zeros((0, 1))
            self._zr = np.zeros((0, 2))
            self._bb = np.zeros((0, 2, 3))

    # ------------------------------------------------------------ construction
    @classmethod
    def from_xml(cls, xml_path: str | Path) -> "RoomGeometry":
        """Read a Mitsuba scene XML and its meshes (see the module docstring)."""
        xml_path = Path(xml_path)
        return cls(read_shapes(xml_path), path=xml_path)

    @classmethod
    def from_scene(cls, name: str) -> "RoomGeometry":
        """Geometry of built-in scene ``name`` (see :mod:`rfmitsuba.scenes`)."""
        import rfmitsuba.scenes as sc  # the top-level scenes/ folder, installed as rfmitsuba.scenes

        return cls.from_xml(sc.path(name))

    @staticmethod
    def _interior(shapes: list[Shape]) -> tuple[np.ndarray, np.ndarray]:
        where = shapes[0].id if shapes else "?"
        floors = [s for s in shapes if s.kind == "floor"]
        walls = [s for s in shapes if s.kind == "wall"]
        ceilings = [s for s in shapes if s.kind == "ceiling"]
        if not floors or not walls:
            raise SceneError(f"scene has no {'floor' if not floors else 'wall'} shape (ids starting with "
                             f"'floor' / 'wall'); cannot find the room (first shape {where!r})")
        fb = np.array([s.mesh.bounds for s in floors])
        z0 = fb[:, 1, 2].max()
        c = 0.5 * (fb[:, 0, :2].min(0) + fb[:, 1, :2].max(0))
        lo = np.array([-np.inf, -np.inf, z0])
        hi = np.array([np.inf, np.inf, np.nan])
        for s in walls:
            b = s.mesh.bounds
            for ax in (0, 1):
                if b[1, ax] <= c[ax]:
                    lo[ax] = max(lo[ax], b[1, ax])
                elif b[0, ax] >= c[ax]:
                    hi[ax] = min(hi[ax], b[0, ax])
        hi[2] = min(s.mesh.bounds[0, 2] for s in ceilings) if ceilings else max(s.mesh.bounds[1, 2] for s in walls)
        lo, hi = np.round(lo, 6), np.round(hi, 6)        # PLY stores float32; keep whole millimetres whole
        if not np.all(np.isfinite(lo)) or not np.all(np.isfinite(hi)) or np.any(hi <= lo):
            raise SceneError(f"cannot find a rectangular room interior from the walls (got {lo}..{hi}); "
                             f"walls must enclose the floor's centre on all four sides")
        return lo, hi

    # ------------------------------------------------------------ properties
    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Interior corners (min [3], max [3]), metres."""
        return self.lo.copy(), self.hi.copy()

    @property
    def size(self) -> np.ndarray:
        """Interior size [3], metres."""
        return self.hi - self.lo

    @property
    def floor_z(self) -> float:
        """Height of the floor's top face, metres."""
        return float(self.lo[2])

    def furniture_bounds(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Axis-aligned bounds (min [3], max [3]) of each furniture object, metres."""
        out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for obj, bb in zip(self.piece_object, self._bb):
            if obj in out:
                out[obj] = (np.minimum(out[obj][0], bb[0]), np.maximum(out[obj][1], bb[1]))
            else:
                out[obj] = (bb[0].copy(), bb[1].copy())
        return out

    # ------------------------------------------------------------ point tests
    def _as_points(self, points) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        if p.ndim == 1:
            p = p[None]
        if p.ndim != 2 or p.shape[1] != 3:
            raise PlacementError(f"points must have shape [N, 3], got {np.shape(points)}")
        return p

    def _piece_margin(self, p: np.ndarray, body_height: float | None) -> np.ndarray:
        """Signed 'hull distance' [N, C]: max over faces of n.x - d (<= 0 inside)."""
        if len(self._d) == 0:
            return np.full((len(p), 0), np.inf)
        if body_height is None:
            return np.max(np.einsum("cpk,nk->ncp", self._n, p) - self._d[None], axis=2)
        m = np.max(np.einsum("cqk,nk->ncq", self._n2, p[:, :2]) - self._d2[None], axis=2)    # [N, C]
        # pieces entirely below the feet or above the head do not block the body
        out_z = (self._zr[None, :, 1] <= p[:, None, 2] + 1e-9) | (self._zr[None, :, 0] >= p[:, None, 2] + body_height)
        return np.where(out_z, np.inf, m)

    def _room_margin(self, p: np.ndarray, body_height: float | None) -> np.ndarray:
        """Distance [N] from the interior's faces, negative outside (horizontal only for a body)."""
        d = np.minimum(p - self.lo, self.hi - p)
        if body_height is None:
            return d.min(axis=1)
        dz = np.minimum(p[:, 2] - self.lo[2] + 1e-9, self.hi[2] - (p[:, 2] + body_height))
        return np.minimum(d[:, :2].min(axis=1), np.where(dz < 0, dz, np.inf))

    def free_mask(self, points, *, clearance: float = 0.0, body_height: float | None = None) -> np.ndarray:
        """Which points are in free space.

        points: float [N, 3], metres. clearance: minimum distance to walls, floor, ceiling and
        furniture, metres. body_height: if set, each point is the foot of a vertical body of that
        height (metres): it must stand inside the room (clearance counted horizontally) and its
        column must keep ``clearance`` from the footprint of any furniture piece at its height.
        Returns bool [N]; non-finite points are not free.
        """
        p = self._as_points(points)
        ok = np.all(np.isfinite(p), axis=1)
        q = np.where(ok[:, None], p, 0.0)
        ok &= self._room_margin(q, body_height) >= clearance
        if len(self._d):
            ok &= np.all(self._piece_margin(q, body_height) > clearance, axis=1)
        return ok

    def explain(self, point, *, clearance: float = 0.0, body_height: float | None = None) -> str | None:
        """Why one point [3] is not free (``None`` if it is): ``"not finite"``, ``"outside the room"``,
        ``"inside 'bed'"`` or ``"within 0.25 m of 'bed'"``."""
        p = self._as_points(point)
        if not np.all(np.isfinite(p)):
            return "not finite"
        rm = self._room_margin(p, body_height)[0]
        if rm < 0:
            return "outside the room"
        if len(self._d):
            m = self._piece_margin(p, body_height)[0]
            i = int(np.argmin(m))
            if m[i] <= 0:
                return f"inside '{self.piece_object[i]}'"
        if rm < clearance:
            return f"within {clearance:g} m of the walls, floor or ceiling"
        if len(self._d):
            if m[i] <= clearance:
                return f"within {clearance:g} m of '{self.piece_object[i]}'"
        return None

    def check_points(self, points, *, what: str = "antenna", clearance: float = 0.0,
                     body_height: float | None = None) -> None:
        """Raise :class:`PlacementError` for the first point that is not free.

        points: float [N, 3], metres. The message names the index, the position and the reason,
        e.g. ``"antenna 3 at (1.200, 0.800, 0.400) is inside 'bed'"``.
        """
        p = self._as_points(points)
        bad = np.flatnonzero(~self.free_mask(p, clearance=clearance, body_height=body_height))
        if len(bad):
            i = int(bad[0])
            why = self.explain(p[i], clearance=clearance, body_height=body_height)
            more = f" ({len(bad) - 1} more position(s) are not free either)" if len(bad) > 1 else ""
            raise PlacementError(f"{what} {i} at {_fmt_point(p[i])} is {why}{more}")

    # ------------------------------------------------------------ sampling
    def sample_free(self, n: int, *, rng: np.random.Generator | int | None = None,
                    z_range: tuple[float, float] | None = None, clearance: float = 0.1,
                    max_tries: int = 200) -> np.ndarray:
        """``n`` points drawn uniformly from the free space, float64 [n, 3], metres.

        rng: a NumPy Generator or a seed. z_range: (lo, hi) heights above the floor, metres
        (default: the whole interior height). clearance: distance to walls and furniture, metres.
        Raises :class:`PlacementError` when the free region is (nearly) empty.
        """
        if n < 0:
            raise PlacementError(f"n must be >= 0, got {n}")
        rng = np.random.default_rng(rng)
        lo = self.lo + clearance
        hi = self.hi - clearance
        if z_range is not None:
            z0, z1 = (float(z_range[0]), float(z_range[1]))
            if not (math.isfinite(z0) and math.isfinite(z1)) or z1 < z0:
                raise PlacementError(f"z_range must be finite (lo, hi) with lo <= hi, got {z_range}")
            lo[2] = max(lo[2], self.lo[2] + z0)
            hi[2] = min(hi[2], self.lo[2] + z1)
        if np.any(hi < lo):
            raise PlacementError(f"no free space: clearance {clearance} m and z_range {z_range} leave an empty "
                                 f"box in room {self.lo}..{self.hi}")
        out = []
        got = 0
        batch = max(256, 2 * n)
        for _ in range(max_tries):
            if got >= n:
                break
            c = lo + (hi - lo) * rng.random((batch, 3))
            c = c[self.free_mask(c, clearance=clearance)]
            out.append(c)
            got += len(c)
        if got < n:
            raise PlacementError(f"found only {got} of {n} free points (clearance {clearance} m, z_range "
                                 f"{z_range}); the free space is too small")
        return np.concatenate(out)[:n].astype(np.float64)

    # ------------------------------------------------------------ segments
    def segment_clear(self, a, b, *, clearance: float = 0.0, body_height: float | None = None) -> bool:
        """Whether the straight segment a -> b (float [3] each, metres) stays in free space.

        With ``body_height`` the segment is the path of a standing body's feet (see
        :meth:`free_mask`). Exact for box furniture (segment clipping against each hull).
        """
        return self.segment_blocker(a, b, clearance=clearance, body_height=body_height) is None

    def segment_blocker(self, a, b, *, clearance: float = 0.0, body_height: float | None = None) -> str | None:
        """What blocks the segment a -> b: ``None`` if clear, else ``"the walls"`` or ``"'<object>'"``."""
        a = np.asarray(a, np.float64).reshape(3)
        b = np.asarray(b, np.float64).reshape(3)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            return "a non-finite position"
        pts = np.stack([a, b])
        # the interior shrunk by the clearance is convex: both ends inside <=> segment inside
        if np.any(self._room_margin(pts, body_height) < clearance):
            return "the walls"
        if not len(self._d):
            return None
        if body_height is None:
            nd = np.einsum("cpk,k->cp", self._n, b - a)             # [C, P]
            na = np.einsum("cpk,k->cp", self._n, a) - self._d - clearance
        else:
            nd = np.einsum("cqk,k->cq", self._n2, (b - a)[:2])
            na = np.einsum("cqk,k->cq", self._n2, a[:2]) - self._d2 - clearance
        # inside piece c for t with na + t*nd <= 0 on every face; clip [0, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -na / nd
        enter = np.where(nd < 0, t, -np.inf).max(axis=1)
        leave = np.where(nd > 0, t, np.inf).min(axis=1)
        parallel_out = np.any((nd == 0) & (na > 0), axis=1)
        hit = (np.maximum(enter, 0.0) < np.minimum(leave, 1.0) + 1e-12) & ~parallel_out
        if body_height is not None:
            z = a[2]
            hit &= ~((self._zr[:, 1] <= z + 1e-9) | (self._zr[:, 0] >= z + body_height))
        idx = np.flatnonzero(hit)
        if len(idx):
            return f"'{self.piece_object[int(idx[0])]}'"
        return None

    # ------------------------------------------------------------ devices
    def corner(self, *, inset: float = 0.3, height: float = 2.0) -> np.ndarray:
        """A fixed device position in a room corner, float64 [3], metres.

        The corners are tried in the order (min x, min y), (max x, min y), (max x, max y),
        (min x, max y); the first one that is free (with 0.05 m clearance) at ``inset`` metres
        from both walls and ``height`` metres above the floor is returned.
        """
        lo, hi = self.lo, self.hi
        z = lo[2] + height
        cands = np.array([[lo[0] + inset, lo[1] + inset, z], [hi[0] - inset, lo[1] + inset, z],
                          [hi[0] - inset, hi[1] - inset, z], [lo[0] + inset, hi[1] - inset, z]])
        ok = self.free_mask(cands, clearance=0.05)
        if not ok.any():
            reasons = "; ".join(f"{_fmt_point(c)}: {self.explain(c, clearance=0.05)}" for c in cands)
            raise PlacementError(f"no free corner at inset {inset} m, height {height} m ({reasons})")
        return cands[int(np.argmax(ok))].copy()

    # ------------------------------------------------------------ plotting
    def plot_top_view(self, ax, *, labels: bool = True):
        """Draw the floor plan on a matplotlib axes: walls, door/window panels, furniture footprints.

        Returns the axes. x and y in metres, equal aspect.
        """
        from matplotlib.patches import Polygon

        colours = {"wall": "0.55", "door": "#a0522d", "window": "#87ceeb"}
        for s in self.shapes:
            if s.kind in ("floor", "ceiling"):
                continue
            for comp in s.mesh.split(only_watertight=False):
                hull = _footprint(np.asarray(comp.vertices)[:, :2])
                if s.kind == "furniture":
                    ax.add_patch(Polygon(hull, closed=True, facecolor="#f4d9a6", edgecolor="#8b5a2b", lw=0.8,
                                         alpha=0.8))
                else:
                    ax.add_patch(Polygon(hull, closed=True, facecolor=colours[s.kind], edgecolor="none"))
        if labels:
            for obj, (lo, hi) in self.furniture_bounds().items():
                c = 0.5 * (lo + hi)
                ax.text(c[0], c[1], obj, ha="center", va="center", fontsize=7)
        t = 0.3
        ax.set_xlim(self.lo[0] - t, self.hi[0] + t)
        ax.set_ylim(self.lo[1] - t, self.hi[1] + t)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        return ax


def _footprint(xy: np.ndarray) -> np.ndarray:
    """Corners [K, 2] of the convex hull of 2-D points (their bounding rectangle if degenerate)."""
    from scipy.spatial import ConvexHull

    pts = np.unique(np.round(xy, 9), axis=0)
    try:
        return pts[ConvexHull(pts).vertices]
    except Exception:  # noqa: BLE001 - collinear points (a panel seen edge-on)
        lo, hi = pts.min(0), pts.max(0)
        return np.array([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]]])


def _fmt_point(p) -> str:
    return "(" + ", ".join(f"{float(v):.3f}" for v in np.asarray(p).reshape(-1)) + ")"
