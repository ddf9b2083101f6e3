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
and diagonal neighbours: 42 complex coefficients), as a passive array's coupling does; a free
``K`` fits the training positions as well and extrapolates much worse. Phase comes from the exact path length to each element (``wavefront =
"spherical"``) or from the plane-wave rule about the array centre (``"plane"``, what Sionna's
synthetic array simulates). The array's pose is learned too: a small rotation (rotation vector
``omega`` [rad]) and a translation ``t`` [m] of the array relative to its stated pose.

The read-out is the amplitude Bartlett (:func:`rfmitsuba.rf.bartlett.bartlett`) or, for NeRF2's
measured spectra, its **phase-only** variant, which uses ``h_m / |h_m|``.

Initialisation (:func:`rfmitsuba.models.coherent_gaussians.build.initial_field`):

* **known room** (the dataset names a scene): the image maps of the room's planes
  (:func:`rfmitsuba.rf.images.scene_image_maps`: the room's box, and the planes of its furniture's,
  doors' and windows' faces), each plane sequence its own image. Whether each image's path
  exists for a view, and whether something stands across it, is decided by Mitsuba ray casts
  in the room's meshes (:class:`rfmitsuba.sim.visibility.SpecularVisibility`, the same JIT):
  a path that does not exist contributes nothing, a clear one with ``g = img_amp + img_slope *
  (c - 1/2)``, where ``c`` is the mean ``|cos|`` of the path's angles of incidence (a reflection
  coefficient changes with the angle: Fresnel), and a blocked one with ``img_through``:
  what passes through the obstacle, the blocked path's own gain. A ray tracer counts each
  crossing (Sionna RT refracts through each surface as a thin slab) as an interaction,
  so where the data were simulated with at most ``D`` interactions per path (the dataset's
  ``solver.max_depth``), a path with more reflections plus crossings than ``D`` does not
  exist (Sionna's default D = 3: the direct path through a wardrobe, two crossings, exists; a
  double reflection through it does not). A tracer also drops a path with a segment shorter
  than its threshold (Sionna RT: 1 cm, ``segment_limit``): a direct path that cuts 6 mm
  through a wardrobe's corner does not exist in such data. Images whose path exists at no
  training position are left out;
* **unknown room**: from the training PAS alone (:func:`.scan.scan`): matching pursuit on arrival directions. The direct path is explained first; then candidate images across axis-aligned
  planes (offsets every ``scan_step`` metres) and candidate scatterers on a grid are scored by
  the mean remaining PAS in the direction each would arrive from at the training views, and
  the best is kept and a beam around its directions masked, ``images`` times, then
  ``scatterers`` times. The planes' images are composed up to ``image_order`` reflections
  (:func:`.geometry.compose_images`). A known room gets scanned scatterers beside its image
  sources too. Where the moving device walks round the fixed one (a room, either task:
  :func:`.geometry.spreads_wide`) the scan keeps no plane, and during training the field grows one plane at a time where the
  loss asks for one (:mod:`rfmitsuba.train.pursuit`, ``pursuit``): the walls next to the fixed
  device too, whose images arrive within the array's beam of the direct path, which the scan
  cannot see.

Parameters (Dr.Jit ``Float``; name, size, unit, optimizer group):

