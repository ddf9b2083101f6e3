"""The coherent Gaussian field's architecture and initialisation options (:class:`CoherentGaussianConfig`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ...core.errors import ConfigError


@dataclass
class CoherentGaussianConfig:
    """Architecture and initialisation of a :class:`CoherentGaussianField`.

    init: "auto" (the room's image sources when the dataset names a scene, else the data scan),
    "room" or "data".
    room_order / furniture_order / min_face_area: image maps of a known room (as
    :class:`~rfmitsuba.models.coherent.CoherentConfig`).
    images: reflecting planes found by the data scan (unknown room; the direct path comes extra).
        None (the default): :data:`SCAN_PLANES` (12) where the moving device's positions lie
        within the array's beam as seen from the fixed device (NeRF2-like tags), none where they
        spread wider (:func:`~rfmitsuba.models.coherent_gaussians.geometry.spreads_wide`: a walked room, where the plane pursuit finds them).
        Within the beam, 12 since 2026-11-25 (6 before), seed 0, 3000 steps: NeRF2-like 200 tags
        0.945 -> 0.958 (IDW-3 0.951), 2000 tags 0.909 (IDW-3 0.919; 24 planes 0.904; 6 planes
        0.888 at 6000 steps); the extra planes are mostly not walls, but their images (and their
        double reflections) are sources where the data put energy. The NeRF2-like spatial-block
        split (extrapolation to a held-out slab) lost on one seed in two (anchored 0.875 and
        0.917 against 0.911 with 6 planes; NN 0.911). In a walked room the scan's planes add
        sources, not accuracy: blind bedroom TX, seed 0, with the pursuit: 12 scanned planes
        0.875 with 587 sources, none 0.877 with 250 (NN 0.723).
    image_order: reflections per image of an unknown room: the scanned planes' images are
    composed up to this order (2: the images across two of the found planes, as a room's
    double reflections), identical maps once.
    scatterers / room_scatterers: fixed scatterers found by the data scan for an unknown room / beside
    a known room's image sources (0 = none). NeRF2-like, known room, random split: 24 scatterers
    0.951 +- 0.002 over 3 seeds (the IDW-3 floor 0.951), 96 scatterers 0.916 (one seed): a known
    room's images already explain most of the spectrum.
    scan_step: offset step of candidate planes and grid step of candidate scatterers [m].
    scan_margin: how far beyond the known positions candidates reach [m].
    scan_radius_deg / room_scan_radius_deg: beam masked around each source the scan keeps
    [degrees], for an unknown room / for the scatterers added to a known room's images (smaller:
    more sources start in the strongest directions; NeRF2-like, known room, test SSIM over 3
    seeds: 12 degrees 0.930 +- 0.031, 4 degrees 0.951 +- 0.002; IDW-3 floor 0.951).
    readout: "auto" (phase-only for a NeRF2 folder that does not say otherwise, amplitude for
    simulated data), "amplitude" or "phase_only".
    wavefront: "auto" (plane for simulated data, whose truth uses the plane-wave rule; spherical
    for measured folders), "plane" or "spherical".
    calibrate: learn the per-element complex calibration; learn_pose: learn the array's pose;
    coupling: also learn the elements' mutual coupling (``I + K`` before the calibration, ``K``
    complex 16 x 16, zero at the start). "auto" (the default): for a NeRF2
    gateway's spectra (phase-only read-out, measured or NeRF2-like), not for the amplitude
    read-out of simulated rooms, whose synthetic arrays have none.
    coupling_model: which entries of ``K`` are learned (:func:`coupling_index`): "neighbours"
    (the default: reciprocal, ``K = K^T``, between row, column and diagonal neighbours only; 42
    complex coefficients, 84 parameters) or "full" (all 256 entries, 512 parameters; states saved
    before this option load as "full"). On the NeRF2-like spatial-block split the full ``K``
    fit the training tags as well and extrapolated far worse where the room was known
    (docs/lab-notes/measurements.md).
    visibility: learn the visibility windows (False: every source keeps its initial, wide window,
    which extrapolates better beyond the training positions).
    init_extent: initial visibility extent sigma [m] (large: every source seen everywhere).
    amp_l1: weight of a sparsity penalty added to the training loss: ``amp_l1`` times the mean
        magnitude of the sources' complex gains (images and scatterers) [1 / gain]; 0: none.
    init_reflection: initial gain of an image of order n is ``init_reflection ** n``.
    scatterer_gain: initial contribution of a scatterer relative to the direct path.
    ray_visibility: known room only: decide each image path's existence and blockage per view by
        ray casts in the room's meshes (the module docstring); False: every image is seen
        everywhere, up to its learned window.
    furniture_planes: known room: furniture planes from the meshes' faces ("faces") or from each
        piece's bounding box ("box"), :func:`rfmitsuba.rf.images.scene_image_maps`.
    init_through: initial per-image remainder ``img_through`` of a blocked path, relative to its clear gain.
    material_through: learn one transmission per crossing of each radio material (``mat_through``):
        a blocked path keeps its clear gain times the transmissions of the surfaces it crosses,
        besides its own remainder ``img_through``. Off by default: in the bedroom (room order 3,
        furniture order 2, depth limit, seed 0) it changed test SSIM by -0.000 (RX, 0.949) and
        -0.001 (TX, 0.939); without the depth limit it cost TX 0.021 (0.918 against 0.939).
    init_transmission: initial magnitude of one crossing's transmission (``mat_through``), in (0, 1].
    depth_limit: a path whose reflections plus crossings exceed the simulating ray tracer's
        depth (:attr:`rfmitsuba.data.views.TrainData.max_depth`) is absent; no effect where the
        data name no tracer (measured data). Bedroom, room order 3, furniture order 2, seed 0:
        RX 0.947 -> 0.949 with 332 -> 275 Gaussians, TX 0.939 -> 0.940 with 322 -> 268.
    segment_limit: a path with two vertices (ends, reflection points, crossed surfaces) no
        farther apart than the simulating ray tracer's shortest segment
        (:attr:`rfmitsuba.data.views.TrainData.min_segment`, Sionna RT: 1 cm) is absent, as the
        tracer drops it; no effect where the data name no tracer. In the bedroom's moving-TX
        data the direct path cuts 6-7 mm through the wardrobe's corner at 2 of 900 positions
        (both in the test split, the model's two worst there) and Sionna has no direct path
        there; 13 mm and more, it has one (139 positions). Room order 3, furniture order 2, grid,
        3000 steps, 3 seeds: TX 0.946 -> 0.953, RX 0.952 -> 0.958.
    prune_unseen: leave out the images whose ray-cast path exists at no training position.
    incidence_slope: learn ``img_slope`` (False: it stays 0).
    frame_search: check the stated array frame against the line of sight before the data scan
        (:func:`rfmitsuba.rf.frame_fit.los_frame_fit`, about 20 s on 2 cores): "report" fits and
        records the result in the run summary (``init.frame_fit``) and warns when the stated
        frame draws the line of sight much worse than the fitted one (a gateway orientation that
        is likely wrong); "apply" also starts from the corrected frame (scan and pose) when it
        gains at least ``frame_min_gain``; "off" does neither; "auto": "report" for a measured
        folder in an unknown room, else "off". Not applied by default, because it did not help:
        NeRF2-like, unknown room, random split, 3000 steps, seeds 0-2, the stated frame 25
        degrees off: 0.943 +- 0.003 applied against 0.943 +- 0.005 not; 45 degrees off: 0.941 +-
        0.010 against 0.947 +- 0.004 (IDW-3 0.951). The fit lands 6 degrees from the truth on that
        data (other paths pull the apparent line of sight), and the field alone copes with a
        stated frame 25-45 degrees off as well as a right one (0.948 +- 0.009).
    frame_min_gain: smallest gain in line-of-sight correlation that applies a correction [1].
    calibration_search: start the per-element calibration ``cal`` from a global search of the
        elements' phase offsets (:func:`rfmitsuba.rf.calibration_fit.los_calibration_fit`, about 7
        s on 2 cores) where it draws the line of sight better than no offset by at least
        ``calibration_min_gain``: "apply", "off", or "auto": "apply" for phase-only spectra (a
        NeRF2 folder) in an unknown room (with ``calibrate``), else "off". Gradient descent from no offset finds
        offsets of tens of degrees but not offsets anywhere in +-180 degrees, as real arrays
        have. The fit and whether it was applied are in the run summary (``init.calibration_fit``).
        NeRF2-like tags (200, random split, 6000 steps, seeds 0-2), test SSIM without / with:
        +-90 degrees 0.959, 0.971, 0.954 / 0.969, 0.973, 0.971 (IDW-3 0.966); +-180 degrees 0.903,
        0.875, 0.815 / 0.875, 0.967, 0.966 (IDW-3 0.961; seed 0 run three times more with the
        same offsets: 0.964, 0.967, 0.966: its first run stuck at validation 0.942, a run-to-run
        local minimum of the training, not the offsets' twin); +-180 degrees at 10 dB 0.744,
        0.786, 0.800 / 0.807, 0.811, 0.789 (IDW-3 0.774); +-30 degrees (``nerf2like``'s default)
        not applied.
    calibration_twin: which of the fitted offsets and their line-of-sight twin
        (:mod:`rfmitsuba.rf.calibration_fit`) the calibration starts from: "nearer" (the one
        nearer no offset) or "other". It does not matter for tags in a patch far from the
        gateway: NeRF2-like tags, +-180 degrees, seed 0, 6000 steps: 0.964 from the one, 0.966
        from the other (IDW-3 0.961); each kept its twin to the end.
    calibration_min_gain: smallest gain in line-of-sight correlation that applies the fitted
        offsets [1]. NeRF2-like tags, +-30 degrees: 0.951 -> 0.966 (not applied); +-90: 0.781 ->
        0.936; +-180: 0.028 -> 0.831.
    room_box: an unknown room whose dimensions are known (a tape measure, a floor plan, no
        XML): its box ``(x0, y0, z0, x1, y1, z1)`` [m] in the data's frame. Its six walls join
        the planes the data scan finds, before their images are composed (``image_order``).
        The scan alone misses walls next to the fixed device, whose images arrive within the
        array's beam of the direct path. Bedroom, moving RX, seed 0, 3000 steps at batch 8:
        0.776 without, 0.878 with the true box, 0.867 with every wall 6-8 cm off, 0.837 with the
        four walls alone (NN 0.710, IDW-3 0.760). Every training position must lie inside it.
    vis_grid: cells (x, y, z) of each source's visibility grid over the training positions' box
        (the module docstring); None: (4, 4, 2), or (8, 8, 4) for an unknown room with 1000
        training positions or more (:func:`default_vis_grid`); (0, 0, 0): none. Known room (bedroom, room order
        3, furniture order 2, 3 seeds): RX 0.949 -> 0.952, TX 0.941 -> 0.946. Unknown room (3
        seeds): bedroom RX 0.767 -> 0.777, TX 0.746 -> 0.756; NeRF2-like random split 0.936 ->
        0.948, block split 0.823 -> 0.830 (its anchored prediction 0.905 -> 0.891).
    pursuit: unknown room: add planes during training where the loss asks for them ("on"),
        not ("off"), or "auto": on where the moving device's training positions spread wider,
        seen from the fixed device, than half the array's beam (:func:`~rfmitsuba.models.coherent_gaussians.geometry.spreads_wide`: a device
        walked round a room, either task; 21-23 degrees in our rooms), off where they lie within
        it (NeRF2-like tags in a patch 5 m from the gateway: 4 degrees). A fixed device's images
        across the walls next to it arrive within the array's beam of the direct path, which the
        directional scan cannot resolve; the pursuit scores them by the loss instead. Blind rooms,
        3000 steps at batch 8, 3 seeds, test SSIM with the pursuit from no scanned plane (the
        default since 2026-11-25): bedroom RX 0.886 +- 0.010, TX 0.874 +- 0.008; living room RX
        0.918 +- 0.005, TX 0.899 +- 0.015 (NN 0.710, 0.723, 0.728, 0.721). Before, with the scan's
        12 planes and five rounds on moving RX only: 0.864, 0.772, 0.882, 0.826 / 0.801. Within
        the beam five rounds cost the NeRF2-like tags 0.008 (random split, 3 of 3 seeds), so
        "auto" leaves it off there.
    pursuit_planes: planes added at each fraction ``pursuit_at`` of the run where the pursuit is
        on (:class:`rfmitsuba.train.pursuit.PlanePursuit`: coherent matching pursuit on the
        gradient of the loss at each candidate image's gain); 0: none. One at a time, refitted
        in between, is matching pursuit proper; more planes at once pick non-walls (blind bedroom
        RX, seed 0, with the scan's 12 planes: one at each of five steps 0.860; 2 at 20% and 50%
        0.850; 4 at 25% 0.846; 6 at 25% 0.839). From no scanned plane, blind bedroom TX, seed 0,
        15 rounds: one plane each 0.877 with 250 sources, two 0.888 with 709 (NN 0.723): the
        knee of the parsimony curve is at one.
    pursuit_at: fractions of the run's iterations at which planes are added, each in (0, 1);
        by default every 4% from 4% to 60% (15 planes). Blind bedroom TX, seed 0, 3000 steps at
        batch 8, no scanned plane: five rounds at 10-50% 0.784 (114 sources), fifteen 0.877 (250
        sources), 25 at 3-75% 0.885 (516 sources; NN 0.723). A walked room's field starts from the direct path and its scatterers
        alone, so the pursuit must supply every wall.
    pursuit_views: training views (evenly spaced) over which a pursuit sums the gradient.
    """

    init: Literal["auto", "room", "data"] = "auto"
    room_order: int = 2
    furniture_order: int = 1
    min_face_area: float = 0.05
    images: int | None = None
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
    coupling_model: Literal["neighbours", "full"] = "neighbours"
    learn_pose: bool = True
    visibility: bool = True
    init_extent: float = 5.0
    amp_l1: float = 0.0
    init_reflection: float = 0.5
    scatterer_gain: float = 0.2
    ray_visibility: bool = True
    furniture_planes: Literal["faces", "box"] = "faces"
    init_through: float = 0.0
    material_through: bool = False
    init_transmission: float = 0.5
    depth_limit: bool = True
    segment_limit: bool = True
    prune_unseen: bool = True
    incidence_slope: bool = True
    vis_grid: tuple[int, int, int] | None = None
    frame_search: Literal["auto", "report", "apply", "off"] = "auto"
    frame_min_gain: float = 0.01
    calibration_search: Literal["auto", "apply", "off"] = "auto"
    calibration_twin: Literal["nearer", "other"] = "nearer"
    calibration_min_gain: float = 0.05
    room_box: tuple[float, float, float, float, float, float] | None = None
    pursuit: Literal["auto", "on", "off"] = "auto"
    pursuit_planes: int = 1
    pursuit_at: tuple[float, ...] = (0.04, 0.08, 0.12, 0.16, 0.2, 0.24, 0.28, 0.32, 0.36, 0.4, 0.44, 0.48, 0.52,
                                     0.56, 0.6)
    pursuit_views: int = 256

    def __post_init__(self) -> None:
        if self.frame_search not in ("auto", "report", "apply", "off"):
            raise ConfigError(f"CoherentGaussianConfig.frame_search must be 'auto', 'report', 'apply' or 'off', got "
                              f"{self.frame_search!r}")
        if not self.amp_l1 >= 0:
            raise ConfigError(f"CoherentGaussianConfig.amp_l1 must be >= 0, got {self.amp_l1!r}")
        if not self.frame_min_gain >= 0:
            raise ConfigError(f"CoherentGaussianConfig.frame_min_gain must be >= 0, got {self.frame_min_gain!r}")
        if self.init not in ("auto", "room", "data"):
            raise ConfigError(f"CoherentGaussianConfig.init must be 'auto', 'room' or 'data', got {self.init!r}")
        if self.coupling not in (True, False, "auto"):
            raise ConfigError(f"CoherentGaussianConfig.coupling must be true, false or 'auto', got {self.coupling!r}")
        if self.coupling_model not in ("neighbours", "full"):
            raise ConfigError(f"CoherentGaussianConfig.coupling_model must be 'neighbours' or 'full', got "
                              f"{self.coupling_model!r}")
        if self.readout not in ("auto", "amplitude", "phase_only"):
            raise ConfigError(f"CoherentGaussianConfig.readout must be 'auto', 'amplitude' or 'phase_only', "
                              f"got {self.readout!r}")
        if self.wavefront not in ("auto", "plane", "spherical"):
            raise ConfigError(f"CoherentGaussianConfig.wavefront must be 'auto', 'plane' or 'spherical', "
                              f"got {self.wavefront!r}")
        if min(self.images or 0, self.scatterers, self.room_scatterers, self.room_order) < 0 or self.image_order < 1 \
                or self.furniture_order not in (0, 1, 2):
            raise ConfigError("CoherentGaussianConfig: images, scatterers, room_scatterers, room_order >= 0 and furniture_order "
                              "0, 1 or 2 required")
        if not (self.scan_step > 0 and self.scan_margin >= 0 and self.init_extent > 0 and self.scan_radius_deg > 0
                and self.room_scan_radius_deg > 0):
            raise ConfigError("CoherentGaussianConfig: scan_step > 0, scan_margin >= 0, init_extent > 0 and scan radii "
                              "> 0 required")
        if self.vis_grid is not None:
            g = tuple(self.vis_grid)
            if len(g) != 3 or not all(isinstance(n, int) and n >= 0 for n in g) or (0 in g and any(g)):
                raise ConfigError(f"CoherentGaussianConfig.vis_grid must be None or 3 cells (x, y, z), all >= 1 "
                                  f"or all 0, got {self.vis_grid!r}")
        if self.room_box is not None:
            box = np.asarray(self.room_box, np.float64)
            if box.shape != (6,) or not np.isfinite(box).all() or not (box[:3] < box[3:]).all():
                raise ConfigError(f"CoherentGaussianConfig.room_box must be 6 finite numbers (x0, y0, z0, x1, y1, "
                                  f"z1) [m] with x0 < x1, y0 < y1, z0 < z1, got {self.room_box!r}")
        if self.calibration_search not in ("auto", "apply", "off"):
            raise ConfigError(f"CoherentGaussianConfig.calibration_search must be 'auto', 'apply' or 'off', got "
                              f"{self.calibration_search!r}")
        if self.calibration_twin not in ("nearer", "other"):
            raise ConfigError(f"CoherentGaussianConfig.calibration_twin must be 'nearer' or 'other', got "
                              f"{self.calibration_twin!r}")
        if not 0.0 <= float(self.calibration_min_gain) <= 2.0:
            raise ConfigError(f"CoherentGaussianConfig.calibration_min_gain must be in [0, 2] (a gain in correlation), "
                              f"got {self.calibration_min_gain!r}")
        if self.pursuit not in ("auto", "on", "off"):
            raise ConfigError(f"CoherentGaussianConfig.pursuit must be 'auto', 'on' or 'off', got {self.pursuit!r}")
        if self.pursuit_planes < 0 or self.pursuit_views < 1 or not all(0 < float(t) < 1 for t in self.pursuit_at):
            raise ConfigError(f"CoherentGaussianConfig: pursuit_planes >= 0, pursuit_views >= 1 and every pursuit_at "
                              f"in (0, 1) required, got {self.pursuit_planes!r}, {self.pursuit_views!r}, "
                              f"{self.pursuit_at!r}")
        if self.furniture_planes not in ("faces", "box"):
            raise ConfigError(f"CoherentGaussianConfig.furniture_planes must be 'faces' or 'box', got "
                              f"{self.furniture_planes!r}")
        if not (0 < self.init_reflection <= 1 and self.scatterer_gain > 0 and 0 <= self.init_through <= 1
                and 0 < self.init_transmission <= 1):
            raise ConfigError("CoherentGaussianConfig: init_reflection in (0, 1], scatterer_gain > 0, init_through "
                              "in [0, 1] and init_transmission in (0, 1] required")
