"""The Stage-1 initial coherent Gaussian field from a dataset (:func:`initial_field`): the room's image
sources or the data scan, scatterers, and the line-of-sight frame and calibration fits."""
from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np

from ...core import backend as B
from ...core.errors import ConfigError
from ...rf.calibration_fit import los_calibration_fit
from ...rf.frame_fit import los_frame_fit
from ...rf.images import ImageMaps, scene_image_maps
from .geometry import (
    DENSE_VIS_GRID,
    compose_images,
    default_vis_grid,
    position_spread_deg,
    room_box_planes,
    scan_planes,
    spreads_wide,
    uses_pursuit,
)
from .scan import scan


#: most training spectra the initial scan reads (evenly spread over the training samples)
SCAN_SAMPLES = 1024

#: a frame fit gaining at least this much line-of-sight correlation over the stated frame warns
#: (a right frame gained 0.002 on NeRF2-like data, one 25 / 45 degrees off 0.023 / 0.66)
FRAME_WARN_GAIN = 0.05

def initial_field(cfg, data, *, scene_xml: Path | None, field_class: type, extra_inputs: int = 0,
                  name: str = "bg"):
    """The Stage-1 initial field: the room's image sources (known room) or the data scan
    (unknown room), plus scanned scatterers; read-out and wavefront resolved from the dataset.

    Args:
        cfg: the :class:`~rfmitsuba.train.config.TrainConfig` (``coherent_gaussians``, ``seed``).
        data: the :class:`~rfmitsuba.data.views.TrainData`; only its training positions and
            PAS are read.
        scene_xml: the room's XML, or None when it is unknown.
        extra_inputs: must be 0 (this field takes no per-view network inputs).
        field_class: :class:`~rfmitsuba.models.coherent_gaussians.field.CoherentGaussianField` or a
            subclass, the field to build; name: the field's name.
    Returns:
        the initial field (``field_class``).
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
    decided = []   # (option, value, reason) of every "auto" decided here (rfmitsuba.train.resolve)
    key = "coherent_gaussians."
    if c.init == "auto":
        decided.append((key + "init", init, "the dataset names its room: the room's image sources" if init == "room"
                        else "no room is named: the directional scan of the training spectra"))
    if c.readout == "auto":
        decided.append((key + "readout", readout, f"the dataset's read-out ({'measured' if measured else 'simulated'} "
                        "folder)"))
    if c.wavefront == "auto":
        decided.append((key + "wavefront", wavefront, "measured folder: exact path lengths to each element"
                        if measured else "simulated data, whose truth uses the plane-wave rule"))
    if c.coupling == "auto":
        decided.append((key + "coupling", readout == "phase_only", "phase-only spectra: a real array's elements "
                        "couple" if readout == "phase_only" else "amplitude read-out: synthetic arrays do not couple"))
    if c.vis_grid == "auto":
        n_pos = len(np.unique(q, axis=0))
        grid = default_vis_grid(init=init, num_positions=n_pos)
        c = dataclasses.replace(c, vis_grid=grid)
        which = "the finer grid where the data are dense" if grid == DENSE_VIS_GRID else "the default grid"
        decided.append((key + "vis_grid", grid, f"{'unknown' if init == 'data' else 'known'} room, {n_pos} distinct "
                        f"training positions: {which}"))
    if init == "data" and (c.images == "auto" or c.pursuit == "auto"):
        fixed = y if data.task == "rx" else x
        spread = position_spread_deg(fixed, q)
        where = f"the positions spread {spread:.1f} degrees seen from the fixed device"
        if c.images == "auto":
            decided.append((key + "images", scan_planes(c, data), where + (" (within the array's beam: the scan "
                            "finds the planes)" if not spreads_wide(data) else " (wider than half the array's beam: "
                            "the pursuit finds them)")))
        if c.pursuit == "auto":   # decided again where the pursuit runs (rfmitsuba.train.pursuit), by the same rule
            decided.append((key + "pursuit", "on" if uses_pursuit(c, data) else "off", where))
    depth = getattr(data, "max_depth", None) if c.depth_limit else None   # the data's tracer depth
    min_seg = getattr(data, "min_segment", None) if c.segment_limit else None   # and its shortest segment
    # the scan reads at most SCAN_SAMPLES training spectra, evenly spread (a dataset of many
    # states, e.g. 720 positions x 30 walk states, would otherwise load 2.8 GB of PAS)
    scan_idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), SCAN_SAMPLES)).astype(np.int64))]
    xs, ys, _ = data.positions(scan_idx)
    pas = data.pas(scan_idx, d=2)
    if init == "room":
        from ...sim.geometry import RoomGeometry

        maps = scene_image_maps(RoomGeometry.from_xml(scene_xml), room_order=c.room_order,
                                furniture_order=c.furniture_order, min_face_area=c.min_face_area,
                                distinct_paths=c.ray_visibility, furniture_planes="faces")
        if c.ray_visibility and c.prune_unseen:
            # parsimony: an image whose path exists at no training position has no gradient
            from ...sim.visibility import SpecularVisibility

            xy = np.unique(np.concatenate([x, y], axis=1), axis=0)      # each geometry once
            tr = SpecularVisibility.from_xml(scene_xml).trace(xy[:, :3], xy[:, 3:], maps.planes, maps.order)
            seen = tr.within_depth(maps.order, depth).without_short_segments(min_seg).exists.any(0)
            seen[maps.order == 0] = True
            maps = ImageMaps(A=maps.A[seen], b=maps.b[seen], order=maps.order[seen],
                             label=[lb for lb, k in zip(maps.label, seen) if k], planes=maps.planes[seen])
        A, order = maps.A, maps.order
        b0 = maps.b
    stated = np.eye(3) if data.rx_to_world is None else np.asarray(data.rx_to_world, np.float64)
    frame, report = stated, {}   # the frame fit only reports: starting from it did not help (lab notes)
    search = c.frame_search if c.frame_search != "auto" else ("report" if measured and init == "data" else "off")
    if c.frame_search == "auto":
        decided.append((key + "frame_search", search, "a measured folder in an unknown room: check the stated "
                        "gateway frame" if search == "report" else "not a measured folder in an unknown room"))
    if search != "off":
        fit = los_frame_fit(pas, xs, ys, rx_to_world=stated, frequency_hz=data.frequency_hz)
        if fit.gain >= FRAME_WARN_GAIN:
            warnings.warn(f"{data.path}: the stated array frame draws the line of sight worse than a frame "
                          f"{fit.angle_deg:.0f} degrees away (correlation {fit.stated_score:.2f} against "
                          f"{fit.score:.2f}); check the gateway orientation", stacklevel=2)
        report["frame_fit"] = {"angle_deg": fit.angle_deg, "rotvec_rad": fit.rotvec.tolist(), "score": fit.score,
                               "stated_score": fit.stated_score}
    cal_search = c.calibration_search if c.calibration_search != "auto" else \
        ("apply" if readout == "phase_only" and init == "data" and c.calibrate else "off")
    if c.calibration_search == "auto":
        decided.append((key + "calibration_search", cal_search, "phase-only spectra in an unknown room: search the "
                        "elements' phase offsets" if cal_search == "apply" else "not phase-only spectra of an unknown "
                        "room"))
    if cal_search == "apply":
        cal_fit = los_calibration_fit(pas, xs, ys, rx_to_world=frame, frequency_hz=data.frequency_hz,
                                      seed=cfg.seed)
        report["calibration_fit"] = {"applied": bool(cal_fit.gain >= c.calibration_min_gain),
                                     "phase_deg": np.degrees(cal_fit.phase_rad).tolist(),
                                     "score": cal_fit.score, "stated_score": cal_fit.stated_score,
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
    f = field_class(
        A, order, sc, cfg=c, readout=readout, wavefront=wavefront, vis_center=q.mean(0),
        frequency_hz=data.frequency_hz, seed=cfg.seed, name=name, scatterer_scale=scale, init=init,
        planes=maps.planes if ray else None, scene_xml=scene_xml if ray else None,
        max_depth=depth, min_segment=min_seg)
    f.params["img_offset"] = B.Float(np.asarray(b0, np.float32).ravel())
    f.init_report = report
    if "calibration_fit" in report:
        r = report["calibration_fit"]
        decided.append(("coherent_gaussians.calibration_fit", "applied" if r["applied"] else "not applied",
                        f"line-of-sight correlation {r['score']:.3f} with the fitted offsets against "
                        f"{r['stated_score']:.3f} without (applied from a gain of {r['min_gain']:g})"))
    if "frame_fit" in report:
        r = report["frame_fit"]
        decided.append(("coherent_gaussians.frame_fit", "reported", f"a frame {r['angle_deg']:.0f} degrees away draws "
                        f"the line of sight at {r['score']:.3f} against the stated frame's {r['stated_score']:.3f}"))
    f._decisions = decided
    if report.get("calibration_fit", {}).get("applied"):
        ph = np.radians(np.asarray(report["calibration_fit"]["phase_deg"], np.float64))
        f.params["cal"] = B.Float(np.stack([np.cos(ph), np.sin(ph)], 1).ravel().astype(np.float32))
    if f.grid_cells:   # the training positions' box, padded by 5% (at least 1 mm) each side
        pad = 0.05 * (q.max(0) - q.min(0)) + 1e-3
        f.params["vis_grid_box"] = B.Float(np.concatenate([q.min(0) - pad, q.max(0) + pad]).astype(np.float32))
    return f
