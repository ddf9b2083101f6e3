"""Which specular paths of a known room exist, by Mitsuba ray casts in the project's Dr.Jit JIT.

An image source (:mod:`rfmitsuba.rf.images`) stands for the specular path that reflects off the
planes ``P_1 ... P_n`` between a transmitter ``y`` and a receiver ``x``. Whether that path exists
for a pair of positions is a question of the room's finite geometry, which the image map alone
does not answer. :class:`SpecularVisibility` answers it the way a ray tracer does:

1. **Reflection points** (:func:`reflection_points`, NumPy): the images ``y_j`` of ``y`` after
   the first ``j`` reflections; then backwards from the receiver, the point ``p_n`` where the
   segment ``y_n -> x`` crosses plane ``P_n``, ``p_{n-1}`` where ``y_{n-1} -> p_n`` crosses
   ``P_{n-1}``, and so on. A segment that does not cross its plane (both ends on one side)
   means no specular path: the image is not *valid*.
2. **Ray casts** (Mitsuba ``Scene.ray_intersect_preliminary`` on the room's meshes, one batched
   call): along every leg ``y -> p_1 -> ... -> p_n -> x`` the first hit must not come before
   the leg's end (else the leg is *blocked*: something stands across it), and a short probe ray
   towards each reflection point must hit a surface there (else the plane has no face at that
   point: a wall ends, a door is open, a furniture face is smaller than its plane). A surface
   within ``flush`` of the plane (measured along its normal) counts as the plane's face: a bed
   standing 1 cm from a wall reflects as the wall does, and the image maps leave out faces
   flush with a room plane for that reason (:func:`rfmitsuba.rf.images.scene_image_maps`).

The result per (view, image) is ``exists`` (valid, and every reflection point lies on a real
face) and ``clear`` (exists, and no leg is blocked). A path that exists but is blocked may still
carry power through what blocks it: Sionna RT refracts through every surface it crosses as
through a thin slab of the surface's radio material, without bending the ray. So a blocked path
also reports its **crossings**: how many surfaces of each material group its legs cross before
their ends (casts continue past each hit, at most ``max_crossings`` per leg). A tracer counts
each crossing as an interaction, so a path with more reflections plus crossings than its depth
does not exist in its data; the coherent Gaussian field can also attenuate a blocked path by one
learned transmission per crossing of each material. A tracer also drops a path with a segment
shorter than its threshold between two vertices (Sionna RT: 1 cm), such as a direct path that
cuts a few millimetres through the corner of a wardrobe: the trace reports each path's
``shortest_segment``.

Positions are metres; the receiver is the array centre (Sionna's synthetic array traces from
there too). All rays in one call; the scene is built once from the room's meshes
(:func:`rfmitsuba.data.scene_xml.read_shapes`), without materials.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..core import backend as B
from ..core.errors import ConfigError


def reflection_points(x: np.ndarray, y: np.ndarray, planes: np.ndarray, order: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The reflection points of every image's specular path (the image method, backwards).

    Args:
        x: float [B, 3] receivers [m]; y: float [B, 3] transmitters [m].
        planes: float [S, O, 4] each image's planes (unit normal, offset [m]) in the order the
            path meets them from the transmitter; rows past ``order`` are ignored (may be NaN).
        order: int [S] reflections per image (0: the direct path).
    Returns:
        (points float64 [B, S, O, 3] m, NaN past each image's order; valid bool [B, S]: every
        segment crossed its plane, so the specular path is geometrically possible).
    """
    x = np.asarray(x, np.float64).reshape(-1, 3)
    y = np.asarray(y, np.float64).reshape(-1, 3)
    planes = np.asarray(planes, np.float64)
    order = np.asarray(order, np.int64).reshape(-1)
    if x.shape != y.shape or planes.ndim != 3 or planes.shape[2] != 4 or planes.shape[0] != len(order):
        raise ConfigError(f"reflection_points: x {x.shape} and y {y.shape} must be [B, 3], planes [S, O, 4] and "
                          f"order [S]; got planes {planes.shape}, order {order.shape}")
    if len(order) and (order.min() < 0 or order.max() > planes.shape[1]):
        raise ConfigError(f"reflection_points: orders must lie in 0..{planes.shape[1]}, got {order.min()}..{order.max()}")
    nb, S, O = len(x), planes.shape[0], planes.shape[1]
    pl = np.nan_to_num(planes)
    img = np.empty((nb, S, O + 1, 3))
    img[:, :, 0] = y[:, None, :]
    for j in range(O):                                   # y_j: the image after the first j reflections
        n, d = pl[:, j, :3], pl[:, j, 3]
        prev = img[:, :, j]
        sd = np.einsum("bsk,sk->bs", prev, n) - d
        img[:, :, j + 1] = np.where((j < order)[None, :, None], prev - 2.0 * sd[..., None] * n, prev)
    pts = np.full((nb, S, O, 3), np.nan)
    valid = np.ones((nb, S), bool)
    t = np.repeat(x[:, None, :], S, 1)
    for j in reversed(range(O)):
        act = (j < order)[None, :]
        n, d = pl[:, j, :3], pl[:, j, 3]
        yj = img[:, :, j + 1]
        sa = np.einsum("bsk,sk->bs", yj, n) - d
        sb = np.einsum("bsk,sk->bs", t, n) - d
        cross = sa * sb < 0.0
        lam = np.where(cross, sa / np.where(cross, sa - sb, 1.0), 0.0)
        p = yj + lam[..., None] * (t - yj)
        pts[:, :, j] = np.where(act[..., None], p, np.nan)
        valid &= np.where(act, cross, True)
        t = np.where(act[..., None], p, t)
    return pts, valid


