"""Where the person can be (:class:`SearchRegion`): the training walk's box grown by a margin, or a
known room's free space, less the walls' and furniture's clearance."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import ConfigError
from .model import TwoStage

#: horizontal clearance [m] of the feet from walls and from furniture footprints at body height
#: in the search region of a known room (the walk keeps 0.25 m; a little less, so that the
#: region holds every walk position)
CLEARANCE_M = 0.2
#: how far [m] the walk search region reaches past the training walk's box
WALK_MARGIN_M = 0.5
#: height [m] of the body column that must be clear of furniture (rfmitsuba.sim.person.HEIGHT)
BODY_HEIGHT_M = 1.7
#: search regions (:meth:`SearchRegion.of`)
REGIONS = ("walk", "room")


@dataclass
class SearchRegion:
    """Where the feet may be: the box ``lo``..``hi`` (float64 [2] each, x and y [m]) at height
    ``z`` [m], less what ``geometry`` (a :class:`~rfmitsuba.sim.geometry.RoomGeometry`, or None)
    says is not free. ``kind``: "room" or "walk"."""

    lo: np.ndarray
    hi: np.ndarray
    z: float
    geometry: object = None
    kind: str = "walk"

    @classmethod
    def of(cls, model: TwoStage, *, region: str = "walk") -> "SearchRegion":
        """The region of ``model``: "walk" (the training walk's box grown by :data:`WALK_MARGIN_M`,
        less the walls' and furniture's margins where the room is known) or "room" (the known
        room's free space)."""
        if region not in REGIONS:
            raise ConfigError(f"region must be one of {REGIONS}, got {region!r}")
        geometry = None
        if model.data.scene_xml is not None:
            from ...sim.geometry import RoomGeometry

            geometry = RoomGeometry.from_xml(model.data.scene_xml)
        if region == "room" and geometry is None:
            raise ConfigError(f"{model.data.path} names no room, so its free space is unknown: use region 'walk'")
        if region == "room":
            lo, hi = geometry.bounds
            lo, hi = lo[:2] + CLEARANCE_M, hi[:2] - CLEARANCE_M
        else:
            lo, hi = model.walk[:, :2].min(0) - WALK_MARGIN_M, model.walk[:, :2].max(0) + WALK_MARGIN_M
            if geometry is not None:
                rlo, rhi = geometry.bounds
                lo, hi = np.maximum(lo, rlo[:2] + CLEARANCE_M), np.minimum(hi, rhi[:2] - CLEARANCE_M)
        return cls(lo=np.asarray(lo, np.float64), hi=np.asarray(hi, np.float64), z=model.feet_z, geometry=geometry,
                   kind=region)

    def feet(self, xy: np.ndarray) -> np.ndarray:
        """float [N, 2] -> feet positions float64 [N, 3] at the region's height."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return np.concatenate([xy, np.full((len(xy), 1), self.z)], axis=1)

    def free(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point float [N, 2] is in the region: bool [N]."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        ok = np.isfinite(xy).all(1) & (xy >= self.lo - 1e-9).all(1) & (xy <= self.hi + 1e-9).all(1)
        if self.geometry is not None and ok.any():
            ok[ok] = self.geometry.free_mask(self.feet(xy[ok]), clearance=CLEARANCE_M, body_height=BODY_HEIGHT_M)
        return ok

    def grid(self, step: float) -> np.ndarray:
        """The free points of a grid of ``step`` [m] spacing centred in the box: float64 [M, 2]."""
        if not step > 0:
            raise ConfigError(f"grid spacing must be > 0 m, got {step}")
        axes = []
        for a in range(2):
            n = max(1, int(np.floor((self.hi[a] - self.lo[a]) / step)) + 1)
            off = 0.5 * ((self.hi[a] - self.lo[a]) - (n - 1) * step)
            axes.append(self.lo[a] + off + step * np.arange(n))
        xy = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 2)
        xy = xy[self.free(xy)]
        if len(xy) == 0:
            raise ConfigError(f"the search region ({self.kind}) holds no free grid point at {step} m spacing")
        return xy