=================  ============  ==========  ==========
``img_offset``     S*3           m           means
``img_amp``        S*2 (re, im)  1           amp
``img_through``    S*2           1           amp  (known room with ray-cast visibility only)
``img_slope``      S*2           1           amp  (known room with ray-cast visibility only)
``sc_pos``         P*3           m           means
``sc_amp``         P*2           1           amp
``vis_center``     (S+P)*3       m           means
``vis_log_extent`` S+P           log m       log_scales
``vis_grid``       (S+P)*G       1 (logit)   amp  (G = the grid's cells, ``vis_grid`` on only)
``vis_grid_box``   6             m           not trained: the grid's box (low corner, high corner)
``cal``            16*2          1           amp
``coupling``       C*2           1           amp  (``coupling`` on only: ``K``'s C = 42 neighbour pairs)
``pose``           6             rad, m      means in a known room (decays), else rotations (constant)
=================  ============  ==========  ==========

All are differentiable (tests/models/coherent_gaussians/test_coherent_gaussians_field.py checks each
against finite differences). State is plain NumPy (npz, no pickle).
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ...core import backend as B
from ...core.config import from_dict, to_dict
from ...core.errors import ConfigError, RunError
from ...rf import array as antenna
from ...rf.bartlett import weights as bartlett_weights
from ..base import FlatParameterField, Views, register
from .array import coupling_index, coupling_size, read_out, _rodrigues, summed_channels
from .config import CoherentGaussianConfig
from .geometry import _check_orthogonal, DENSE_VIS_GRID
from .._points import columns32, write_points_ply


FORMAT = "rfmitsuba-coherent-gaussians/1"

#: optimizer group of every parameter (rfmitsuba.train.trainer's learning rates)
LR_GROUPS = {"img_offset": "means", "img_amp": "amp", "img_through": "amp", "img_slope": "amp",
             "sc_pos": "means",
             "sc_amp": "amp", "vis_center": "means", "vis_log_extent": "log_scales", "vis_grid": "amp",
             "cal": "amp", "coupling": "amp", "pose": "means"}   # vis_grid_box is never trained: no group

#: least passes over the fitting positions a field with a grid of DENSE_VIS_GRID's cells or more
#: advises (CoherentGaussianField.epochs_advised)
DENSE_EPOCHS = 40.0

#: most views whose ray-cast path visibility a known-room field remembers (CoherentGaussianField.path_trace)
VIS_CACHE_VIEWS = 20000

#: spread of the jittered training views the field advises for phase-only (NeRF2) spectra
#: [carrier wavelengths]: 5.0 cm at NeRF2's 920 MHz (TrainConfig.jitter, rfmitsuba.train.jitter)
JITTER_PHASE_ONLY = 0.153

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

def _builtin_scene(xml: str) -> str:
    """The built-in scene a missing XML path names (a run saved in another checkout), else RunError."""
    from ...scenes import path as scene_path

    try:
        found = Path(scene_path(Path(xml).stem))
    except Exception:  # noqa: BLE001 - not a built-in scene's name
        found = None
    if found is None or found.name != Path(xml).name or not found.is_file():
        raise RunError(f"CoherentGaussianField: the room's XML {xml} (ray-cast visibility) is missing")
    return str(found)

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
    #: trains on 45 x 180 block means (``TrainConfig.downsample = "auto"``): its sources are points and
    #: its read-out the array's beam (about 26 degrees wide), so 2-degree pixels pin them as well as
    #: 1-degree ones at a quarter of the read-out's cost (docs/lab-notes/rooms.md)
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
        index = coupling_index().ravel()
        self._coupling_lanes = (B.UInt32(np.maximum(index, 0).astype(np.uint32)),
                                B.Float((index >= 0).astype(np.float32)))
        self.frequency_hz = float(frequency_hz)
        antenna.wavelength(self.frequency_hz)
        self.seed, self.name = int(seed), name
        #: how the field was initialised: "room" or "data" (None when not known)
        self.init = init
        self.init_report: dict = {}   # what initial_field decided (e.g. {"frame_fit": ...}), for the run summary
        self.frozen = False
        self.scatterer_scale = float(scatterer_scale)
        #: the fixed image maps as 9 device columns, uploaded once
        self._A_cols = columns32(self.A.reshape(-1, 9))
        sc = np.asarray(scatterers, np.float64).reshape(-1, 3)
        S, P = len(self.A), len(sc)
        self.num_images, self.num_scatterers = S, P
        #: cells of each source's visibility grid (0: none)
        self.grid_cells = 0 if cfg.vis_grid == "auto" else int(np.prod(cfg.vis_grid))
        self.planes = self.scene_xml = self._vis = None
        #: most reflections plus crossings of a path (None: no limit); see CoherentGaussianConfig.depth_limit
        self.max_depth = None if max_depth is None or not cfg.depth_limit else int(max_depth)
        #: shortest segment of a path [m] (None: no limit); see CoherentGaussianConfig.segment_limit
        self.min_segment = None if min_segment is None or not cfg.segment_limit else float(min_segment)
        if planes is not None and scene_xml is not None and cfg.ray_visibility:
            from ...sim.visibility import SpecularVisibility

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
                params["coupling"] = np.zeros(2 * coupling_size())
            if self._vis is not None:
                params["img_through"] = cfg.init_through * params["img_amp"]
                params["img_slope"] = np.zeros(S * 2)
            if self.grid_cells:   # zero logits: a factor of 1; the box until initial_field sets it
                params["vis_grid"] = np.zeros((S + P) * self.grid_cells)
                c0 = np.asarray(vis_center, np.float64).reshape(3)
                params["vis_grid_box"] = np.concatenate([c0 - 1.0, c0 + 1.0])
        self.params: dict = {}
        self.load_state_dict(params)

    # ---- construction ----------------------------------------------------------------------
    @classmethod
    def for_training(cls, cfg, data, *, scene_xml: Path | None, rng: np.random.Generator | None = None,
                     extra_inputs: int = 0, name: str = "bg") -> "CoherentGaussianField":
        """The Stage-1 initial field (:func:`rfmitsuba.models.coherent_gaussians.build.initial_field`)."""
        from .build import initial_field

        return initial_field(cfg, data, scene_xml=scene_xml, extra_inputs=extra_inputs, name=name, field_class=cls)

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
        (docs/lab-notes/nerf2like.md)."""
        searched = self.init_report.get("calibration_fit", {}).get("applied")
        return 2 if searched or self.cfg.coupling is True else 1

    @property
    def jitter_advised(self) -> float:
        """:data:`JITTER_PHASE_ONLY` wavelengths for phase-only (NeRF2) spectra, else 0
        (:mod:`rfmitsuba.train.jitter`). On the NeRF2-like spatial-block split (default folder,
        unknown room, validation slab held out) one field scored 0.886 +- 0.003 without and
        0.909 +- 0.006 with the jittered copies (3 and 10 seeds; nearest neighbour 0.911, IDW-3
        0.906), its spread over seeds a quarter of before; on the published random split 0.959
        +- 0.001 with them, 5 of 5 seeds above IDW-3, against 4 of 5 without (docs/lab-notes/nerf2like.md). Simulated rooms with the amplitude read-out were not measured with them, so
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

    def _sizes(self) -> dict:
        S, P = self.num_images, self.num_scatterers
        out = {"img_offset": S * 3, "img_amp": S * 2, "sc_pos": P * 3, "sc_amp": P * 2, "vis_center": (S + P) * 3,
               "vis_log_extent": S + P, "cal": 2 * antenna.NUM_ELEMENTS, "pose": 6}
        if self.cfg.coupling:
            out["coupling"] = 2 * coupling_size()
        if self.grid_cells:
            out["vis_grid"], out["vis_grid_box"] = (S + P) * self.grid_cells, 6
        if self._vis is not None:
            out["img_through"] = out["img_slope"] = S * 2
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
            cfg = from_dict(CoherentGaussianConfig, meta["config"], saved=True)
            if "coupling" not in state and cfg.coupling is not False:  # saved before (or without) coupling
                cfg = dataclasses.replace(cfg, coupling=False)
            if "coupling" in state and np.asarray(state["coupling"]).size != 2 * coupling_size():
                raise RunError(f"CoherentGaussianField state: a mutual coupling of "
                               f"{np.asarray(state['coupling']).size // 2} coefficients (the removed free coupling); "
                               f"this version learns the {coupling_size()} neighbour pairs: train the field again")
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
        self._A_cols = columns32(self.A.reshape(-1, 9))

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
               "cols": {"x": columns32(x), "y": columns32(y), "q": columns32(q), "e": columns32(e_world)}}
        if self._vis is not None:
            tr = self.path_trace(x, y)
            out["vis"] = tuple(B.Float(np.asarray(v, np.float32).ravel())
                               for v in (tr.exists, tr.clear, tr.cos_incidence - 0.5))
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
        from ...sim.visibility import PathTrace

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
        return [write_points_ply(Path(folder) / "sources.ply", self.source_points(views.transmitter[0]),
                                  self.magnitudes())]
