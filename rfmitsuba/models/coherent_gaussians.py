"""Coherent Gaussian field: virtual sources and scatterers with complex gains, summed coherently at
the array's elements and read out by the Bartlett beamformer, for known and unknown rooms.

A PAS is the Bartlett response to a *coherent* sum of paths (docs/conventions.md). This field
models the paths themselves, with every parameter physical:

* **Image sources** ``i`` (``S`` of them): a virtual source at ``s_i = A_i y + b_i``, the image of
  the transmitter ``y`` under a fixed orthogonal map ``A_i`` (identity: the direct path; a
  reflection across a plane; a product of reflections) plus a learned offset ``b_i`` [m]. The
  images move with the transmitter, as a wall's image does in the moving-TX task. Path length
  ``L = |s_i - e_m|`` to element ``m``.
* **Scatterers** ``k`` (``P`` of them): a fixed point ``p_k`` [m] that re-radiates (furniture, an
  edge, a scatterer the data implies). Path length ``|y - p_k| + |p_k - e_m|``.

Each source carries a complex gain ``a`` (unitless: reflection coefficients and the rest) and a
**visibility window** over the moving device's position ``q``: ``w(q) = exp(-|q - c|^2 / (2
sigma^2))`` with centre ``c`` [m] and extent ``sigma`` [m], the Gaussian of the name; it sets
where a contribution is seen (a finite wall, an occluded path). Optionally (``vis_grid``, on by
default) the window is also multiplied by ``2 sigmoid(v(q))``, ``v`` a coarse
trilinear grid per source over the box of the training positions (padded by 5% each side;
clamped to its faces beyond it), zero at the start: shadows and lit regions that one Gaussian
window cannot draw. The channel at element ``m`` is

    h_m = cal_m * sum_sources  a * w(q) * exp(-j k L_m) / D,

with ``D`` the spreading (``L`` for an image, ``|y - p| |p - e_m|`` for a scatterer), ``k = 2 pi /
lambda``, and ``cal_m`` a learned complex per-element calibration (cable and phase-centre errors of a
measured array). For phase-only (NeRF2) spectra by default (``coupling``) the elements' channels are first mixed by ``I + K``,
``K`` a learned complex 16 x 16 matrix (zero at the start): a real array's mutual coupling, under
which an element's response depends on the arrival direction and no per-element gain undoes it.
By default ``K`` is reciprocal (``K = K^T``) and couples neighbouring elements only (row, column
and diagonal neighbours: 42 complex coefficients, ``coupling_model``), as a passive array's
coupling does; a free ``K`` fits the training positions as well and extrapolates much worse. Phase comes from the exact path length to each element (``wavefront =
"spherical"``) or from the plane-wave rule about the array centre (``"plane"``, what Sionna's
synthetic array simulates). The array's pose is learned too: a small rotation (rotation vector
``omega`` [rad]) and a translation ``t`` [m] of the array relative to its stated pose.

The read-out is the amplitude Bartlett (:func:`rfmitsuba.rf.bartlett.bartlett`) or, for NeRF2's
measured spectra, its **phase-only** variant, which uses ``h_m / |h_m|``.

Initialisation (:meth:`CoherentGaussianField.for_training`):

* **known room** (the dataset names a scene): the image maps of the room's planes
  (:func:`rfmitsuba.rf.images.scene_image_maps`: the room's box, and the planes of its furniture's,
  doors' and windows' faces), each plane sequence its own image. Whether each image's path
  exists for a view, and whether something stands across it, is decided by Mitsuba ray casts
  in the room's meshes (:class:`rfmitsuba.sim.visibility.SpecularVisibility`, the same JIT):
  a path that does not exist contributes nothing, a clear one with ``g = img_amp + img_slope *
  (c - 1/2)``, where ``c`` is the mean ``|cos|`` of the path's angles of incidence (a reflection
  coefficient changes with the angle: Fresnel), and a blocked one with ``g * T + img_through``:
  what passes through the obstacle. ``T = exp(sum_g n_g (rho_g + j phi_g))`` over the radio
  materials ``g`` of the room, ``n_g`` the surfaces of material ``g`` the path crosses (ray
  cast) and ``rho_g + j phi_g`` = ``mat_through`` the learned log-transmission of one crossing,
  as Sionna RT refracts through each surface as a thin slab without bending the ray; so a path
  blocked by the wardrobe at one position and by the bed at another is attenuated by each
  (``material_through``; off by default, ``T = 0``: it did not help in the bedroom).
  ``img_through`` is the blocked path's own gain. A ray tracer counts each crossing as an interaction,
  so where the data were simulated with at most ``D`` interactions per path (the dataset's
  ``solver.max_depth``), a path with more reflections plus crossings than ``D`` does not
  exist (Sionna's default D = 3: the direct path through a wardrobe, two crossings, exists; a
  double reflection through it does not). A tracer also drops a path with a segment shorter
  than its threshold (Sionna RT: 1 cm, ``segment_limit``): a direct path that cuts 6 mm
  through a wardrobe's corner does not exist in such data. Images whose path exists at no
  training position are left out;
* **unknown room**: from the training PAS alone (:func:`scan`): matching pursuit on arrival
  directions. The direct path is explained first; then candidate images across axis-aligned
  planes (offsets every ``scan_step`` metres) and candidate scatterers on a grid are scored by
  the mean remaining PAS in the direction each would arrive from at the training views, and
  the best is kept and a beam around its directions masked, ``images`` times, then
  ``scatterers`` times. The planes' images are composed up to ``image_order`` reflections
  (:func:`compose_images`). A known room gets scanned scatterers beside its image sources too.
  Where the moving device walks round the fixed one (a room, either task: :func:`spreads_wide`)
  the scan keeps no plane, and during training the field grows one plane at a time where the
  loss asks for one (:mod:`rfmitsuba.train.pursuit`, ``pursuit``): the walls next to the fixed
  device too, whose images arrive within the array's beam of the direct path, which the scan
  cannot see.

Parameters (Dr.Jit ``Float``; name, size, unit, optimizer group):

=================  ============  ==========  ==========
``img_offset``     S*3           m           means
``img_amp``        S*2 (re, im)  1           amp
``img_through``    S*2           1           amp  (known room with ray-cast visibility only)
``img_slope``      S*2           1           amp  (known room with ray-cast visibility only)
``mat_through``    G*2           1, rad      amp  (log-magnitude, phase per crossing of each of
                                                  the room's G radio materials; ray casts only)
``sc_pos``         P*3           m           means
``sc_amp``         P*2           1           amp
``vis_center``     (S+P)*3       m           means
``vis_log_extent`` S+P           log m       log_scales
``vis_grid``       (S+P)*G       1 (logit)   amp  (G = the grid's cells, ``vis_grid`` on only)
``vis_grid_box``   6             m           not trained: the grid's box (low corner, high corner)
``cal``            16*2          1           amp
``coupling``       C*2           1           amp  (``coupling`` on only: ``K``'s C = 42 neighbour pairs, or
                                                  256 entries with ``coupling_model = "full"``)
``pose``           6             rad, m      means in a known room (decays), else rotations (constant)
=================  ============  ==========  ==========

All are differentiable (tests/models/test_coherent_gaussians.py checks each against finite
differences). State is plain NumPy (npz, no pickle).
"""
from __future__ import annotations

import dataclasses
import json
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..core import backend as B
from ..core.config import from_dict, to_dict
from ..core.errors import ConfigError, RunError
from ..rf import array as antenna
from ..rf.bartlett import bartlett
from ..rf.bartlett import weights as bartlett_weights
from ..rf.calibration_fit import los_calibration_fit
from ..rf.frame_fit import los_frame_fit
from ..rf.images import ImageMaps, scene_image_maps
from .base import FlatParameterField, Views, register
from .coherent import _columns, _write_points_ply

FORMAT = "rfmitsuba-coherent-gaussians/1"
#: most training spectra the initial scan reads (evenly spread over the training samples)
SCAN_SAMPLES = 1024

#: optimizer group of every parameter (rfmitsuba.train.trainer's learning rates)
LR_GROUPS = {"img_offset": "means", "img_amp": "amp", "img_through": "amp", "img_slope": "amp",
             "mat_through": "amp", "sc_pos": "means",
             "sc_amp": "amp", "vis_center": "means", "vis_log_extent": "log_scales", "vis_grid": "amp",
             "cal": "amp", "coupling": "amp", "pose": "means"}   # vis_grid_box is never trained: no group
#: a frame fit gaining at least this much line-of-sight correlation over the stated frame warns
#: (a right frame gained 0.002 on NeRF2-like data, one 25 / 45 degrees off 0.023 / 0.66)
FRAME_WARN_GAIN = 0.05
#: the visibility grid every field gets by default (cells along x, y, z), CoherentGaussianConfig.vis_grid
DEFAULT_VIS_GRID = (4, 4, 2)
#: an unknown room's default grid where it has at least DENSE_POSITIONS training positions
DENSE_VIS_GRID = (8, 8, 4)
DENSE_POSITIONS = 1000
#: least passes over the fitting positions a field with a grid of DENSE_VIS_GRID's cells or more
#: advises (CoherentGaussianField.epochs_advised)
DENSE_EPOCHS = 40.0
#: most views whose ray-cast path visibility a known-room field remembers (CoherentGaussianField.path_trace)
VIS_CACHE_VIEWS = 20000
#: spread of the jittered training views the field advises for phase-only (NeRF2) spectra
#: [carrier wavelengths]: 5.0 cm at NeRF2's 920 MHz (TrainConfig.jitter, rfmitsuba.train.jitter)
JITTER_PHASE_ONLY = 0.153
#: planes the data scan finds for an unknown room by default where the moving device's positions
#: lie within the array's beam (CoherentGaussianConfig.images = None; elsewhere none: the pursuit)
SCAN_PLANES = 12


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
        spread wider (:func:`spreads_wide`: a walked room, where the plane pursuit finds them).
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
        seen from the fixed device, than half the array's beam (:func:`spreads_wide`: a device
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


