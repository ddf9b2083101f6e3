"""Where a localisation fails: geometric proxies of why a person position is hard to find (the
distance from the array and the transmitter, blocked direct paths, furniture hiding the body)."""
from __future__ import annotations

import numpy as np

from .region import BODY_HEIGHT_M

#: radius [m] of the body for the failure proxies (half of rfmitsuba.sim.person.WIDTH)
BODY_RADIUS_M = 0.225
#: height above the feet [m] of the point the shadow proxy looks at (the chest)
CHEST_M = 1.2


def failure_proxies(feet: np.ndarray, array_pos: np.ndarray, transmitters: np.ndarray, geometry=None) -> dict:
    """Geometric proxies of why a person position is hard to find.

    Args:
        feet: float [3] the true feet position [m]; array_pos: float [K, 3] the array centres of
        the query's views [m]; transmitters: float [K, 3] their transmitters [m]; geometry: the
        room (:class:`~rfmitsuba.sim.geometry.RoomGeometry`) or None.

    Returns:
        {"distance_to_array_m": horizontal distance to the nearest array centre, "distance_to_tx_m":
        to the nearest transmitter, "blocked_share": share of the views whose direct path
        (transmitter -> array centre) passes within :data:`BODY_RADIUS_M` of the body axis at a
        height within the body, "hidden_from_tx": furniture lies on the line from the transmitter
        to the chest (:data:`CHEST_M` above the feet; None without a room), "hidden_share": share
        of the array centres from which furniture hides the chest (None without a room)}.
    """
    h = np.asarray(feet, np.float64).reshape(3)
    x = np.asarray(array_pos, np.float64).reshape(-1, 3)
    y = np.asarray(transmitters, np.float64).reshape(-1, 3)
    d = x - y
    w = h[None, :2] - y[:, :2]
    t = np.clip((w * d[:, :2]).sum(1) / np.maximum((d[:, :2] ** 2).sum(1), 1e-12), 0.0, 1.0)
    r = np.hypot(*(w - t[:, None] * d[:, :2]).T)
    z = y[:, 2] + t * d[:, 2]
    blocked = (r < BODY_RADIUS_M) & (z >= h[2]) & (z <= h[2] + BODY_HEIGHT_M)
    out = {"distance_to_array_m": float(np.hypot(*(x[:, :2] - h[:2]).T).min()),
           "distance_to_tx_m": float(np.hypot(*(y[:, :2] - h[:2]).T).min()),
           "blocked_share": float(blocked.mean()), "hidden_from_tx": None, "hidden_share": None}
    if geometry is not None:
        chest = h + [0.0, 0.0, CHEST_M]

        def hidden(a):
            who = geometry.segment_blocker(a, chest)
            return who is not None and who != "the walls"

        out["hidden_from_tx"] = bool(hidden(y[0]))
        out["hidden_share"] = float(np.mean([hidden(a) for a in np.unique(x, axis=0)]))
    return out