class PathTrace(NamedTuple):
    """What :meth:`SpecularVisibility.trace` finds for B views and S images (arrays [B, S]).

    exists: bool, the specular path is valid and every reflection point lies on a face;
    clear: bool, it exists and nothing stands across it;
    cos_incidence: float64, the mean over its reflections of ``|cos|`` of the angle between the
    incoming leg and the plane's normal (1 at normal incidence; 1 for the direct path);
    crossings: float32 [B, S, G], the surfaces of each of the G material groups
    (:attr:`SpecularVisibility.group_names`) that the path's legs cross (0 where it is clear
    or does not exist);
    shortest_segment: float64, the shortest distance between consecutive vertices of the path
    [m]: its ends, its reflection points and every surface it crosses (so a path that cuts the
    corner of a box 6 mm deep has a 6 mm segment); inf where it does not exist.
    """

    exists: np.ndarray
    clear: np.ndarray
    cos_incidence: np.ndarray
    crossings: np.ndarray
    shortest_segment: np.ndarray

    def within_depth(self, order: np.ndarray, max_depth: int | None) -> "PathTrace":
        """The trace with every path whose reflections (``order``, int [S]) plus crossings exceed
        ``max_depth`` marked absent, as a tracer limited to that many interactions would have it
        (None: unchanged)."""
        if max_depth is None:
            return self
        deep = np.asarray(order)[None, :] + self.crossings.sum(-1) > max_depth
        return self._absent(deep)

    def without_short_segments(self, min_segment: float | None) -> "PathTrace":
        """The trace with every path that has a segment not longer than ``min_segment`` [m]
        marked absent (None: unchanged). A ray tracer drops such paths: Sionna RT's image method
        keeps an interaction only if the segment to it is longer than its ``MIN_SEGMENT_LENGTH``
        (1 cm), so a direct path that cuts 6 mm through a wardrobe's corner is not in its data,
        while one that crosses 13 mm of it is."""
        if min_segment is None:
            return self
        return self._absent(self.shortest_segment <= float(min_segment))

    def _absent(self, gone: np.ndarray) -> "PathTrace":
        """The trace with the paths where ``gone`` (bool [B, S]) is True marked absent."""
        return self._replace(exists=self.exists & ~gone, clear=self.clear & ~gone,
                             crossings=np.where(gone[..., None], 0.0, self.crossings),
                             shortest_segment=np.where(gone, np.inf, self.shortest_segment))


