"""
The Lepton 2 as a sensor: radiometric response, optics, noise, drift and flat-field corrections.

Scene temperatures become 14-bit counts: band radiance (approximated by ``T^4`` in kelvin,
linearised at 20 deg C to ``counts_per_kelvin``), lens blur, vignetting, temporal noise of about
50 mK, fixed-pattern and column noise (redrawn at each flat-field correction), an offset that
drifts as the uncooled sensor warms and jumps back at each FFC, and a per-camera gain and
offset, so two cameras never agree on brightness.
"""

import dataclasses

import cv2
import numpy as np

KELVIN = 273.15
COUNTS_MAX = 2 ** 14 - 1


def band_radiance(celsius):
    """Relative in-band radiance ``(T / 293.15 K)^4`` of a temperature (deg C)."""
    return ((np.asarray(celsius, dtype=np.float64) + KELVIN) / (20.0 + KELVIN)) ** 4


def temperature_of_radiance(radiance):
    """Inverse of ``band_radiance``: the temperature (deg C) of a mean radiance."""
    return (20.0 + KELVIN) * np.asarray(radiance) ** 0.25 - KELVIN


@dataclasses.dataclass(frozen=True)
class SensorModel:
    """
    One camera's response and noise; every field is documented by its name and unit.

    ``blur_sigma_px`` is the lens + detector blur (Gaussian); ``vignetting`` the relative loss
    of signal at the image corners; ``drift_counts_per_s`` the offset drift between FFCs,
    which happen at ``ffc_first_s`` and every ``ffc_period_s`` after it (0 = never).
    """

    counts_per_kelvin: float = 35.0
    reference_counts: float = 8000.0
    temporal_noise_mk: float = 50.0
    pixel_fpn_counts: float = 1.5
    column_fpn_counts: float = 1.0
    blur_sigma_px: float = 0.55
    vignetting: float = 0.06
    gain: float = 1.0
    offset_counts: float = 0.0
    drift_counts_per_s: float = 0.5
    ffc_first_s: float = 0.0
    ffc_period_s: float = 180.0
    seed: int = 0

    def ffc_index(self, time_s):
        """Count the flat-field corrections done by ``time_s`` (the first at ``ffc_first_s``)."""
        if self.ffc_period_s <= 0 or time_s < self.ffc_first_s:
            return 0
        return 1 + int((time_s - self.ffc_first_s) // self.ffc_period_s)

    def seconds_since_ffc(self, time_s):
        """Time since the last FFC (or since start-up), seconds."""
        index = self.ffc_index(time_s)
        if index == 0:
            return time_s
        return time_s - self.ffc_first_s - (index - 1) * self.ffc_period_s


class LeptonSensor:
    """Turns rendered temperature images into 14-bit frames, frame after frame."""

    def __init__(self, model, shape):
        self.model = model
        self.shape = shape
        rows, cols = shape
        v, u = np.mgrid[0:rows, 0:cols]
        r2 = ((u - (cols - 1) / 2) ** 2 + (v - (rows - 1) / 2) ** 2) / \
            (((cols - 1) / 2) ** 2 + ((rows - 1) / 2) ** 2)
        self.vignette = 1.0 - model.vignetting * r2
        self.noise = np.random.default_rng(model.seed)
        self._fpn_index = None
        self._fpn = None

    def fixed_pattern(self, time_s):
        """Pixel and column pattern left by the last FFC (redrawn at each FFC)."""
        index = self.model.ffc_index(time_s)
        if index != self._fpn_index:
            rng = np.random.default_rng((self.model.seed, index))
            rows, cols = self.shape
            self._fpn = (rng.normal(0.0, self.model.pixel_fpn_counts, self.shape)
                         + rng.normal(0.0, self.model.column_fpn_counts, (1, cols)))
            self._fpn_index = index
        return self._fpn

    def signal_counts(self, celsius):
        """Noise-free counts of a temperature image: radiometric response, blur, vignetting."""
        m = self.model
        # d band_radiance / dT at 20 C is 4 / 293.15 per kelvin.
        signal = (band_radiance(celsius) - 1.0) * (20.0 + KELVIN) / 4.0 * m.counts_per_kelvin
        if m.blur_sigma_px > 0:
            signal = cv2.GaussianBlur(signal, (0, 0), m.blur_sigma_px,
                                      borderType=cv2.BORDER_REFLECT)
        return m.reference_counts + m.gain * self.vignette * signal

    def frame(self, celsius, time_s, noise=True):
        """Return the 14-bit counts (uint16) of a temperature image at ``time_s``."""
        m = self.model
        counts = self.signal_counts(celsius) + m.offset_counts
        if noise:
            counts = counts + m.drift_counts_per_s * m.seconds_since_ffc(time_s)
            counts = counts + self.fixed_pattern(time_s)
            counts = counts + self.noise.normal(
                0.0, m.temporal_noise_mk * 1e-3 * m.counts_per_kelvin, self.shape)
        return np.clip(np.rint(counts), 0, COUNTS_MAX).astype(np.uint16)
