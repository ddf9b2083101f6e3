"""Exceptions raised by rfmitsuba. Every message names the thing that is wrong."""
from __future__ import annotations


class RfmError(Exception):
    """Base class of every error rfmitsuba raises on purpose."""


class ConfigError(RfmError, ValueError):
    """A configuration value or file is invalid (unknown key, wrong type, bad range)."""


class SceneError(RfmError, ValueError):
    """A scene is unknown, malformed, or refers to a missing mesh file."""


class PlacementError(RfmError, ValueError):
    """An antenna or person position is outside the room, inside furniture, or not finite."""


class DatasetError(RfmError, ValueError):
    """A dataset folder is missing arrays, truncated, inconsistent, or of another configuration."""


class RunError(RfmError, ValueError):
    """A training run folder is inconsistent with the requested configuration."""


class GaussianError(RfmError, ValueError):
    """Gaussian parameters or render inputs are invalid (non-finite, wrong size, zero quaternion)."""


class ImageError(RfmError, ValueError):
    """Images of mismatched or too small shape were given to SSIM or the loss."""
