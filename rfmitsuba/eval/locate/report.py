"""The localisation's figure (:func:`plot_locate`) and Markdown report (:func:`report_markdown`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: an estimate this far [cm] from the truth counts as a miss in the report's account of why
MISS_CM = 100.0


def plot_locate(path: str | Path, result: dict) -> Path:
    """PNG: left, the room's top view with the walk, every true held-out position and its estimates
    (model per job, fingerprint) joined to it; right, the error against the distance from the
    fixed device (the transmitter of a moving-RX dataset, the array of a moving-TX one), model
    and fingerprint, blocked direct paths marked."""
    from ...core import plots

    truth = np.asarray(result["truth"], np.float64)
    fig, (ax, bx) = plots.subplots(1, 2, figsize=(13, 6.4))
    geom = None
    if result.get("scene_xml") and Path(result["scene_xml"]).is_file():
        from ...sim.geometry import RoomGeometry

        geom = RoomGeometry.from_xml(result["scene_xml"])
        geom.plot_top_view(ax, labels=True)
    walk = np.asarray(result["walk"], np.float64)
    ax.plot(walk[:, 0], walk[:, 1], ".", color="0.6", ms=4, label="training walk")
    arr, tx = np.asarray(result["array_positions"]), np.asarray(result["transmitters"])
    ax.plot(arr[:, 0], arr[:, 1], "s", color="0.3", ms=2.5, label="array positions of the queries")
    ax.plot(tx[:, 0], tx[:, 1], "*", color="red", ms=12, ls="none", label="transmitter" if len(tx) == 1 else
            "transmitters")
    colours = ["#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
    for i, (label, e) in enumerate(result["estimates"]["model"].items()):
        e = np.asarray(e, np.float64)
        c = colours[i % len(colours)]
        for a, b in zip(truth, e):
            ax.plot([a[0], b[0]], [a[1], b[1]], "-", color=c, lw=0.7, alpha=0.7)
        ax.plot(e[:, 0], e[:, 1], "o", color=c, ms=5, label=f"model ({label})")
    f = np.asarray(result["estimates"]["fingerprint"], np.float64)
    ax.plot(f[:, 0], f[:, 1], "^", mfc="none", mec="#d62728", ms=7, label="fingerprint")
    ax.plot(truth[:, 0], truth[:, 1], "kx", ms=8, mew=2, label="true position")
    cen = result["estimates"]["walk_centroid"]
    ax.plot(cen[0], cen[1], "P", color="#ff7f0e", ms=10, label="walk centroid")
    if geom is None:
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    handles, labels = ax.get_legend_handles_labels()
    ax.set_title(f"true and estimated positions ({len(truth)} held-out, {result['settings']['views']} PAS each)",
                 fontsize=9)
    fixed = "distance_to_tx_m" if result["task"] == "rx" else "distance_to_array_m"
    dist = np.array([p[fixed] for p in result["proxies"]])
    blocked = np.array([p["blocked_share"] for p in result["proxies"]]) > 0
    for i, (label, e) in enumerate(result["errors_cm"]["model"].items()):
        e = np.asarray(e)
        c = colours[i % len(colours)]
        bx.plot(dist[~blocked], e[~blocked], "o", color=c, ms=5, label=f"model ({label})")
        bx.plot(dist[blocked], e[blocked], "o", mfc="none", mec=c, ms=7)
    fe = np.asarray(result["errors_cm"]["fingerprint"])
    bx.plot(dist, fe, "^", mfc="none", mec="#d62728", ms=7, label="fingerprint")
    bx.axhline(result["stats"]["walk_centroid"]["median_cm"], color="#ff7f0e", ls="--", lw=1,
               label="walk centroid (median)")
    plots.label(bx, xlabel=f"distance from the {'transmitter' if result['task'] == 'rx' else 'array'} (m)",
                ylabel="error (cm)")
    bx.set_title("error against distance (hollow circles: the person blocks a direct path)", fontsize=9)
    fig.legend(handles, labels, loc="lower left", bbox_to_anchor=(0.03, 0.0), ncol=4, fontsize=7)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return plots.save(fig, path, tight=False)


def _row(name: str, s: dict | None) -> str:
    if not s:
        return f"| {name} | n/a | n/a | n/a | 0 |"
    return f"| {name} | {s['median_cm']:.0f} | {s['p90_cm']:.0f} | {s['mean_cm']:.0f} | {s['n']} |"


def _split_rows(result: dict, values: np.ndarray, edges: list, names: list[str], what: str) -> list[str]:
    """Median error [cm] of the model (pooled) and the fingerprint per group of a proxy."""
    model = np.asarray(list(result["errors_cm"]["model"].values()), np.float64)   # [J, Q]
    fp = np.asarray(result["errors_cm"]["fingerprint"], np.float64)
    out = []
    for name, lo, hi in zip(names, edges[:-1], edges[1:]):
        sel = (values >= lo) & (values < hi)
        if not sel.any():
            continue
        out.append(f"| {what} {name} | {int(sel.sum())} | {np.median(model[:, sel]):.0f} | "
                   f"{np.percentile(model[:, sel], 90):.0f} | {np.median(fp[sel]):.0f} |")
    return out


def _why_lines(result: dict) -> list[str]:
    """Markdown: of the queries with an error over :data:`MISS_CM`, how many the search missed (the
    model's loss at the true position is below its estimate's) and how many the model missed (it
    is not), and how often the model's person at the true position explains the query worse than
    no person at all."""
    d = result.get("losses")
    if not d:
        return []
    rows = [(e, r) for label in d for e, r in zip(result["errors_cm"]["model"][label], d[label])]
    miss = [r for e, r in rows if e > MISS_CM]
    search = sum(r["truth"] < r["estimate"] for r in miss)
    worse = sum(r["truth"] > r["no_person"] for _, r in rows)
    return ["", f"Of the {len(rows)} estimates, {len(miss)} are more than {MISS_CM:g} cm off: for {search} of them "
            f"the model's loss at the true position is lower than at its estimate (the search missed it), for "
            f"{len(miss) - search} it is not (the model prefers another place). For {worse} of the {len(rows)} the "
            "model's person at the true position explains the query worse than the background alone (no person): "
            "there the model has not learned what the person does to these PAS."]


def report_markdown(result: dict, *, command: str | None = None) -> str:
    """The Markdown report of :func:`evaluate_locate`'s result."""
    s, st = result["settings"], result["stats"]
    lines = [f"# Localisation with `{result['run']}`", "",
             f"Dataset `{result['dataset']}` (moving {result['task'].upper()}); {len(result['states'])} held-out walk "
             f"positions (the dataset's person test split), each located from {s['views']} PAS at "
             f"{'its test' if s['antennas'] == 'test' else 'its'} antenna positions"
             f"{' (a seeded subset)' if s['views'] < s.get('available_views', s['views']) else ''}; jobs "
             f"{', '.join(result['jobs'])}; "
             + ("the model's change fitted on top of the empty room's measured PAS at the same antennas. "
                if s.get("reference") == "empty" else "the model's PAS compared with the query as it is. ")
             + f"Search: {result['region']} region, {s['grid_m']} m grid, {s['starts']} starts, "
             f"{', '.join(result['descent'])} descent ({s['steps']} steps), loss "
             f"{'0.8 L1 + 0.2 (1 - SSIM)' if s['loss'] == 'train' else '1 - SSIM'} at "
             f"{90 // s['downsample']} x {360 // s['downsample']}. Errors are horizontal distances in cm.", "",
             "| estimate | median (cm) | 90th pct (cm) | mean (cm) | n |", "|---|---|---|---|---|",
             _row("model (all jobs)", st["model"])]
    if len(st["model_per_job"]) > 1:
        lines += [_row(f"model ({k})", v) for k, v in st["model_per_job"].items()]
    lines += [_row("fingerprint (nearest training walk state by SSIM)", st["fingerprint"]),
              _row("walk centroid", st["walk_centroid"])]
    if st.get("room_centre"):
        lines.append(_row("room centre", st["room_centre"]))
    px = result["proxies"]
    dist = np.array([p["distance_to_array_m"] for p in px])
    dtx = np.array([p["distance_to_tx_m"] for p in px])
    lines += ["", "## Where it fails", "",
              "Median and 90th-percentile error (cm) of the model (pooled over jobs) and the fingerprint's median, "
              "per group of held-out positions.", "",
              "| group | positions | model median | model p90 | fingerprint median |", "|---|---|---|---|---|"]
    q = np.quantile(dist, [0, 1 / 3, 2 / 3, 1])
    q[-1] += 1e-9
    lines += _split_rows(result, dist, list(q), [f"{a:.2f}-{b:.2f} m" for a, b in zip(q[:-1], q[1:])],
                         "distance from the nearest array position")
    q = np.quantile(dtx, [0, 1 / 3, 2 / 3, 1])
    q[-1] += 1e-9
    lines += _split_rows(result, dtx, list(q), [f"{a:.2f}-{b:.2f} m" for a, b in zip(q[:-1], q[1:])],
                         "distance from the transmitter" if result["task"] == "rx" else "distance from the nearest TX")
    blocked = np.array([p["blocked_share"] for p in px])
    lines += _split_rows(result, (blocked > 0).astype(float), [0, 0.5, 1.5],
                         ["no", "yes"], "blocks a direct path:")
    if px and px[0]["hidden_from_tx"] is not None:
        hid = np.array([float(p["hidden_from_tx"]) for p in px])
        lines += _split_rows(result, hid, [0, 0.5, 1.5], ["no", "yes"], "furniture between TX and chest:")
        hs = np.array([p["hidden_share"] for p in px])
        lines += _split_rows(result, (hs > 0).astype(float), [0, 0.5, 1.5], ["none", "some"],
                             "array positions that see the chest through furniture:")
    lines += _why_lines(result)
    lines += ["", f"{result['losses_evaluated']} model losses evaluated in {result['time_s']:.0f} s.", ""]
    if command:
        lines += ["Regenerate with:", "", "```", command, "```", ""]
    return "\n".join(lines)