class SpecularVisibility:
    """Ray-cast existence and blockage of image-source paths in one room (module docstring).

    Args:
        meshes: the room's triangle meshes in world coordinates [m] (``trimesh.Trimesh``, or
            anything with ``vertices`` [V, 3] and ``faces`` [F, 3]).
        tol: distance tolerance of the hit tests [m]: a leg counts as blocked when its first
            hit comes more than ``tol`` before its end (and, for a leg that ends on a plane, more
            than ``flush`` from that plane).
        flush: a surface this close to a reflection plane, along its normal, is that plane's face [m].
        probe: length of the probe ray that ends at each reflection point [m]; the probe must hit
            a surface before it passes the plane by ``tol``.
        rounds: how many surfaces within ``flush`` of the plane a leg starts on are looked past
            (a panel on a wall has a front and a back).
        groups: the material group of each mesh (names, one per mesh; default: one group per
            mesh). :meth:`from_xml` groups by radio material.
        max_crossings: most surfaces counted along one blocked leg.
    """

    def __init__(self, meshes, *, tol: float = 0.02, flush: float = 0.05, probe: float = 0.05, rounds: int = 3,
                 groups=None, max_crossings: int = 8):
        if not meshes:
            raise ConfigError("SpecularVisibility needs at least one mesh")
        if not (tol > 0 and flush > 0 and probe > tol):
            raise ConfigError(f"SpecularVisibility: tol > 0, flush > 0 and probe > tol required, got tol {tol}, "
                              f"flush {flush}, probe {probe}")
        if groups is None:
            groups = [f"mesh{i}" for i in range(len(meshes))]
        groups = [str(g) for g in groups]
        if len(groups) != len(meshes) or max_crossings < 1:
            raise ConfigError(f"SpecularVisibility: one group per mesh ({len(meshes)}) and max_crossings >= 1 "
                              f"required, got {len(groups)} groups and max_crossings {max_crossings}")
        B.ensure()
        import drjit as dr
        import mitsuba as mi

        self.tol, self.flush, self.probe, self.rounds = float(tol), float(flush), float(probe), int(rounds)
        self.max_crossings = int(max_crossings)
        #: the material groups, in order of first appearance; crossings are counted per group
        self.group_names: list[str] = list(dict.fromkeys(groups))
        desc = {"type": "scene"}
        for i, m in enumerate(meshes):
            v = np.asarray(m.vertices, np.float32).reshape(-1, 3)
            f = np.asarray(m.faces, np.uint32).reshape(-1, 3)
            if not len(f) or not np.isfinite(v).all():
                raise ConfigError(f"SpecularVisibility: mesh {i} has no faces or non-finite vertices")
            mesh = mi.Mesh(f"shape{i}", vertex_count=len(v), face_count=len(f), has_vertex_normals=False,
                           has_vertex_texcoords=False)
            p = mi.traverse(mesh)
            p["vertex_positions"] = mi.Float(v.ravel())
            p["faces"] = mi.UInt32(f.ravel())
            p.update()
            desc[f"shape{i}"] = mesh
        self.scene = mi.load_dict(desc)
        # a hit names its shape by Mitsuba's registry id; each shape's own id ("shape<i>") names its mesh
        ids = np.asarray(dr.reinterpret_array(mi.UInt32, self.scene.shapes_dr()).numpy(), np.int64)
        self._group_of_id = np.full(int(ids.max()) + 1, -1, np.int64)
        for sid, shape in zip(ids, self.scene.shapes()):
            self._group_of_id[sid] = self.group_names.index(groups[int(shape.id()[len("shape"):])])

    @classmethod
    def from_xml(cls, xml_path: str | Path, **kw) -> "SpecularVisibility":
        """The room of a Mitsuba scene XML (every shape, grouped by radio material; SceneError
        names a bad file)."""
        from ..data.scene_xml import read_shapes

        shapes = read_shapes(xml_path)
        return cls([s.mesh for s in shapes], groups=[s.material for s in shapes], **kw)

    def first_hits(self, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Distance to the first surface along each ray: float [R, 3] origins [m] and unit
        directions -> float64 [R] metres (inf where the ray leaves the scene)."""
        return self.hits(origin, direction)[0]

    def hits(self, origin: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The first surface along each ray: (distance float64 [R] m, inf where the ray leaves the
        scene; material group int64 [R], -1 there)."""
        import drjit as dr
        import mitsuba as mi

        if len(origin) == 0:
            return np.zeros(0), np.zeros(0, np.int64)
        o = np.ascontiguousarray(np.asarray(origin, np.float32).T)
        d = np.ascontiguousarray(np.asarray(direction, np.float32).T)
        pi = self.scene.ray_intersect_preliminary(mi.Ray3f(mi.Point3f(o), mi.Vector3f(d)))
        t = np.asarray(pi.t.numpy(), np.float64)
        sid = np.asarray(dr.reinterpret_array(mi.UInt32, pi.shape).numpy(), np.int64)
        hit = np.isfinite(t)
        group = np.where(hit, self._group_of_id[np.clip(sid, 0, len(self._group_of_id) - 1)], -1)
        return np.where(hit, t, np.inf), group

    def __call__(self, x: np.ndarray, y: np.ndarray, planes: np.ndarray, order: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(exists, clear), both bool [B, S], for receivers ``x`` and transmitters ``y`` (float
        [B, 3] m) and the images' ``planes`` [S, O, 4] / ``order`` [S] (:func:`reflection_points`)."""
        tr = self.trace(x, y, planes, order)
        return tr.exists, tr.clear

    def trace(self, x: np.ndarray, y: np.ndarray, planes: np.ndarray, order: np.ndarray) -> PathTrace:
        """:class:`PathTrace` of every image for every view (arguments as :meth:`__call__`)."""
        x = np.asarray(x, np.float64).reshape(-1, 3)
        y = np.asarray(y, np.float64).reshape(-1, 3)
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise ConfigError("SpecularVisibility: positions must be finite")
        order = np.asarray(order, np.int64).reshape(-1)
        refl, valid = reflection_points(x, y, planes, order)
        nb, S, O = refl.shape[:3]
        pts = np.empty((nb, S, O + 2, 3))
        pts[:, :, 0] = y[:, None, :]
        pts[:, :, 1:O + 1] = refl
        pts[:, np.arange(S), order + 1] = x[:, None, :]
        leg = np.arange(O + 1)
        active = (leg[None, :] <= order[:, None])[None] & valid[..., None]          # [B, S, O+1]
        ends_on_face = (leg[None, :] < order[:, None])[None] & active
        # inactive legs (past an image's order, or of a path that is not valid) may hold NaN or inf
        # points: only active legs are measured
        pts = np.where(np.isfinite(pts), pts, 0.0)
        a, b = pts[:, :, :-1], pts[:, :, 1:]
        seg = np.where(active[..., None], b - a, 1.0)
        L = np.linalg.norm(seg, axis=-1)
        u = seg / np.maximum(L, 1e-12)[..., None]
        eps = 1e-3
        # legs: from just past the start towards the end; probes: the last ``probe`` metres before a face
        hp = np.minimum(self.probe, 0.5 * L)
        t, g = self.hits(np.concatenate([(a + eps * u)[active], (b - hp[..., None] * u)[ends_on_face]]),
                         np.concatenate([u[active], u[ends_on_face]]))
        n_leg = int(active.sum())
        t_leg = np.full(active.shape, np.inf)
        t_leg[active] = eps + t[:n_leg]
        g_leg = np.full(active.shape, -1, np.int64)
        g_leg[active] = g[:n_leg]
        t_probe = np.full(active.shape, np.nan)
        t_probe[ends_on_face] = t[n_leg:]
        # A hit within ``flush`` of the plane a leg starts on is that plane's own face (a panel
        # on the wall it left): look past it, up to ``rounds`` times. A hit within ``flush`` of
        # the plane it ends on is the face it reflects off.
        pl = np.nan_to_num(np.asarray(planes, np.float64))
        zero = np.zeros((S, 1, 4))
        end_pl = np.concatenate([pl, zero], 1)[:, :O + 1]
        start_pl = np.concatenate([zero, pl], 1)[:, :O + 1]
        starts_on_face = (leg >= 1)[None, None, :] & active

        def off(side):
            hit = a + np.where(np.isfinite(t_leg), t_leg, 0.0)[..., None] * u
            return np.abs(np.einsum("bsok,sok->bso", hit, side[..., :3]) - side[None, ..., 3])

        for _ in range(self.rounds):
            again = starts_on_face & np.isfinite(t_leg) & (t_leg < L - self.tol) & (off(start_pl) <= self.flush) \
                & ~(ends_on_face & (off(end_pl) <= self.flush))
            if not again.any():
                break
            t2, g2 = self.hits((a + (t_leg + eps)[..., None] * u)[again], u[again])
            t_leg[again] = t_leg[again] + eps + t2
            g_leg[again] = g2
        near_end = ends_on_face & (off(end_pl) <= self.flush)
        blocked = active & (t_leg < L - self.tol) & ~near_end
        on_face = ~ends_on_face | (t_probe <= hp + self.tol)
        exists = valid & on_face.all(-1)
        clear = exists & ~blocked.any(-1)
        crossings, gap = self._crossings(a, u, L, t_leg, g_leg, blocked & (exists & ~clear)[..., None],
                                         np.where(ends_on_face, self.flush, 0.0))
        # a clear leg is one segment; a blocked one is cut into several by what it crosses
        shortest = np.where(active, L, np.inf).min(-1)
        shortest = np.where(exists, np.minimum(shortest, gap), np.inf)
        cos_in = np.abs(np.einsum("bsok,sok->bso", u, end_pl[..., :3]))       # incoming leg . the plane it ends on
        cos_in = np.where(ends_on_face, cos_in, 0.0).sum(-1) / np.maximum(order, 1)[None, :]
        cos_in = np.where(order[None, :] == 0, 1.0, cos_in)
        return PathTrace(exists, clear, cos_in, crossings, shortest)

    def _crossings(self, a, u, L, t_leg, g_leg, blocked, margin) -> tuple[np.ndarray, np.ndarray]:
        """Surfaces of each group crossed by the blocked legs: float32 [B, S, G], and the shortest
        segment between consecutive vertices of those legs (the leg's ends and the surfaces it
        crosses): float64 [B, S] m, inf where no leg is blocked. From each leg's first blocking
        hit (distance ``t_leg``, group ``g_leg``), casts go on past every hit until one reaches
        the leg's end less ``tol`` and ``margin`` (the face the leg reflects off)."""
        nb, S = blocked.shape[:2]
        G = len(self.group_names)
        out = np.zeros((nb, S, G), np.float32)
        gap = np.full((nb, S), np.inf)
        bi, si, li = np.nonzero(blocked)
        t, g = t_leg[bi, si, li], g_leg[bi, si, li]
        end = L[bi, si, li] - self.tol - margin[bi, si, li]
        prev = np.zeros(len(t))                                  # the last vertex along each leg [m]
        shortest = np.full(len(t), np.inf)
        for _ in range(self.max_crossings):
            live = np.isfinite(t) & (t < end) & (g >= 0)
            if not live.any():
                break
            np.add.at(out, (bi[live], si[live], g[live]), 1.0)
            shortest[live] = np.minimum(shortest[live], t[live] - prev[live])
            prev[live] = t[live]
            origin = a[bi[live], si[live], li[live]] + (t[live] + 1e-3)[:, None] * u[bi[live], si[live], li[live]]
            t2, g2 = self.hits(origin, u[bi[live], si[live], li[live]])
            t_new = np.full(len(t), np.inf)
            g_new = np.full(len(t), -1, np.int64)
            t_new[live], g_new[live] = t[live] + 1e-3 + t2, g2
            t, g = t_new, g_new
        shortest = np.minimum(shortest, L[bi, si, li] - prev)   # from the last surface to the leg's end
        np.minimum.at(gap, (bi, si), shortest)
        return out, gap
