"""Localisation scored on the held-out walk: every Ours job of a run locates every held-out person
position, beside the fingerprint and centre floors (:func:`evaluate_locate`)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ...core.errors import ConfigError, DatasetError, RunError
from ...data.samples import SampleData
from .failures import failure_proxies
from .fingerprint_floor import fingerprint
from .model import job_folders, open_two_stage
from .query import REFERENCES
from .region import SearchRegion
from .search import locate


def _stats_cm(err_m: np.ndarray) -> dict:
    e = 100.0 * np.asarray(err_m, np.float64)
    return {"median_cm": float(np.median(e)), "p90_cm": float(np.percentile(e, 90)), "mean_cm": float(e.mean()),
            "n": int(len(e))}


def query_antennas(data: SampleData, *, antennas: str = "all", views: int = 0, seed: int = 0) -> np.ndarray:
    """The antenna indices of every evaluation query: the dataset's test antennas ("test") or all
    ("all"); ``views`` > 0 keeps that many of them (seeded, sorted). int64 [K]."""
    if antennas not in ("test", "all"):
        raise ConfigError(f"antennas must be 'test' or 'all', got {antennas!r}")
    a = (np.asarray(data.split.antenna_test, np.int64) if antennas == "test"
         else np.unique(np.asarray(data.antennas, np.int64)))
    if views < 0:
        raise ConfigError(f"views must be >= 0 (0 = all), got {views}")
    if views and views < len(a):
        a = np.sort(np.random.default_rng([seed, 11]).choice(a, views, replace=False))
    if len(a) == 0:
        raise DatasetError(f"{data.path}: no {antennas} antenna positions to take the queries at")
    return a


def evaluate_locate(run: str | Path, *, antennas: str = "all", views: int = 0, reference: str = "empty",
                    grid_m: float = 0.25, starts: int = 4, steps: int = 30, lr_m: float = 0.03, loss: str = "train",
                    downsample: int = 2, region: str = "walk", descent: str = "auto", quiet: bool = False) -> dict:
    """Locate every held-out walk position (the dataset's person test split) with every Ours job
    of ``run`` (:func:`job_folders`), beside the fingerprint and centre floors.

    Each query is one held-out person state seen at the antennas of :func:`query_antennas`
    (``antennas``, ``views``): the dataset's measured PAS there, the person's true feet position the
    answer. ``reference``: "empty" gives :func:`locate` the dataset's empty-room PAS at the same
    antennas (the model's change is fitted on top of them), "none" compares the model's PAS
    with the query as they are. The other options are :func:`locate`'s.

    Returns:
        a JSON-ready dict: "dataset", "jobs" (labels), "antennas" (indices), "states", "truth"
        [Q][3], "estimates" {"model": {label: [Q][3]}, "fingerprint": [Q][3], "walk_centroid": [3],
        "room_centre": [3] or None}, "errors_cm" (the same keys, [Q] per job and floor), "stats"
        {"model" (pooled over jobs), "model_per_job" {label: stats}, "fingerprint",
        "walk_centroid", "room_centre": {"median_cm", "p90_cm", "mean_cm", "n"}}, "proxies" [Q]
        (:func:`failure_proxies`), "settings", "descent", "time_s", "losses_evaluated".

    Raises:
        RunError: no two-stage job, or jobs trained on different datasets.
    """
    from ...core import progress

    if reference not in REFERENCES:
        raise ConfigError(f"reference must be one of {REFERENCES}, got {reference!r}")
    t0 = time.perf_counter()
    jobs = job_folders(run)
    models = []
    for label, jd in jobs:
        models.append((label, open_two_stage(jd)))
    paths = {str(Path(m.data.path).resolve()) for _, m in models}
    if len(paths) > 1:
        raise RunError(f"{run}: its jobs trained on different datasets ({', '.join(sorted(paths))})")
    data = models[0][1].data
    sp = data.split
    test_states = np.asarray(sp.person_test, np.int64) + 1
    train_states = np.asarray(sp.person_train, np.int64) + 1
    if len(test_states) == 0:
        raise DatasetError(f"{data.path}: no held-out walk positions (person test split) to locate")
    ant = query_antennas(data, antennas=antennas, views=views)
    lookup = {(int(s), int(a)): i for i, (s, a) in enumerate(zip(data.states, data.antennas))}
    search = {label: SearchRegion.of(m, region=region) for label, m in models}
    geometry = next(iter(search.values())).geometry
    truth, fp, proxies = [], [], []
    est = {label: [] for label, _ in models}
    diag = {label: [] for label, _ in models}
    used, evals = set(), 0
    with progress.bar(len(test_states) * (len(models) + 1), desc="locate", unit="query", quiet=quiet) as pb:
        for s in test_states:
            rows = np.array([lookup[(int(s), int(a))] for a in ant], np.int64)
            pas = data.pas(rows)
            empty = data.pas(np.array([lookup[(0, int(a))] for a in ant], np.int64)) if reference == "empty" else None
            feet = np.asarray(data.person_pos[rows[0]], np.float64)
            truth.append(feet)
            fp.append(fingerprint(data, pas, ant, states=train_states)["position"])
            x, y, q = data.positions(rows)
            proxies.append(failure_proxies(feet, x, y, geometry))
            pb.update(1)
            for label, m in models:
                r = locate(m, pas, q, grid_m=grid_m, starts=starts, steps=steps, lr_m=lr_m, loss=loss,
                           downsample=downsample, descent=descent, search=search[label], empty=empty,
                           score_at=feet[None])
                est[label].append(r["position"])
                diag[label].append({"estimate": r["loss"], "truth": float(r["losses_at"][0]),
                                    "no_person": r["loss_without_person"]})
                used.add(r["descent"])
                evals += r["losses_evaluated"]
                pb.update(1)
    truth = np.asarray(truth)
    x0, y0, _ = data.positions(np.array([lookup[(int(test_states[0]), int(a))] for a in ant], np.int64))
    centroid = np.concatenate([models[0][1].walk[:, :2].mean(0), [models[0][1].feet_z]])
    room_centre = None
    if geometry is not None:
        lo, hi = geometry.bounds
        room_centre = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), models[0][1].feet_z])

    def err(p):
        return np.hypot(*(np.asarray(p, np.float64).reshape(-1, 3)[:, :2] - truth[:, :2]).T)

    errors = {"model": {label: err(e) for label, e in est.items()}, "fingerprint": err(fp),
              "walk_centroid": err(np.tile(centroid, (len(truth), 1)))}
    if room_centre is not None:
        errors["room_centre"] = err(np.tile(room_centre, (len(truth), 1)))
    stats = {"model": _stats_cm(np.concatenate(list(errors["model"].values()))),
             "model_per_job": {label: _stats_cm(e) for label, e in errors["model"].items()},
             "fingerprint": _stats_cm(errors["fingerprint"]), "walk_centroid": _stats_cm(errors["walk_centroid"]),
             "room_centre": _stats_cm(errors["room_centre"]) if room_centre is not None else None}
    return {
        "run": str(run), "dataset": str(data.path), "task": data.task,
        "scene_xml": None if data.scene_xml is None else str(data.scene_xml), "jobs": [label for label, _ in models],
        "job_folders": [str(jd) for _, jd in jobs], "antennas": ant.tolist(), "states": test_states.tolist(),
        "truth": truth.tolist(),
        "estimates": {"model": {k: np.asarray(v).tolist() for k, v in est.items()},
                      "fingerprint": np.asarray(fp).tolist(), "walk_centroid": centroid.tolist(),
                      "room_centre": None if room_centre is None else room_centre.tolist()},
        "errors_cm": {"model": {k: (100 * v).tolist() for k, v in errors["model"].items()},
                      **{k: (100 * v).tolist() for k, v in errors.items() if k != "model"}},
        "stats": stats, "proxies": proxies, "losses": diag,
        "walk": models[0][1].walk.tolist(), "region": next(iter(search.values())).kind,
        "array_positions": np.unique(x0, axis=0).tolist(), "transmitters": np.unique(y0, axis=0).tolist(),
        "settings": {"antennas": antennas, "views": int(len(ant)),
                     "available_views": int(len(query_antennas(data, antennas=antennas))), "reference": reference, "grid_m": grid_m, "starts": starts,
                     "steps": steps, "lr_m": lr_m, "loss": loss, "downsample": downsample, "region": region,
                     "descent": descent},
        "descent": sorted(used), "losses_evaluated": int(evals), "time_s": time.perf_counter() - t0,
    }
