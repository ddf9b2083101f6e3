"""An ensemble of independently trained Stage-1 fields, rendered as the mean of their PAS.

A run trained with ``TrainConfig.members = K`` holds ``K`` run folders of its own
(``RUN/members/0`` ...), each one field fitted to the same split from another seed.
:class:`FieldMean` renders all of them and returns the mean of their per-image min-max
normalised PAS (the metric protocol's scale, docs/conventions.md), so every consumer of a
run's renderer (evaluation, the neighbour-anchored prediction, ``predict``) sees one
prediction.

Why a mean of images and not of fields: each member is a coherent sum of paths, and where the
training positions do not reach (the NeRF2-like spatial-block split) the members disagree on
the paths' relative phases. The mean of their PAS is the expected image over those fits,
which is what the SSIM of an uncertain prediction rewards; a mean of their channels would
interfere the disagreements instead.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..rf.bartlett_ref import normalize as minmax
from .base import Field, FieldSet


class FieldMean:
    """The mean PAS of several trained renderers (:class:`~rfmitsuba.models.base.FieldSet`),
    each rendering one member field of an ensemble.

    Args:
        members: the members' renderers, one per trained field (at least one).
    """

    def __init__(self, members: list[FieldSet]):
        if not members:
            raise ConfigError("FieldMean: no members")
        self.members = list(members)

    @property
    def fields(self) -> list[Field]:
        """Every member's fields, member by member."""
        return [f for m in self.members for f in m.fields]

    @property
    def num_primitives(self) -> int:
        """Primitives (Gaussians) of all members together."""
        return sum(m.num_primitives for m in self.members)

    def render(self, data, idx: np.ndarray, *, batch: int = 8, h: int = 90, w: int = 360) -> np.ndarray:
        """Mean of the members' min-max normalised PAS at indices ``idx`` of ``data``: float32
        [K, h, w] in [0, 1] (as :meth:`FieldSet.render`, which gives the raw PAS)."""
        return mean_image([m.render(data, idx, batch=batch, h=h, w=w) for m in self.members])


def mean_image(pas: list[np.ndarray]) -> np.ndarray:
    """The members' PAS (each float [K, H, W], any scale) normalised per image to [0, 1] and
    averaged: float32 [K, H, W]."""
    if not pas:
        raise ConfigError("mean_image: no members")
    shapes = {p.shape for p in pas}
    if len(shapes) != 1:
        raise ConfigError(f"mean_image: the members' PAS differ in shape: {sorted(shapes)}")
    return np.mean([minmax(np.asarray(p, np.float32)) for p in pas], axis=0).astype(np.float32)