def position_spread_deg(fixed: np.ndarray, moving: np.ndarray) -> float:
    """How widely the moving device's positions spread as seen from the fixed device: the median
    angle [degrees] between the directions from ``fixed`` (float [3] or [N, 3] m) to each of
    ``moving`` (float [N, 3] m) and their mean direction."""
    v = np.asarray(moving, np.float64).reshape(-1, 3) - np.asarray(fixed, np.float64).reshape(-1, 3)
    n = np.linalg.norm(v, axis=1)
    v = v[n > 1e-9] / n[n > 1e-9, None]
    if not len(v):
        return 0.0
    m = v.mean(0)
    if np.linalg.norm(m) < 1e-9:                 # positions all round the fixed device
        return 90.0
    return float(np.median(np.degrees(np.arccos(np.clip(v @ (m / np.linalg.norm(m)), -1.0, 1.0)))))


def spreads_wide(data) -> bool:
    """Whether ``data``'s training positions (a :class:`~rfmitsuba.data.views.TrainData`) spread
    wider, seen from the fixed device, than half the array's half-power beamwidth
    (:func:`rfmitsuba.rf.array.half_power_beamwidth_deg`, 13 degrees): a moving device that walks the
    room around the fixed one (our rooms: 21-23 degrees), not tags in a patch far from the gateway
    (NeRF2-like: about 4 degrees). Within the beam a source arrives from about one direction at every
    view, which the data scan's directional search needs; beyond it the plane pursuit finds the
    planes (:class:`CoherentGaussianConfig`, ``pursuit`` and ``images``)."""
    idx = np.asarray(data.train, np.int64)
    x, y, q = data.positions(idx)
    fixed = y if data.task == "rx" else x
    return position_spread_deg(fixed, q) > antenna.half_power_beamwidth_deg() / 2


def scan_planes(cfg: CoherentGaussianConfig, data) -> int:
    """Planes the data scan finds for an unknown room: ``cfg.images``, or where it is None
    :data:`SCAN_PLANES` for positions within the array's beam and none where they spread wider
    (:func:`spreads_wide`: the plane pursuit finds them)."""
    if cfg.images is not None:
        return int(cfg.images)
    return 0 if spreads_wide(data) else SCAN_PLANES


def uses_pursuit(cfg: CoherentGaussianConfig, data) -> bool:
    """Whether an unknown room's field grows planes by the plane pursuit during training:
    ``cfg.pursuit`` "on" / "off", or "auto": where the positions spread wider than the array's
    beam (:func:`spreads_wide`)."""
    if cfg.pursuit != "auto":
        return cfg.pursuit == "on"
    return spreads_wide(data)


def default_vis_grid(*, init: str, num_positions: int) -> tuple[int, int, int]:
    """The visibility grid of ``vis_grid = None``: :data:`DENSE_VIS_GRID` for an unknown room
    (``init`` "data") with at least :data:`DENSE_POSITIONS` distinct training positions, else
    :data:`DEFAULT_VIS_GRID`. A finer grid draws finer shadows where the data are dense enough to
    show them: NeRF2-like, 2000 tags (1600 training), seeds 0 / 1: 0.920 / 0.918 with (4, 4, 2),
    0.925 / 0.926 (medians 0.942 / 0.944) with (8, 8, 4), 0.927 / 0.946 with (12, 12, 6) on seed
    0 (IDW-3 0.919 / 0.938). With 160 training tags (8, 8, 4) scores 0.956 / 0.960 against
    0.958 +- 0.001; the rooms' 720 positions keep the grid their figures were measured with."""
    if init == "data" and num_positions >= DENSE_POSITIONS:
        return DENSE_VIS_GRID
    return DEFAULT_VIS_GRID


# ------------------------------------------------------------------------------ initialisation

def pas_pixels(shape: tuple, u: np.ndarray) -> np.ndarray:
    """Flat pixel index (``row * W + col``) of each arrival direction on a PAS grid.

    Args:
        shape: (H, W) of the grid (:mod:`rfmitsuba.rf.grid`, any 90/d x 360/d).
        u: float [..., 3] unit directions in the array frame; arrivals from below fold onto the
            upper hemisphere, as the horizontal array folds them.
    Returns:
        int64 [...].
    """
    h, w = shape
    res = 90.0 / h
    el = np.degrees(np.arcsin(np.clip(np.abs(u[..., 2]), 0.0, 1.0)))
    az = np.degrees(np.arctan2(u[..., 1], u[..., 0])) % 360.0
    row = np.clip(np.rint((el - (res + 1.0) / 2.0) / res).astype(np.int64), 0, h - 1)   # rfmitsuba.rf.grid
    col = np.rint((az - (res - 1.0) / 2.0) / res).astype(np.int64) % w
    return row * w + col


