"""The coherent Gaussian field's architecture and initialisation options (:class:`CoherentGaussianConfig`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np

from ...core.errors import ConfigError


@dataclass
class CoherentGaussianConfig:
    """Architecture and initialisation of a :class:`~rfmitsuba.models.coherent_gaussians.field.CoherentGaussianField`.

    One line per option: meaning [unit] (default). "auto" is decided from the data at the start of
    training and recorded in the run summary; the measurements behind each default are in the lab
    notes (docs/lab-notes/defaults.md).

    init: "room" (the scene's image sources), "data" (the directional scan) or "auto": "room" where the
        dataset names a scene ("auto").
    room_order: reflections per image of a known room's box (2).
    furniture_order: reflections per image off furniture, doors and windows, 0 to 2 (1).
    min_face_area: smallest furniture face that becomes a plane [m^2] (0.05).
    images: planes the data scan keeps for an unknown room; "auto": 12 where the positions lie within
        the array's beam, else 0 ("auto").
    image_order: reflections per image composed from the scanned planes (2).
    scatterers: fixed scatterers the scan finds for an unknown room (96).
    room_scatterers: scanned scatterers beside a known room's images (24).
    scan_step: offset step of candidate planes and grid step of candidate scatterers [m] (0.1).
    scan_margin: how far beyond the known positions the candidates reach [m] (4.0).
    scan_radius_deg: beam masked around each source the scan keeps, unknown room [deg] (12).
    room_scan_radius_deg: the same for the scatterers beside a known room's images [deg] (4).
    readout: "amplitude", "phase_only" (Bartlett of h/|h|) or "auto": the dataset's read-out ("auto").
    wavefront: "plane", "spherical" or "auto": spherical for measured folders, else plane ("auto").
    calibrate: learn the per-element complex calibration ``cal`` (true).
    coupling: learn the mutual coupling ``I + K`` between neighbouring elements (reciprocal, 42 complex
        coefficients); "auto": for the phase-only read-out ("auto").
    learn_pose: learn the array's rotation and translation (true).
    visibility: learn the visibility windows; false: every source keeps its initial wide window (true).
    init_extent: initial visibility extent sigma [m] (5.0).
    init_reflection: initial gain of an image of order n, ``init_reflection ** n`` [1] (0.5).
    scatterer_gain: initial contribution of a scatterer relative to the direct path [1] (0.2).
    ray_visibility: known room: each image path's existence and blockage per view by Mitsuba ray casts (true).
    init_through: initial remainder ``img_through`` of a blocked path relative to its clear gain [1] (0.0).
    depth_limit: a path with more reflections plus crossings than the data's ray-tracer depth is absent (true).
    segment_limit: a path with a segment shorter than the data's ray-tracer threshold is absent (true).
    prune_unseen: leave out the images whose ray-cast path exists at no training position (true).
    incidence_slope: learn ``img_slope``, the gain's change with the angle of incidence (true).
    vis_grid: cells (x, y, z) of each source's visibility grid; "auto": (4, 4, 2), or (8, 8, 4) for an unknown
        room with 1000 positions or more; (0, 0, 0): none (None).
    frame_search: "report" fits the array frame to the line of sight and warns when the stated one is far
        off, "off", or "auto": "report" for a measured unknown room ("auto").
    calibration_search: "apply" starts ``cal`` from a global search of the elements' phase offsets, "off",
        or "auto": "apply" for phase-only spectra in an unknown room ("auto").
    calibration_min_gain: least gain in line-of-sight correlation that applies the searched offsets [1] (0.05).
    room_box: an unknown room's known box (x0, y0, z0, x1, y1, z1) [m]: its six walls join the scanned
        planes (None).
    pursuit: grow planes during training where the loss asks for them: "on", "off", or "auto": on where the
        positions spread wider than the array's beam ("auto").
    pursuit_planes: planes added at each fraction of ``pursuit_at`` (1).
    pursuit_at: fractions of the run at which the pursuit adds planes, each in (0, 1) (every 0.04 from 0.04
        to 0.6).
    pursuit_views: training views over which a pursuit sums the gradient (256).
    """

    #: options that were removed because they did not help (core.config: saved files still load)
    removed_options: ClassVar[dict] = {"amp_l1": 0.0, "material_through": False, "init_transmission": None,
                                       "frame_min_gain": None, "calibration_twin": None,
                                       "coupling_model": "neighbours", "furniture_planes": "faces"}
    #: values that were removed: a saved file's frame_search "apply" only steered the start
    removed_values: ClassVar[dict] = {"frame_search": {"apply": "report"}, "images": {None: "auto"},
                                      "vis_grid": {None: "auto"}}

    init: Literal["auto", "room", "data"] = "auto"
    room_order: int = 2
    furniture_order: int = 1
    min_face_area: float = 0.05
    images: int | Literal["auto"] = "auto"
    image_order: int = 2
    scatterers: int = 96
    room_scatterers: int = 24
    scan_step: float = 0.1
    scan_margin: float = 4.0
    scan_radius_deg: float = 12.0
    room_scan_radius_deg: float = 4.0
    readout: Literal["auto", "amplitude", "phase_only"] = "auto"
    wavefront: Literal["auto", "plane", "spherical"] = "auto"
    calibrate: bool = True
    coupling: bool | Literal["auto"] = "auto"
    learn_pose: bool = True
    visibility: bool = True
    init_extent: float = 5.0
    init_reflection: float = 0.5
    scatterer_gain: float = 0.2
    ray_visibility: bool = True
    init_through: float = 0.0
    depth_limit: bool = True
    segment_limit: bool = True
    prune_unseen: bool = True
    incidence_slope: bool = True
    vis_grid: tuple[int, int, int] | Literal["auto"] = "auto"
    frame_search: Literal["auto", "report", "off"] = "auto"
    calibration_search: Literal["auto", "apply", "off"] = "auto"
    calibration_min_gain: float = 0.05
    room_box: tuple[float, float, float, float, float, float] | None = None
    pursuit: Literal["auto", "on", "off"] = "auto"
    pursuit_planes: int = 1
    pursuit_at: tuple[float, ...] = (0.04, 0.08, 0.12, 0.16, 0.2, 0.24, 0.28, 0.32, 0.36, 0.4, 0.44, 0.48, 0.52,
                                     0.56, 0.6)
    pursuit_views: int = 256

    def __post_init__(self) -> None:
        if self.frame_search not in ("auto", "report", "off"):
            raise ConfigError(f"CoherentGaussianConfig.frame_search must be 'auto', 'report' or 'off', got "
                              f"{self.frame_search!r}")
        if self.init not in ("auto", "room", "data"):
            raise ConfigError(f"CoherentGaussianConfig.init must be 'auto', 'room' or 'data', got {self.init!r}")
        if self.coupling not in (True, False, "auto"):
            raise ConfigError(f"CoherentGaussianConfig.coupling must be true, false or 'auto', got {self.coupling!r}")
        if self.readout not in ("auto", "amplitude", "phase_only"):
            raise ConfigError(f"CoherentGaussianConfig.readout must be 'auto', 'amplitude' or 'phase_only', "
                              f"got {self.readout!r}")
        if self.wavefront not in ("auto", "plane", "spherical"):
            raise ConfigError(f"CoherentGaussianConfig.wavefront must be 'auto', 'plane' or 'spherical', "
                              f"got {self.wavefront!r}")
        if min(0 if self.images == "auto" else self.images, self.scatterers, self.room_scatterers, self.room_order) < 0 or self.image_order < 1 \
                or self.furniture_order not in (0, 1, 2):
            raise ConfigError("CoherentGaussianConfig: images, scatterers, room_scatterers, room_order >= 0 and furniture_order "
                              "0, 1 or 2 required")
        if not (self.scan_step > 0 and self.scan_margin >= 0 and self.init_extent > 0 and self.scan_radius_deg > 0
                and self.room_scan_radius_deg > 0):
            raise ConfigError("CoherentGaussianConfig: scan_step > 0, scan_margin >= 0, init_extent > 0 and scan radii "
                              "> 0 required")
        if self.vis_grid != "auto":
            g = tuple(self.vis_grid) if isinstance(self.vis_grid, (tuple, list)) else ()
            if len(g) != 3 or not all(isinstance(n, int) and n >= 0 for n in g) or (0 in g and any(g)):
                raise ConfigError(f"CoherentGaussianConfig.vis_grid must be 'auto' or 3 cells (x, y, z), all >= 1 "
                                  f"or all 0, got {self.vis_grid!r}")
        if self.room_box is not None:
            box = np.asarray(self.room_box, np.float64)
            if box.shape != (6,) or not np.isfinite(box).all() or not (box[:3] < box[3:]).all():
                raise ConfigError(f"CoherentGaussianConfig.room_box must be 6 finite numbers (x0, y0, z0, x1, y1, "
                                  f"z1) [m] with x0 < x1, y0 < y1, z0 < z1, got {self.room_box!r}")
        if self.calibration_search not in ("auto", "apply", "off"):
            raise ConfigError(f"CoherentGaussianConfig.calibration_search must be 'auto', 'apply' or 'off', got "
                              f"{self.calibration_search!r}")
        if not 0.0 <= float(self.calibration_min_gain) <= 2.0:
            raise ConfigError(f"CoherentGaussianConfig.calibration_min_gain must be in [0, 2] (a gain in correlation), "
                              f"got {self.calibration_min_gain!r}")
        if self.pursuit not in ("auto", "on", "off"):
            raise ConfigError(f"CoherentGaussianConfig.pursuit must be 'auto', 'on' or 'off', got {self.pursuit!r}")
        if self.pursuit_planes < 0 or self.pursuit_views < 1 or not all(0 < float(t) < 1 for t in self.pursuit_at):
            raise ConfigError(f"CoherentGaussianConfig: pursuit_planes >= 0, pursuit_views >= 1 and every pursuit_at "
                              f"in (0, 1) required, got {self.pursuit_planes!r}, {self.pursuit_views!r}, "
                              f"{self.pursuit_at!r}")
        if not (0 < self.init_reflection <= 1 and self.scatterer_gain > 0 and 0 <= self.init_through <= 1):
            raise ConfigError("CoherentGaussianConfig: init_reflection in (0, 1], scatterer_gain > 0 and init_through "
                              "in [0, 1] required")