def pas_lookup(pas: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Value of each view's PAS in the arrival direction ``u``.

    Args:
        pas: float [N, H, W] normalised PAS (grid of :mod:`rfmitsuba.rf.grid`, any 90/d x 360/d).
        u: float [N, C, 3] unit directions in the array frame (C candidates per view); arrivals
            from below fold onto the upper hemisphere, as the horizontal array folds them.
    Returns:
        float64 [N, C].
    """
    n, h, w = pas.shape
    return np.asarray(pas, np.float64).reshape(n, -1)[np.arange(n)[:, None], pas_pixels((h, w), u)]


def _unit(d: np.ndarray) -> np.ndarray:
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)


def _fold(u: np.ndarray) -> np.ndarray:
    """Directions folded onto the upper hemisphere (what a horizontal array sees)."""
    return np.concatenate([u[..., :2], np.abs(u[..., 2:])], axis=-1)


class _Residual:
    """The training PAS with the directions already explained masked out (matching pursuit on
    arrival directions): :meth:`score` is the mean remaining PAS in each candidate's direction,
    :meth:`explain` masks a beam width around a chosen source's direction at every view."""

    def __init__(self, pas: np.ndarray, radius_deg: float):
        from ..rf.grid import directions

        self.pas = np.array(pas, np.float64, copy=True)
        n, h, w = self.pas.shape
        self.dirs = directions(resolution_deg=90.0 / h).reshape(-1, 3)
        self.cos_r = np.cos(np.radians(radius_deg))

    def score(self, u: np.ndarray) -> np.ndarray:
        """u: float [N, C, 3] array-frame directions -> float [C]."""
        return pas_lookup(self.pas, u).mean(0)

    def score_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """:meth:`score` of directions already turned into pixels (:func:`pas_pixels`, int [N, C])."""
        n = len(self.pas)
        return self.pas.reshape(n, -1)[np.arange(n)[:, None], pixels].mean(0)

    def explain(self, u: np.ndarray) -> None:
        """u: float [N, 3], one chosen source's direction at every view."""
        n, h, w = self.pas.shape
        near = (_fold(u) @ self.dirs.T) >= self.cos_r                  # [N, H*W]
        self.pas.reshape(n, -1)[near] = 0.0


def _greedy(res: _Residual, dirs: np.ndarray, count: int, *, allowed: np.ndarray | None = None) -> list[int]:
    """Pick ``count`` candidates one by one by their score on the residual, explaining each away.

    dirs: float [N, C, 3] directions of every candidate at every view."""
    chosen: list[int] = []
    ok = np.ones(dirs.shape[1], bool) if allowed is None else allowed.copy()
    pixels = pas_pixels(res.pas.shape[1:], dirs) if count else None   # the directions stay; the residual changes
    for _ in range(count):
        if not ok.any():
            break
        sc = np.where(ok, res.score_pixels(pixels), -np.inf)
        i = int(np.argmax(sc))
        if not np.isfinite(sc[i]) or sc[i] <= 0:
            break
        chosen.append(i)
        ok[i] = False
        res.explain(dirs[:, i])
    return chosen


def scan(pas: np.ndarray, x: np.ndarray, y: np.ndarray, *, images: int, scatterers: int, step: float,
         margin: float, rx_to_world: np.ndarray | None = None, radius_deg: float = 12.0, max_views: int = 128,
         max_points: int = 12000) -> dict:
    """Sources that the training PAS imply, for an unknown room (matching pursuit on arrival
    directions; the direct path is explained first).

    Candidates: the images of every transmitter across axis-aligned planes ``coord_a = d`` (offset
    every ``step`` metres within the positions' bounds padded by ``margin``, planes through the
    positions' own span excluded) and fixed scatterers on a grid (every ``max(step, 0.25)`` metres,
    at most about ``max_points`` points, none within 0.3 m of a position). Scores average over at
    most ``max_views`` training views, evenly spaced. A candidate's score is the mean
    of the residual PAS in the direction it would arrive from at every training view; the best is
    kept and a ``radius_deg`` beam around its directions is masked, ``images`` times for planes,
    then ``scatterers`` times for points.

    Args:
        pas: float [N, H, W] normalised training PAS; x, y: float [N, 3] array centres and
            transmitters [m]; rx_to_world: float [3, 3] array frame -> world, or None.
    Returns:
        {"A": float [S, 3, 3] reflections, "b": float [S, 3] [m], "image_score": [S],
         "points": float [P, 3] [m], "point_score": [P]}.
    """
    R = np.eye(3) if rx_to_world is None else np.asarray(rx_to_world, np.float64)
    if len(pas) > max_views:  # the score is a mean over views: an even subset estimates it
        keep = np.linspace(0, len(pas) - 1, max_views).round().astype(np.int64)
        pas, x, y = pas[keep], x[keep], y[keep]
    res = _Residual(pas, radius_deg)
    res.explain(_unit(y - x) @ R)                                    # the direct path
    pts = np.concatenate([x, y])
    lo, hi = pts.min(0) - margin, pts.max(0) + margin
    axis = np.concatenate([np.full(len(np.arange(lo[a], hi[a] + 1e-9, step)), a) for a in range(3)])
    off = np.concatenate([np.arange(lo[a], hi[a] + 1e-9, step) for a in range(3)])
    inside = (off > pts.min(0)[axis] - 0.2) & (off < pts.max(0)[axis] + 0.2)
    img = np.repeat(y[:, None, :], len(off), 1)
    img[:, np.arange(len(off)), axis] = 2 * off[None, :] - y[:, axis]
    img_dirs = _unit(img - x[:, None, :]) @ R
    sc0 = res.score(img_dirs)
    pick = _greedy(res, img_dirs, images, allowed=~inside)
    A = np.repeat(np.eye(3)[None], len(pick), 0)
    b = np.zeros((len(pick), 3))
    for n, i in enumerate(pick):
        A[n, axis[i], axis[i]] = -1.0
        b[n, axis[i]] = 2 * off[i]
    out = {"A": A, "b": b, "image_score": sc0[pick]}
    g = max(step, 0.25, float(np.prod(hi - lo) / max_points) ** (1 / 3))
    grid = np.stack(np.meshgrid(*[np.arange(lo[a] + g / 2, hi[a], g) for a in range(3)], indexing="ij"), -1)
    grid = grid.reshape(-1, 3)
    sub = pts[::max(1, len(pts) // 256)]
    far = np.min(np.linalg.norm(grid[:, None, :] - sub[None], axis=-1), axis=1) >= 0.3
    grid = grid[far]
    if scatterers and len(grid):
        # for a fixed array, points along one ray look alike: keep one candidate per direction cell
        dirs = _unit(grid[None] - x[:, None, :]) @ R                 # [N, G, 3]
        pick = _greedy(res, dirs, scatterers)
        out["points"], out["point_score"] = grid[pick], np.zeros(len(pick))
    else:
        out["points"], out["point_score"] = np.zeros((0, 3)), np.zeros(0)
    return out


def outside_room_box(box, positions: np.ndarray) -> np.ndarray:
    """Which ``positions`` (float [N, 3] m) lie outside the box ``(x0, y0, z0, x1, y1, z1)`` [m]
    (its faces count as inside): bool [N]."""
    box = np.asarray(box, np.float64).reshape(6)
    pts = np.asarray(positions, np.float64).reshape(-1, 3)
    return ~((pts >= box[:3]) & (pts <= box[3:])).all(axis=1)


def room_box_planes(box, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The six walls of a known room box as reflections ``y -> A y + b``.

    Args:
        box: (x0, y0, z0, x1, y1, z1) [m]; positions: float [N, 3] every known position [m]
            (the moving device's, the array's, the transmitter's), which must lie inside it.
    Returns:
        (A float64 [6, 3, 3], b float64 [6, 3] [m]): x0, x1, y0, y1, z0, z1.
    Raises:
        ConfigError: a position outside the box (named, with its coordinates).
    """
    box = np.asarray(box, np.float64).reshape(6)
    pts = np.asarray(positions, np.float64).reshape(-1, 3)
    outside = outside_room_box(box, pts)
    if outside.any():
        i = int(np.argmax(outside))
        raise ConfigError(f"coherent_gaussians.room_box {box.tolist()}: position {i} at "
                          f"{np.round(pts[i], 3).tolist()} m lies outside the room "
                          f"({int(outside.sum())} of {len(pts)} positions do)")
    A = np.repeat(np.eye(3)[None], 6, 0)
    b = np.zeros((6, 3))
    for k, (axis, offset) in enumerate([(0, box[0]), (0, box[3]), (1, box[1]), (1, box[4]), (2, box[2]), (2, box[5])]):
        A[k, axis, axis] = -1.0
        b[k, axis] = 2.0 * offset
    return A, b


def compose_images(A: np.ndarray, b: np.ndarray, *, max_order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The direct path plus the images of up to ``max_order`` reflections across the given planes.

    Args:
        A, b: float [n, 3, 3] / [n, 3], single reflections ``y -> A y + b``.
        max_order: reflections per image (>= 1); consecutive reflections across one plane cancel
            and are left out, identical maps appear once.
    Returns:
        (A float64 [S, 3, 3], b float64 [S, 3] [m], order int64 [S]), the direct path first.
    """
    out = [(np.eye(3), np.zeros(3), 0, -1)]
    seen = {tuple(np.round(np.concatenate([np.eye(3).ravel(), np.zeros(3)]), 6))}
    frontier = [out[0]]
    for order in range(1, max_order + 1):
        nxt = []
        for Am, bm, _, last in frontier:
            for i in range(len(A)):
                if i == last:
                    continue
                An, bn = A[i] @ Am, A[i] @ bm + b[i]
                key = tuple(np.round(np.concatenate([An.ravel(), bn]), 6))
                if key in seen:
                    continue
                seen.add(key)
                nxt.append((An, bn, order, i))
        out += nxt
        frontier = nxt
    return (np.stack([o[0] for o in out]), np.stack([o[1] for o in out]), np.array([o[2] for o in out], np.int64))


def summed_channels(fields: list, views: Views) -> tuple:
    """The calibrated channels of ``fields`` (coherent Gaussian family) added: (re, im) ``Float`` [B*16]."""
    hr = hi = None
    for f in fields:
        fr, fi = f.channels(views)
        hr, hi = (fr, fi) if hr is None else (hr + fr, hi + fi)
    return hr, hi


def read_out(h_re, h_im, *, readout: str, frequency_hz: float, height: int, width: int, normalize: bool):
    """PAS of calibrated channels (re, im) ``Float`` [B*16]: the amplitude Bartlett, or for
    ``readout = "phase_only"`` the Bartlett of ``h_m / |h_m|`` (NeRF2's measured spectra):
    ``TensorXf`` [B, height, width], differentiable in the channels."""
    import drjit as dr

    if readout == "phase_only":
        mag = dr.sqrt(h_re * h_re + h_im * h_im + 1e-20)
        h_re, h_im = h_re / mag, h_im / mag
    return bartlett(h_re, h_im, frequency_hz=frequency_hz, height=height, width=width, normalize=normalize)


def _jit_arrays(tree) -> list:
    """The Dr.Jit arrays in ``tree`` (dicts, lists and tuples of them, searched depth first;
    anything else is skipped)."""
    import drjit as dr

    if dr.is_array_v(tree):
        return [tree]
    if isinstance(tree, dict):
        tree = list(tree.values())
    if isinstance(tree, (list, tuple)):
        return [a for v in tree for a in _jit_arrays(v)]
    return []


# ------------------------------------------------------------------------------ the field

def _check_orthogonal(A: np.ndarray, owner: str) -> None:
    """ConfigError naming ``owner`` unless every map of ``A`` (float [S, 3, 3]) is orthogonal."""
    if not np.allclose(np.einsum("sij,skj->sik", A, A), np.eye(3), atol=1e-6):
        raise ConfigError(f"{owner}: image maps must be orthogonal")


def _builtin_scene(xml: str) -> str:
    """The built-in scene a missing XML path names (a run saved in another checkout), else RunError."""
    from ..scenes import path as scene_path

    try:
        found = Path(scene_path(Path(xml).stem))
    except Exception:  # noqa: BLE001 - not a built-in scene's name
        found = None
    if found is None or found.name != Path(xml).name or not found.is_file():
        raise RunError(f"CoherentGaussianField: the room's XML {xml} (ray-cast visibility) is missing")
    return str(found)


def coupling_index(model: str = "neighbours") -> np.ndarray:
    """Which learned coupling coefficient each entry ``K[m, n]`` of the mutual coupling ``I + K``
    of the 4 x 4 array takes: int64 [16, 16], -1 where ``K[m, n] = 0``.

    ``"neighbours"``: a reciprocal coupling (``K = K^T``, as for any passive array) between
    elements that are row, column or diagonal neighbours (42 pairs, 84 parameters); elements
    farther apart and ``K[m, m]`` (a per-element gain, which the calibration already holds)
    take none. ``"full"``: every entry its own coefficient (256, 512 parameters).
    """
    M = antenna.NUM_ELEMENTS
    if model == "full":
        return np.arange(M * M, dtype=np.int64).reshape(M, M)
    if model != "neighbours":
        raise ConfigError(f"coupling model must be 'neighbours' or 'full', got {model!r}")
    r, c = np.divmod(np.arange(M), antenna.COLS)
    near = (np.abs(r[:, None] - r[None]) <= 1) & (np.abs(c[:, None] - c[None]) <= 1) & ~np.eye(M, dtype=bool)
    out = np.full((M, M), -1, np.int64)
    m, n = np.nonzero(np.triu(near, 1))
    out[m, n] = out[n, m] = np.arange(len(m))
    return out


def coupling_size(model: str = "neighbours") -> int:
    """Learned complex coupling coefficients of ``model`` (:func:`coupling_index`)."""
    return int(coupling_index(model).max()) + 1


def _rodrigues(w0, w1, w2, v0, v1, v2):
    """Rotate vectors ``v`` by the rotation vector ``w`` (Dr.Jit arrays, broadcast)."""
    import drjit as dr

    th = dr.sqrt(w0 * w0 + w1 * w1 + w2 * w2 + 1e-24)
    k0, k1, k2 = w0 / th, w1 / th, w2 / th
    c, s = dr.cos(th), dr.sin(th)
    kv = k0 * v0 + k1 * v1 + k2 * v2
    cx0, cx1, cx2 = k1 * v2 - k2 * v1, k2 * v0 - k0 * v2, k0 * v1 - k1 * v0
    return (v0 * c + cx0 * s + k0 * kv * (1 - c), v1 * c + cx1 * s + k1 * kv * (1 - c),
            v2 * c + cx2 * s + k2 * kv * (1 - c))


@register
class CoherentGaussianField(FlatParameterField):
    """The coherent Gaussian field (see the module docstring).

    Args:
        A: float [S, 3, 3] fixed orthogonal maps of the image sources (identity = direct path).
        order: int [S] reflections of each image (0 = direct path), for the initial gains.
        scatterers: float [P, 3] initial scatterer positions [m].
        cfg: :class:`CoherentGaussianConfig`; readout / wavefront: resolved ("amplitude" or
            "phase_only"; "plane" or "spherical").
        vis_center: float [3] initial visibility centre (the moving positions' centre) [m].
        frequency_hz: carrier [Hz]; seed, name: as the other fields.
        params: stored parameters (name -> float32 array) instead of the initial ones.
        planes: float [S, O, 4] each image's reflection planes (:attr:`rfmitsuba.rf.images.ImageMaps.planes`)
            and scene_xml: the room; with both (and ``cfg.ray_visibility``), the images' visibility is ray-cast
            (:class:`~rfmitsuba.sim.visibility.SpecularVisibility`) and ``img_through`` and
            ``img_slope`` are learned.
        max_depth: most reflections plus crossings of a path in the data (their ray tracer's
            depth; None: no limit), applied with ``cfg.depth_limit``.
        min_segment: the simulating ray tracer's shortest path segment [m] (None: no limit),
            applied with ``cfg.segment_limit``.
    """

    LR_GROUPS = LR_GROUPS
    kind = "coherent_gaussians"
    family = "coherent_gaussians"
    format = FORMAT
    #: trains on 45 x 180 block means (``TrainConfig.downsample = 0``): its sources are points and
    #: its read-out the array's beam (about 26 degrees wide), so 2-degree pixels pin them as well as
    #: 1-degree ones at a quarter of the read-out's cost (docs/lab-notes/measurements.md)
    downsample_advised = 2

    def __init__(self, A: np.ndarray, order: np.ndarray, scatterers: np.ndarray, *, cfg: CoherentGaussianConfig,
                 readout: str, wavefront: str, vis_center: np.ndarray, frequency_hz: float, seed: int = 0,
                 name: str = "bg", params: dict | None = None, scatterer_scale: float = 1.0,
                 init: str | None = None, planes: np.ndarray | None = None, scene_xml: str | Path | None = None,
                 max_depth: int | None = None, min_segment: float | None = None):
        B.ensure()
        self.A = np.asarray(A, np.float64).reshape(-1, 3, 3)
        self.order = np.asarray(order, np.int64).reshape(-1)
        if len(self.order) != len(self.A) or len(self.A) == 0:
            raise ConfigError("CoherentGaussianField: one order per image map, and at least one image")
        _check_orthogonal(self.A, "CoherentGaussianField")
        if readout not in ("amplitude", "phase_only") or wavefront not in ("plane", "spherical"):
            raise ConfigError(f"CoherentGaussianField: readout {readout!r} / wavefront {wavefront!r} not resolved")
        if cfg.coupling == "auto":
            cfg = dataclasses.replace(cfg, coupling=readout == "phase_only")
        self.cfg, self.readout, self.wavefront = cfg, readout, wavefront
        #: K[m, n]'s coefficient per entry (UInt32 [256]) and 1 where it has one, else 0 (Float [256])
        index = coupling_index(cfg.coupling_model).ravel()
        self._coupling_lanes = (B.UInt32(np.maximum(index, 0).astype(np.uint32)),
                                B.Float((index >= 0).astype(np.float32)))
        self.frequency_hz = float(frequency_hz)
        antenna.wavelength(self.frequency_hz)
        self.seed, self.name = int(seed), name
        #: how the field was initialised: "room" or "data" (None when not known)
        self.init = init
        self.init_report: dict = {}   # what for_training decided (e.g. {"frame_fit": ...}), for the run summary
        self.frozen = False
        self.scatterer_scale = float(scatterer_scale)
        #: the fixed image maps as 9 device columns, uploaded once
        self._A_cols = _columns(self.A.reshape(-1, 9))
        sc = np.asarray(scatterers, np.float64).reshape(-1, 3)
        S, P = len(self.A), len(sc)
        self.num_images, self.num_scatterers = S, P
        #: cells of each source's visibility grid (0: none)
        self.grid_cells = int(np.prod(cfg.vis_grid)) if cfg.vis_grid else 0
        self.planes = self.scene_xml = self._vis = None
        #: most reflections plus crossings of a path (None: no limit); see CoherentGaussianConfig.depth_limit
        self.max_depth = None if max_depth is None or not cfg.depth_limit else int(max_depth)
        #: shortest segment of a path [m] (None: no limit); see CoherentGaussianConfig.segment_limit
        self.min_segment = None if min_segment is None or not cfg.segment_limit else float(min_segment)
        if planes is not None and scene_xml is not None and cfg.ray_visibility:
            from ..sim.visibility import SpecularVisibility

            self.planes = np.asarray(planes, np.float64)
            if self.planes.ndim != 3 or self.planes.shape[0] != S or self.planes.shape[2] != 4 \
                    or self.order.max() > self.planes.shape[1]:
                raise ConfigError(f"CoherentGaussianField: planes must be [S={S}, O >= max order, 4], "
                                  f"got {self.planes.shape}")
            self.scene_xml = str(scene_xml)
            if not Path(self.scene_xml).is_file():
                self.scene_xml = _builtin_scene(self.scene_xml)
            self._vis = SpecularVisibility.from_xml(self.scene_xml)
            #: (x, y) rows already cast -> (exists bool [S], clear bool [S], cos_incidence float [S])
            self._vis_cache: dict = {}
        if params is None:
            a = cfg.init_reflection ** self.order.astype(np.float64)
            params = {"img_offset": np.zeros(S * 3), "img_amp": np.stack([a, np.zeros(S)], 1).ravel(),
                      "sc_pos": sc.ravel(),
                      "sc_amp": np.tile([cfg.scatterer_gain * self.scatterer_scale, 0.0], P),
                      "vis_center": np.tile(np.asarray(vis_center, np.float64).reshape(3), S + P),
                      "vis_log_extent": np.full(S + P, np.log(cfg.init_extent)),
                      "cal": np.tile([1.0, 0.0], antenna.NUM_ELEMENTS), "pose": np.zeros(6)}
            if cfg.coupling:
                params["coupling"] = np.zeros(2 * coupling_size(cfg.coupling_model))
            if self._vis is not None:
                params["img_through"] = cfg.init_through * params["img_amp"]
                params["img_slope"] = np.zeros(S * 2)
                if cfg.material_through:
                    G = len(self._vis.group_names)
                    params["mat_through"] = np.tile([np.log(cfg.init_transmission), 0.0], G)
            if self.grid_cells:   # zero logits: a factor of 1; the box until for_training sets it
                params["vis_grid"] = np.zeros((S + P) * self.grid_cells)
                c0 = np.asarray(vis_center, np.float64).reshape(3)
                params["vis_grid_box"] = np.concatenate([c0 - 1.0, c0 + 1.0])
        self.params: dict = {}
        self.load_state_dict(params)

    # ---- construction ----------------------------------------------------------------------
    @classmethod
    def for_training(cls, cfg, data, *, scene_xml: Path | None, rng: np.random.Generator | None = None,
                     extra_inputs: int = 0, name: str = "bg") -> "CoherentGaussianField":
        """The Stage-1 initial field: the room's image sources (known room) or the data scan
        (unknown room), plus scanned scatterers; read-out and wavefront resolved from the dataset.

        Args:
            cfg: the :class:`~rfmitsuba.train.config.TrainConfig` (``coherent_gaussians``, ``seed``).
            data: the :class:`~rfmitsuba.data.views.TrainData`; only its training positions and
                PAS are read.
            scene_xml: the room's XML, or None when it is unknown.
            extra_inputs: must be 0 (this field takes no per-view network inputs).
        """
        if extra_inputs:
            raise ConfigError("model 'coherent_gaussians' takes no extra per-view inputs (its End-to-End model is "
                              "the joint field, rfmitsuba.models.coherent_gaussians_joint)")
        c = cfg.coherent_gaussians
        init = c.init if c.init != "auto" else ("room" if scene_xml is not None else "data")
        if init == "room" and c.room_box is not None:
            raise ConfigError(f"coherent_gaussians.room_box describes an unknown room, but dataset {data.path} is "
                              f"trained from its scene's XML (init 'room'); set coherent_gaussians.init=data to "
                              f"train it as an unknown room with that box")
        if init == "room" and scene_xml is None:
            raise ConfigError(f"coherent_gaussians.init = 'room' but dataset {data.path} names no scene")
        measured = bool(getattr(data, "measured", False))
        readout = c.readout if c.readout != "auto" else str(getattr(data, "readout", "amplitude"))
        wavefront = c.wavefront if c.wavefront != "auto" else ("spherical" if measured else "plane")
        idx = np.asarray(data.train, np.int64)
        x, y, q = data.positions(idx)
        if c.vis_grid is None:
            c = dataclasses.replace(c, vis_grid=default_vis_grid(init=init, num_positions=len(np.unique(q, axis=0))))
        depth = getattr(data, "max_depth", None) if c.depth_limit else None   # the data's tracer depth
        min_seg = getattr(data, "min_segment", None) if c.segment_limit else None   # and its shortest segment
        # the scan reads at most SCAN_SAMPLES training spectra, evenly spread (a dataset of many
        # states, e.g. 720 positions x 30 walk states, would otherwise load 2.8 GB of PAS)
        scan_idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), SCAN_SAMPLES)).astype(np.int64))]
        xs, ys, _ = data.positions(scan_idx)
        pas = data.pas(scan_idx, d=2)
        if init == "room":
            from ..sim.geometry import RoomGeometry

            maps = scene_image_maps(RoomGeometry.from_xml(scene_xml), room_order=c.room_order,
                                    furniture_order=c.furniture_order, min_face_area=c.min_face_area,
                                    distinct_paths=c.ray_visibility, furniture_planes=c.furniture_planes)
            if c.ray_visibility and c.prune_unseen:
                # parsimony: an image whose path exists at no training position has no gradient
                from ..sim.visibility import SpecularVisibility

                xy = np.unique(np.concatenate([x, y], axis=1), axis=0)      # each geometry once
                tr = SpecularVisibility.from_xml(scene_xml).trace(xy[:, :3], xy[:, 3:], maps.planes, maps.order)
                seen = tr.within_depth(maps.order, depth).without_short_segments(min_seg).exists.any(0)
                seen[maps.order == 0] = True
                maps = ImageMaps(A=maps.A[seen], b=maps.b[seen], order=maps.order[seen],
                                 label=[lb for lb, k in zip(maps.label, seen) if k], planes=maps.planes[seen])
            A, order = maps.A, maps.order
            b0 = maps.b
        stated = np.eye(3) if data.rx_to_world is None else np.asarray(data.rx_to_world, np.float64)
        frame, report = stated, {}
        search = c.frame_search if c.frame_search != "auto" else ("report" if measured and init == "data" else "off")
        if search != "off":
            fit = los_frame_fit(pas, xs, ys, rx_to_world=stated, frequency_hz=data.frequency_hz)
            applied = search == "apply" and fit.gain >= c.frame_min_gain
            if fit.gain >= FRAME_WARN_GAIN:
                warnings.warn(f"{data.path}: the stated array frame draws the line of sight worse than a frame "
                              f"{fit.angle_deg:.0f} degrees away (correlation {fit.stated_score:.2f} against "
                              f"{fit.score:.2f}); check the gateway orientation"
                              + (" (training starts from the fitted frame)" if applied else
                                 " (coherent_gaussians.frame_search = 'apply' starts from the fitted frame)"),
                              stacklevel=2)
            report["frame_fit"] = {"applied": bool(applied), "angle_deg": fit.angle_deg,
                                   "rotvec_rad": fit.rotvec.tolist(), "score": fit.score,
                                   "stated_score": fit.stated_score, "min_gain": c.frame_min_gain}
            if applied:
                frame = fit.rx_to_world(stated)
        cal_search = c.calibration_search if c.calibration_search != "auto" else \
            ("apply" if readout == "phase_only" and init == "data" and c.calibrate else "off")
        if cal_search == "apply":
            cal_fit = los_calibration_fit(pas, xs, ys, rx_to_world=frame, frequency_hz=data.frequency_hz,
                                          seed=cfg.seed)
            twin = c.calibration_twin == "other"
            report["calibration_fit"] = {"applied": bool(cal_fit.gain >= c.calibration_min_gain),
                                         "phase_deg": np.degrees(cal_fit.twin_phase_rad if twin
                                                                 else cal_fit.phase_rad).tolist(),
                                         "twin": "other" if twin else "nearer",
                                         "score": cal_fit.twin_score if twin else cal_fit.score,
                                         "stated_score": cal_fit.stated_score,
                                         "min_gain": c.calibration_min_gain}
        found = scan(pas, xs, ys, images=0 if init == "room" else scan_planes(c, data),
                     scatterers=c.room_scatterers if init == "room" else c.scatterers,
                     step=c.scan_step, margin=c.scan_margin, rx_to_world=frame,
                     radius_deg=c.room_scan_radius_deg if init == "room" else c.scan_radius_deg)
        if init != "room":
            planes_A, planes_b = found["A"], found["b"]
            if c.room_box is not None:
                box_A, box_b = room_box_planes(c.room_box, np.concatenate([x, y, q]))
                planes_A, planes_b = np.concatenate([planes_A, box_A]), np.concatenate([planes_b, box_b])
            A, b0, order = compose_images(planes_A, planes_b, max_order=c.image_order)
        sc = found["points"]
        # a scatterer's spreading is |y-p||p-x| against the direct path's |y-x|: start it at
        # ``scatterer_gain`` of the direct path at the median view
        if len(sc):
            l1 = np.linalg.norm(y[:, None] - sc[None], axis=-1)
            l2 = np.linalg.norm(sc[None] - x[:, None], axis=-1)
            scale = float(np.median(l1 * l2 / np.maximum(np.linalg.norm(y - x, axis=-1), 1e-3)[:, None]))
        else:
            scale = 1.0
        ray = init == "room" and c.ray_visibility
        f = cls(A, order, sc, cfg=c, readout=readout, wavefront=wavefront, vis_center=q.mean(0),
                frequency_hz=data.frequency_hz, seed=cfg.seed, name=name, scatterer_scale=scale, init=init,
                planes=maps.planes if ray else None, scene_xml=scene_xml if ray else None,
                max_depth=depth, min_segment=min_seg)
        f.params["img_offset"] = B.Float(np.asarray(b0, np.float32).ravel())
        f.init_report = report
        if report.get("calibration_fit", {}).get("applied"):
            ph = np.radians(np.asarray(report["calibration_fit"]["phase_deg"], np.float64))
            f.params["cal"] = B.Float(np.stack([np.cos(ph), np.sin(ph)], 1).ravel().astype(np.float32))
        if report.get("frame_fit", {}).get("applied"):
            # the pose rotates the stated frame's element offsets in the world: rot(w) R = R C^T
            w = -stated @ np.asarray(report["frame_fit"]["rotvec_rad"])
            f.params["pose"] = B.Float(np.concatenate([w, np.zeros(3)]).astype(np.float32))
        if f.grid_cells:   # the training positions' box, padded by 5% (at least 1 mm) each side
            pad = 0.05 * (q.max(0) - q.min(0)) + 1e-3
            f.params["vis_grid_box"] = B.Float(np.concatenate([q.min(0) - pad, q.max(0) + pad]).astype(np.float32))
        return f

    # ---- parameters ------------------------------------------------------------------------
    def lr_group(self, name: str) -> str:
        """The optimizer group of parameter ``name`` (:data:`LR_GROUPS`). The array pose of a known
        room settles on the decaying "means" schedule (bedroom RX, seed 0: a late validation dip
        0.913 -> 0.877 gone, test 0.907 -> 0.909); from a data scan it keeps the constant
        "rotations" rate, which extrapolates better (NeRF2-like, unknown room, block split, seeds
        0 / 1: field alone 0.854 / 0.826 constant against 0.646 / 0.870 decaying)."""
        if name == "pose" and self.init != "room":
            return "rotations"
        return LR_GROUPS[name]

    @property
    def starts_advised(self) -> int:
        """2 where the elements' phase offsets were searched and applied at the start
        (``init_report["calibration_fit"]``), else 1. Fitting phases and sources together is not
        convex: on one NeRF2-like folder (+-180 degree offsets, 6000 steps, one start) 1 run in 7
        with the searched offsets stalled (validation 0.942, test 0.875, against 0.964-0.967),
        its training loss twice the others' from step 400 on (TrainConfig.starts). Also 2 where the
        mutual coupling is learned (``coupling``): NeRF2-like, coupling -15 dB, seeds 0-2, test SSIM
        0.948 / 0.960 / 0.961 with one start, 0.957 / 0.962 / 0.957 with two (IDW-3 0.952); the
        code as committed later, seeds 0-4, two starts: 0.954 +- 0.005, 4 of 5 above IDW-3
        (docs/lab-notes/measurements.md)."""
        searched = self.init_report.get("calibration_fit", {}).get("applied")
        return 2 if searched or self.cfg.coupling is True else 1

    @property
    def jitter_advised(self) -> float:
        """:data:`JITTER_PHASE_ONLY` wavelengths for phase-only (NeRF2) spectra, else 0
        (:mod:`rfmitsuba.train.jitter`). On the NeRF2-like spatial-block split (default folder,
        unknown room, validation slab held out) one field scored 0.886 +- 0.003 without and
        0.909 +- 0.006 with the jittered copies (3 and 10 seeds; nearest neighbour 0.911, IDW-3
        0.906), its spread over seeds a quarter of before; on the published random split 0.959
        +- 0.001 with them, 5 of 5 seeds above IDW-3, against 4 of 5 without (docs/lab-notes/measurements.md). Simulated rooms with the amplitude read-out were not measured with them, so
        they get none."""
        return JITTER_PHASE_ONLY if self.readout == "phase_only" else 0.0

    @property
    def epochs_advised(self) -> float:
        """:data:`DENSE_EPOCHS` (40) where the visibility grid has :data:`DENSE_VIS_GRID`'s cells
        (256) or more per source, else 0. A cell learns only from the views whose moving device
        is near it, so a fine grid needs passes over the data, not a fixed number of steps.
        NeRF2-like, (8, 8, 4) grid, test mean / median (IDW-3): 2000 tags (1576 fitting
        positions), seeds 0-2: 6000 steps (15 passes) 0.926 +- 0.001 / 0.943, 20 passes 0.922 +-
        0.004 / 0.941 (1 of 3 above IDW-3), 40 passes 0.929 +- 0.001 / 0.950 (3 of 3; IDW-3 0.919
        / 0.938); 6000 tags (4776 fitting positions), seed 0: 5 passes 0.915 / 0.934, 10 passes
        0.921 / 0.941, 20 passes 0.923 / 0.942, 40 passes 0.925 / 0.946 (IDW-3 0.916 / 0.936).
        Below 600 fitting positions 40 passes are fewer than the default 6000 steps at batch 4
        and change nothing."""
        return DENSE_EPOCHS if self.grid_cells >= int(np.prod(DENSE_VIS_GRID)) else 0.0

    def penalty(self):
        """``amp_l1`` times the mean magnitude of every source's complex gain (``img_amp`` and
        ``sc_amp``), or None where ``amp_l1`` is 0."""
        import drjit as dr

        if not self.cfg.amp_l1:
            return None
        total, n = 0.0, 0
        for key in ("img_amp", "sc_amp"):
            a = self.params.get(key)
            if a is None or dr.width(a) == 0:
                continue
            idx = dr.arange(B.UInt32, dr.width(a) // 2)
            re, im = dr.gather(B.Float, a, 2 * idx), dr.gather(B.Float, a, 2 * idx + 1)
            total = total + dr.sum(dr.sqrt(re * re + im * im + 1e-12))
            n += dr.width(a) // 2
        return None if n == 0 else total * (self.cfg.amp_l1 / n)

    def _sizes(self) -> dict:
        S, P = self.num_images, self.num_scatterers
        out = {"img_offset": S * 3, "img_amp": S * 2, "sc_pos": P * 3, "sc_amp": P * 2, "vis_center": (S + P) * 3,
               "vis_log_extent": S + P, "cal": 2 * antenna.NUM_ELEMENTS, "pose": 6}
        if self.cfg.coupling:
            out["coupling"] = 2 * coupling_size(self.cfg.coupling_model)
        if self.grid_cells:
            out["vis_grid"], out["vis_grid_box"] = (S + P) * self.grid_cells, 6
        if self._vis is not None:
            out["img_through"] = out["img_slope"] = S * 2
            if self.cfg.material_through:
                out["mat_through"] = 2 * len(self._vis.group_names)
        return out

    @property
    def num_primitives(self) -> int:
        """The Gaussians: image sources plus scatterers."""
        return self.num_images + self.num_scatterers

    def trainable(self) -> dict:
        out = super().trainable()  # no scatterers: no empty arrays
        drop = ([] if self.cfg.calibrate else ["cal"]) + ([] if self.cfg.learn_pose else ["pose"]) \
            + ([] if self.cfg.visibility else ["vis_center", "vis_log_extent"]) \
            + ([] if self.cfg.incidence_slope else ["img_slope"]) + ["vis_grid_box"]
        return {k: v for k, v in out.items() if k not in drop}

    def state_dict(self) -> dict:
        out = {k: np.array(v.numpy(), np.float32, copy=True) for k, v in self.params.items()}
        out["geometry.A"] = self.A.copy()
        out["geometry.order"] = self.order.copy()
        if self.planes is not None:
            out["geometry.planes"] = self.planes.copy()
        out["meta"] = np.asarray(json.dumps({
            "scene_xml": self.scene_xml,
            "format": FORMAT, "config": to_dict(self.cfg), "readout": self.readout, "wavefront": self.wavefront,
            "frequency_hz": self.frequency_hz, "seed": self.seed, "name": self.name, "frozen": self.frozen,
            "scatterer_scale": self.scatterer_scale, "init": self.init, "max_depth": self.max_depth,
            "min_segment": self.min_segment}))
        return out

    @classmethod
    def from_state_dict(cls, state: dict) -> "CoherentGaussianField":
        try:
            meta = json.loads(str(state["meta"]))
            if meta.get("format") != FORMAT:
                raise RunError(f"not a CoherentGaussianField state (format {meta.get('format')!r})")
            P = len(np.asarray(state["sc_pos"]).ravel()) // 3
            cfg = from_dict(CoherentGaussianConfig, meta["config"])
            if "mat_through" not in state and cfg.material_through:   # saved before material transmission
                cfg = dataclasses.replace(cfg, material_through=False)
            if "coupling" not in state and cfg.coupling is not False:  # saved before (or without) coupling
                cfg = dataclasses.replace(cfg, coupling=False)
            if "coupling" in state and np.asarray(state["coupling"]).size == 2 * coupling_size("full"):
                cfg = dataclasses.replace(cfg, coupling_model="full")  # saved before the neighbours' model
            f = cls(state["geometry.A"], state["geometry.order"], np.zeros((P, 3)),
                    cfg=cfg, readout=meta["readout"],
                    wavefront=meta["wavefront"], vis_center=np.zeros(3), frequency_hz=meta["frequency_hz"],
                    seed=meta["seed"], name=meta.get("name", "bg"), params=state,
                    scatterer_scale=meta.get("scatterer_scale", 1.0), init=meta.get("init"),
                    planes=state.get("geometry.planes"), scene_xml=meta.get("scene_xml"),
                    max_depth=meta.get("max_depth"), min_segment=meta.get("min_segment"))
        except KeyError as e:
            raise RunError(f"CoherentGaussianField state lacks {e}") from None
        if meta.get("frozen"):
            f.freeze()
        return f

    def load_state_dict(self, state: dict) -> None:
        """Load parameters; a state whose image maps differ (an unknown-room field that grew by
        :meth:`add_images`, e.g. a checkpoint of a resumed run) brings its geometry along."""
        if "geometry.A" in state:
            A = np.asarray(state["geometry.A"], np.float64).reshape(-1, 3, 3)
            order = np.asarray(state["geometry.order"], np.int64).reshape(-1)
            if A.shape != self.A.shape or not np.allclose(A, self.A):
                if self._vis is not None:
                    raise RunError("CoherentGaussianField: a state with other image maps cannot load into a field "
                                   "with ray-cast visibility")
                self._set_geometry(A, order)
        super().load_state_dict(state)

    def _set_geometry(self, A: np.ndarray, order: np.ndarray) -> None:
        self.A = np.asarray(A, np.float64).reshape(-1, 3, 3)
        self.order = np.asarray(order, np.int64).reshape(-1)
        self.num_images = len(self.A)
        self._A_cols = _columns(self.A.reshape(-1, 9))

    # ---- growth: sources the loss asks for (rfmitsuba.train.pursuit) -------------------------
    def single_planes(self) -> tuple[np.ndarray, np.ndarray]:
        """The field's single reflections across axis-aligned planes, where they are now.

        Returns:
            (axis int64 [n] (0, 1, 2 = x, y, z), offset float64 [n] [m]): the planes
            ``coord_axis = offset`` whose mirror images the learned offsets draw.
        """
        off = np.asarray(self.params["img_offset"].numpy(), np.float64).reshape(-1, 3)
        axis, offset = [], []
        for i, (A, o) in enumerate(zip(self.A, self.order)):
            d = np.diag(A)
            if o == 1 and np.allclose(A, np.diag(d)) and (d < 0).sum() == 1:
                a = int(np.argmin(d))
                axis.append(a)
                offset.append(off[i, a] / 2.0)
        return np.asarray(axis, np.int64), np.asarray(offset, np.float64)

    def image_gain_gradients(self, views: Views, grad_re: np.ndarray, grad_im: np.ndarray, A: np.ndarray,
                             b: np.ndarray) -> np.ndarray:
        """How the loss would change with the gain of candidate images not in the field: the
        gradient of ``sum Re(conj(G) h)`` with respect to each candidate's (re, im) gain, ``G`` the
        loss's gradient at this field's calibrated channels and ``h`` the candidate's channel
        (the field's calibration, array pose and wavefront, no visibility window). Linear in the
        gain, so the value is the gradient at zero gain: the candidate that would lower the loss
        most if added.

        Args:
            views: B views; grad_re, grad_im: float [B*16] the loss's gradient at the channels.
            A, b: float [C, 3, 3] maps and [C, 3] offsets [m] of the candidates (``s = A y + b``).
        Returns:
            float64 [C, 2] (d/d re, d/d im).
        """
        import drjit as dr

        A = np.asarray(A, np.float64).reshape(-1, 3, 3)
        C = len(A)
        cfg = dataclasses.replace(self.cfg, vis_grid=(0, 0, 0))
        cand = type(self)(A, np.ones(C, np.int64), np.zeros((0, 3)), cfg=cfg, readout=self.readout,
                          wavefront=self.wavefront, vis_center=np.zeros(3), frequency_hz=self.frequency_hz)
        cand.params["img_offset"] = B.Float(np.asarray(b, np.float32).ravel())
        cand.params["vis_log_extent"] = dr.full(B.Float, 30.0, C)        # a window of 1 everywhere
        cand.params["cal"] = dr.detach(self.params["cal"])
        cand.params["pose"] = dr.detach(self.params["pose"])
        if "coupling" in self.params:
            cand.params["coupling"] = dr.detach(self.params["coupling"])
        amp = B.Float(np.tile([1.0, 0.0], C).astype(np.float32))
        dr.enable_grad(amp)
        cand.params["img_amp"] = amp
        hr, hi = cand.channels(views)
        gr = B.Float(np.asarray(grad_re, np.float32).ravel())
        gi = B.Float(np.asarray(grad_im, np.float32).ravel())
        dr.backward(dr.sum(hr * gr + hi * gi))
        return np.asarray(dr.grad(amp).numpy(), np.float64).reshape(C, 2)

    def add_images(self, A: np.ndarray, b: np.ndarray, order: np.ndarray, *, vis_center: np.ndarray) -> dict:
        """Append images with zero gain (the loss is unchanged at insertion), the initial extent
        ``init_extent`` about ``vis_center`` [m] and a neutral visibility grid. Unknown room only.

        Args:
            A, b, order: float [n, 3, 3] maps, [n, 3] offsets [m], int [n] reflections.
            vis_center: float [3] the new windows' centre [m].
        Returns:
            name -> int64 [old size]: where each parameter's old values sit in its new array
            (the optimizer's moments move with them; the new entries start at zero).
        """
        if self._vis is not None:
            raise ConfigError("CoherentGaussianField.add_images: a known room's images come from its ray casts")
        A = np.asarray(A, np.float64).reshape(-1, 3, 3)
        b = np.asarray(b, np.float64).reshape(-1, 3)
        order = np.asarray(order, np.int64).reshape(-1)
        n, S, P = len(A), self.num_images, self.num_scatterers
        if not (len(b) == len(order) == n) or not np.isfinite(b).all():
            raise ConfigError(f"add_images: {n} maps need {n} finite offsets and orders, got {b.shape}, {order.shape}")
        _check_orthogonal(A, "add_images")
        old = {k: np.asarray(v.numpy(), np.float64) for k, v in self.params.items()}
        src = np.concatenate([np.arange(S), np.arange(S, S + P) + n])          # old source -> new source
        per_source = {"vis_center": 3, "vis_log_extent": 1, "vis_grid": self.grid_cells}
        new_rows = {"vis_center": np.tile(np.asarray(vis_center, np.float64).reshape(3), n),
                    "vis_log_extent": np.full(n, np.log(self.cfg.init_extent)),
                    "vis_grid": np.zeros(n * self.grid_cells)}
        out, where = {}, {}
        for k, v in old.items():
            if k == "img_offset":
                out[k], where[k] = np.concatenate([v, b.ravel()]), np.arange(len(v))
            elif k == "img_amp":
                out[k], where[k] = np.concatenate([v, np.zeros(2 * n)]), np.arange(len(v))
            elif k in per_source and per_source[k]:
                w = per_source[k]
                pos = (src[:, None] * w + np.arange(w)[None]).ravel()
                arr = np.zeros((S + P + n) * w)
                arr[pos] = v
                arr[(np.arange(S, S + n)[:, None] * w + np.arange(w)[None]).ravel()] = new_rows[k]
                out[k], where[k] = arr, pos
            else:
                out[k], where[k] = v, np.arange(len(v))
        self._set_geometry(np.concatenate([self.A, A]), np.concatenate([self.order, order]))
        for k, v in out.items():
            self.params[k] = B.Float(v.astype(np.float32))
        return where

    # ---- evaluation ------------------------------------------------------------------------
    def channels(self, views: Views, *, weight=None) -> tuple:
        """Calibrated channels at the 16 elements for ``views``: (re, im) ``Float`` [B*16],
        differentiable in every parameter. Raises ConfigError on non-finite positions.

        ``weight``: None, or ``(group, lanes, s) -> Float`` per lane (``group`` "img" or "sc",
        ``lanes`` of :meth:`_lanes`, ``s`` the source point [3 ``Float``]) that multiplies each
        source's term (e.g. the person's blockage, :mod:`rfmitsuba.models.coherent_gaussians_person`)."""
        prep = self._prepare(views)
        hr, hi = self._paths(prep, weight=weight)
        return self._calibrate(prep, hr, hi)

    # ---- a render split in its host part and its device part (recorded once, replayed) -------
    #: :meth:`channels` is :meth:`prepare` (host: checks, cached ray casts, uploads) then
    #: :meth:`channels_prepared` (Dr.Jit only), so :mod:`rfmitsuba.train.frozen_step` can record
    #: the device part with the read-out, loss and backward pass once and replay it every step
    freezable = True

    def prepare(self, views: Views) -> dict:
        """The host part of :meth:`channels` (:meth:`_prepare`): positions checked, ray casts
        looked up, the views' columns uploaded."""
        return self._prepare(views)

    def channels_prepared(self, prep: dict) -> tuple:
        """The device part of :meth:`channels` from :meth:`prepare`'s ``prep``: (re, im) ``Float`` [B*16]."""
        return self._calibrate(prep, *self._paths(prep))

    def device_inputs(self, prep: dict) -> list:
        """Every Dr.Jit array :meth:`channels_prepared` and :meth:`penalty` read: the field's
        parameters and image maps and ``prep``'s columns. One missing here fails the recording,
        and may abort the process (:mod:`rfmitsuba.train.frozen_step`)."""
        return _jit_arrays(self.params) + list(self._A_cols) + list(self._coupling_lanes) + _jit_arrays(prep)

    def structure(self, prep: dict) -> tuple:
        """What :meth:`channels_prepared` takes from Python rather than from arrays (counts, which
        parts exist, the read-out), hashable: a recording of it is valid while this is unchanged."""
        return (self.num_images, self.num_scatterers, int(prep["nb"]), float(prep["kw"]), tuple(sorted(prep)),
                tuple(sorted(self.params)), self.readout, self.wavefront, self.grid_cells, repr(self.cfg))

    def read_out_channels(self, h_re, h_im, *, frequency_hz: float, height: int, width: int,
                          normalize: bool = True):
        """The family's read-out of summed channels (:func:`read_out` with this field's ``readout``):
        ``TensorXf`` [B, height, width]."""
        return read_out(h_re, h_im, readout=self.readout, frequency_hz=frequency_hz, height=height, width=width,
                        normalize=normalize)

    def read_out_inputs(self, *, frequency_hz: float, height: int, width: int) -> list:
        """The Dr.Jit arrays :meth:`read_out_channels` reads: the beamformer weights."""
        return list(bartlett_weights(frequency_hz=frequency_hz, height=height, width=width))

    # ---- the pieces of :meth:`channels`, shared with the Stage-2 person field ----------------
    def _prepare(self, views: Views) -> dict:
        """Host-side checks and device columns of ``views``: {"nb", "x", "y", "q" (float64 [B, 3]),
        "cols" (name -> 3 ``Float`` columns of x, y, q and the world element offsets e), "kw" (k [rad/m])}."""
        x = np.asarray(views.view_pos, np.float64).reshape(-1, 3)
        y = np.asarray(views.transmitter, np.float64).reshape(-1, 3)
        q = np.asarray(views.antenna_pos, np.float64).reshape(-1, 3)
        if not (x.shape == y.shape == q.shape) or not (np.isfinite(x).all() and np.isfinite(y).all()
                                                       and np.isfinite(q).all()):
            raise ConfigError(f"views need finite positions of one shape [B, 3], got {x.shape}, {y.shape}, {q.shape}")
        R = np.eye(3) if views.rx_to_world is None else np.asarray(views.rx_to_world, np.float64).reshape(3, 3)
        e_world = antenna.element_positions(self.frequency_hz) @ R.T          # [16, 3] world offsets
        kw = 2.0 * np.pi / antenna.wavelength(self.frequency_hz)
        out = {"nb": len(x), "x": x, "y": y, "q": q, "kw": kw,
               "cols": {"x": _columns(x), "y": _columns(y), "q": _columns(q), "e": _columns(e_world)}}
        if self._vis is not None:
            tr = self.path_trace(x, y)
            out["vis"] = tuple(B.Float(np.asarray(v, np.float32).ravel())
                               for v in (tr.exists, tr.clear, tr.cos_incidence - 0.5))
            if self.cfg.material_through:
                out["cross"] = B.Float(np.ascontiguousarray(tr.crossings, np.float32).ravel())
        return out

    def visibility(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ray-cast (exists, clear) bool [B, S] and mean incidence ``|cos|`` float [B, S] of every
        image path for array centres ``x`` and transmitters ``y`` (float [B, 3] m)
        (:class:`~rfmitsuba.sim.visibility.PathTrace`); all True and 1 without a known room."""
        x = np.asarray(x, np.float64).reshape(-1, 3)
        if self._vis is None:
            full = np.ones((len(x), self.num_images), bool)
            return full, full, np.ones(full.shape)
        return tuple(self.path_trace(x, y))[:3]

    def path_trace(self, x: np.ndarray, y: np.ndarray):
        """The :class:`~rfmitsuba.sim.visibility.PathTrace` of every image path for array centres
        ``x`` and transmitters ``y`` (float [B, 3] m; known room with ray casts only), blocked
        paths deeper than :attr:`max_depth` or with a segment within :attr:`min_segment` marked
        absent. Views already cast are remembered (training revisits the same positions), up to
        :data:`VIS_CACHE_VIEWS` of them: positions seen once (jittered training views,
        :mod:`rfmitsuba.train.jitter`) are cast every time once the cache is full."""
        from ..sim.visibility import PathTrace

        x = np.asarray(x, np.float64).reshape(-1, 3)
        y = np.asarray(y, np.float64).reshape(-1, 3)
        keys = [np.concatenate([a, b]).tobytes() for a, b in zip(x, y)]
        missing: dict = {}                               # key -> first row index, each uncast view once
        for i, k in enumerate(keys):
            if k not in self._vis_cache:
                missing.setdefault(k, i)
        if missing:
            idx = np.array(list(missing.values()))
            tr = self._vis.trace(x[idx], y[idx], self.planes, self.order)
            fresh = {k: tuple(a[j] for a in tr) for j, k in enumerate(missing)}
            for k, row in fresh.items():
                if len(self._vis_cache) >= VIS_CACHE_VIEWS:
                    break
                self._vis_cache[k] = row
        else:
            fresh = {}
        rows = [fresh[k] if k in fresh else self._vis_cache[k] for k in keys]
        tr = PathTrace(*(np.stack([r[i] for r in rows]) for i in range(len(PathTrace._fields))))
        return tr.within_depth(self.order, self.max_depth).without_short_segments(self.min_segment)

    def _lanes(self, prep: dict, K: int) -> dict:
        """Per (view, element, source) lanes ``(b * 16 + m) * K + k`` of ``K`` sources: source ``k``,
        view ``b``, element ``m`` (``UInt32``); the view's array centre ``x``, transmitter ``y`` and
        moving device ``q``; the posed element offset ``r``, array centre ``cen`` and element
        position ``el`` (each 3 ``Float``)."""
        import drjit as dr

        nb, M = prep["nb"], antenna.NUM_ELEMENTS
        cols = prep["cols"]
        lane = dr.arange(B.UInt32, nb * M * K)
        k = lane % dr.opaque(B.UInt32, K)
        bm = lane // dr.opaque(B.UInt32, K)
        m = bm % M
        b = bm // M
        xb = [dr.gather(B.Float, c, b) for c in cols["x"]]
        yb = [dr.gather(B.Float, c, b) for c in cols["y"]]
        qb = [dr.gather(B.Float, c, b) for c in cols["q"]]
        # the pose read per lane: its adjoint is then a scatter-add inside the backward kernel,
        # not a separate reduction (and re-run of this kernel) per component
        pose = self.params["pose"]
        w0, w1, w2, t0, t1, t2 = (dr.gather(B.Float, pose, dr.full(B.UInt32, i, nb * M * K)) for i in range(6))
        r = _rodrigues(w0, w1, w2, *(dr.gather(B.Float, c, m) for c in cols["e"]))
        cen = [xb[0] + t0, xb[1] + t1, xb[2] + t2]
        el = [cen[i] + r[i] for i in range(3)]
        return {"K": K, "k": k, "b": b, "m": m, "x": xb, "y": yb, "q": qb, "r": r, "cen": cen, "el": el}

    def _sources(self, prep: dict, ln: dict, group: str) -> tuple:
        """The background's sources of ``group`` ("img" or "sc") on lanes ``ln``: (source point s
        [3 Float] m, first-leg length ``lead`` [m] (0 for an image), spreading factor besides the
        last leg ``spread0``, gain (re, im), visibility window ``w(q)``)."""
        import drjit as dr

        k, yb, qb = ln["k"], ln["y"], ln["q"]
        gi_ = k if group == "img" else k + self.num_images                 # index of visibility params
        if group == "img":
            Ak = [dr.gather(B.Float, c, k) for c in self._A_cols]
            off = self.params["img_offset"]
            s = [Ak[3 * i] * yb[0] + Ak[3 * i + 1] * yb[1] + Ak[3 * i + 2] * yb[2]
                 + dr.gather(B.Float, off, 3 * k + i) for i in range(3)]
            amp = self.params["img_amp"]
            lead = 0.0
            spread0 = 1.0
            ar, ai = dr.gather(B.Float, amp, 2 * k), dr.gather(B.Float, amp, 2 * k + 1)
            if "vis" in prep:   # ray-cast: absent paths drop out, blocked ones take the through gain
                lane = ln["b"] * self.num_images + k
                ex, cl, c = (dr.gather(B.Float, v, lane) for v in prep["vis"])
                th, sl = self.params["img_through"], self.params["img_slope"]
                tr, ti = dr.gather(B.Float, th, 2 * k), dr.gather(B.Float, th, 2 * k + 1)
                ar = ar + c * dr.gather(B.Float, sl, 2 * k)
                ai = ai + c * dr.gather(B.Float, sl, 2 * k + 1)
                if "cross" in prep:  # the clear gain through every crossed surface: g * exp(sum n (rho + j phi))
                    G = len(self._vis.group_names)
                    mt = self.params["mat_through"]
                    lr = li = 0.0
                    for g in range(G):
                        n = dr.gather(B.Float, prep["cross"], lane * G + g)
                        lr = lr + n * dr.gather(B.Float, mt, dr.full(B.UInt32, 2 * g, dr.width(lane)))
                        li = li + n * dr.gather(B.Float, mt, dr.full(B.UInt32, 2 * g + 1, dr.width(lane)))
                    mag = dr.exp(lr)
                    Tr, Ti = mag * dr.cos(li), mag * dr.sin(li)
                    tr, ti = tr + ar * Tr - ai * Ti, ti + ar * Ti + ai * Tr
                ar, ai = cl * ar + (ex - cl) * tr, cl * ai + (ex - cl) * ti
        else:
            pos = self.params["sc_pos"]
            s = [dr.gather(B.Float, pos, 3 * k + i) for i in range(3)]
            amp = self.params["sc_amp"]
            lead = dr.sqrt(sum((yb[i] - s[i]) ** 2 for i in range(3)) + 1e-12)
            spread0 = lead
            ar, ai = dr.gather(B.Float, amp, 2 * k), dr.gather(B.Float, amp, 2 * k + 1)
        vc = self.params["vis_center"]
        d2 = sum((qb[i] - dr.gather(B.Float, vc, 3 * gi_ + i)) ** 2 for i in range(3))
        ext = dr.exp(dr.gather(B.Float, self.params["vis_log_extent"], gi_))
        win = dr.exp(-0.5 * d2 / (ext * ext))
        if self.grid_cells:
            win = win * self._grid_factor(qb, gi_)
        return s, lead, spread0, ar, ai, win

    def _grid_factor(self, qb, gi_):
        """``2 sigmoid(v(q))`` of each lane's source ``gi_`` (UInt32) at the moving device ``qb``
        (3 ``Float`` [m]): ``v`` trilinear in the source's ``vis_grid`` cells over ``vis_grid_box``,
        ``q`` clamped into the box."""
        import drjit as dr

        n = tuple(int(c) for c in self.cfg.vis_grid)
        box, g = self.params["vis_grid_box"], self.params["vis_grid"]
        nl = dr.width(gi_)
        cell, frac = [], []
        for i in range(3):
            lo = dr.gather(B.Float, box, dr.full(B.UInt32, i, nl))
            hi = dr.gather(B.Float, box, dr.full(B.UInt32, 3 + i, nl))
            t = dr.clip((qb[i] - lo) / (hi - lo), 0.0, 1.0) * (n[i] - 1)
            c0 = dr.minimum(B.UInt32(dr.floor(t)), max(n[i] - 2, 0))
            cell.append(c0)
            frac.append(t - B.Float(c0))
        v = 0.0
        for corner in range(8):
            d = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
            if any(d[i] and n[i] < 2 for i in range(3)):
                continue
            w = 1.0
            for i in range(3):
                w = w * (frac[i] if d[i] else 1.0 - frac[i])
            idx = ((cell[0] + d[0]) * n[1] + cell[1] + d[1]) * n[2] + cell[2] + d[2]
            v = v + w * dr.gather(B.Float, g, gi_ * self.grid_cells + idx)
        return 2.0 / (1.0 + dr.exp(-v))

    def _propagate(self, prep: dict, ln: dict, s, lead, spread0, ar, ai, win) -> tuple:
        """Sum over the lanes' sources of ``(ar + j ai) * win * exp(-j k (L + lead)) / (L spread0)``,
        ``L`` the last leg from ``s`` to the element (``wavefront``): uncalibrated (re, im) ``Float`` [B*16]."""
        import drjit as dr

        kw, r, cen, el = prep["kw"], ln["r"], ln["cen"], ln["el"]
        if self.wavefront == "spherical":
            L = dr.sqrt(sum((s[i] - el[i]) ** 2 for i in range(3)) + 1e-12)
            phase = -kw * (L + lead)
        else:
            L = dr.sqrt(sum((s[i] - cen[i]) ** 2 for i in range(3)) + 1e-12)
            u = [(s[i] - cen[i]) / L for i in range(3)]
            phase = kw * (r[0] * u[0] + r[1] * u[1] + r[2] * u[2]) - kw * (L + lead)
        w = win / (L * spread0)
        sn, c = B.sincos_phase(phase)
        vr, vi = w * (ar * c - ai * sn), w * (ar * sn + ai * c)
        dr.eval(vr, vi)                                   # one kernel for both parts
        return dr.block_sum(vr, ln["K"]), dr.block_sum(vi, ln["K"])

    def _paths(self, prep: dict, *, weight=None) -> tuple:
        """Uncalibrated channels of every source (images, then scatterers), each term times
        ``weight(group, lanes, s)`` when given: (re, im) ``Float`` [B*16]."""
        hr = hi = None
        for group, K in (("img", self.num_images), ("sc", self.num_scatterers)):
            if K == 0:
                continue
            ln = self._lanes(prep, K)
            s, lead, spread0, ar, ai, win = self._sources(prep, ln, group)
            if weight is not None:
                win = win * weight(group, ln, s)
            cr, ci = self._propagate(prep, ln, s, lead, spread0, ar, ai, win)
            hr, hi = (cr, ci) if hr is None else (hr + cr, hi + ci)
        return hr, hi

    def _calibrate(self, prep: dict, hr, hi) -> tuple:
        """The per-element calibration ``cal_m`` applied to channels (re, im) ``Float`` [B*16],
        after the mutual coupling ``h + K h`` where ``coupling`` is on."""
        import drjit as dr

        M = antenna.NUM_ELEMENTS
        if "coupling" in self.params:
            # lane (b * 16 + m) * 16 + n: K[m, n] h_n[b], summed over n; K[m, n] is the parameter
            # pair coupling_index(model)[m, n] (none: 0)
            lane = dr.arange(B.UInt32, prep["nb"] * M * M)
            mn = lane % (M * M)                                   # entry (m, n) of K
            src = (lane // (M * M)) * M + mn % M                  # channel n of view b
            pidx = dr.gather(B.UInt32, self._coupling_lanes[0], mn)
            on = dr.gather(B.Float, self._coupling_lanes[1], mn)
            kr = dr.gather(B.Float, self.params["coupling"], 2 * pidx) * on
            ki = dr.gather(B.Float, self.params["coupling"], 2 * pidx + 1) * on
            gr, gi = dr.gather(B.Float, hr, src), dr.gather(B.Float, hi, src)
            hr, hi = hr + dr.block_sum(kr * gr - ki * gi, M), hi + dr.block_sum(kr * gi + ki * gr, M)
        m16 = dr.arange(B.UInt32, prep["nb"] * M) % M
        cal = self.params["cal"]
        calr, cali = dr.gather(B.Float, cal, 2 * m16), dr.gather(B.Float, cal, 2 * m16 + 1)
        return hr * calr - hi * cali, hr * cali + hi * calr

    @classmethod
    def render_family(cls, fields: list, views: Views, *, height: int, width: int, normalize: bool):
        """PAS of the fields' summed channels through one Bartlett read-out (phase-only when the
        first field's ``readout`` says so): ``TensorXf`` [B, height, width]."""
        hr, hi = summed_channels(fields, views)
        return read_out(hr, hi, readout=fields[0].readout, frequency_hz=views.frequency_hz, height=height,
                        width=width, normalize=normalize)

    # ---- export ------------------------------------------------------------------------------
    def source_points(self, y: np.ndarray) -> np.ndarray:
        """Where the sources are for a transmitter at ``y`` (float [3] m): float64 [S+P, 3] m."""
        off = np.asarray(self.params["img_offset"].numpy(), np.float64).reshape(-1, 3)
        img = np.einsum("sij,j->si", self.A, np.asarray(y, np.float64)) + off
        return np.concatenate([img, np.asarray(self.params["sc_pos"].numpy(), np.float64).reshape(-1, 3)])

    def magnitudes(self) -> np.ndarray:
        """|gain| of every source (images then scatterers): float64 [S+P]."""
        a = np.concatenate([np.asarray(self.params["img_amp"].numpy(), np.float64).reshape(-1, 2),
                            np.asarray(self.params["sc_amp"].numpy(), np.float64).reshape(-1, 2)])
        return np.hypot(a[:, 0], a[:, 1])

    def export_ply(self, folder: str | Path, *, views: Views) -> list[Path]:
        """``sources.ply``: the sources for the first view's transmitter, as small Gaussians whose
        opacity is the gain's magnitude relative to the largest."""
        return [_write_points_ply(Path(folder) / "sources.ply", self.source_points(views.transmitter[0]),
                                  self.magnitudes())]
