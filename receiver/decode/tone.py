"""Tone-mode decoding: stripe frequency of a row profile, matched to the map (PROTOCOL.md s. 4).

A tone LED blinks a 50 % square wave at `freq_hz`; a rolling-shutter camera whose rows start
`row_readout_us` apart sees it as stripes of `freq_hz * t_row` cycles per row. The fundamental is
the strongest spectral line (a square wave's odd harmonics fall as 1/k), so:

1. trim the blob's thin top and bottom rows, remove the mean and a linear trend (the blob's
   brightness envelope), apply a Hann window (its sidelobes fall fast, so the envelope's
   energy near DC does not pull the peak);
2. coarse peak of the zero-padded FFT inside [fmin_hz, fmax_hz];
3. refinement: parabolic interpolation of the log power through the three padded bins at
   the peak (the Hann main lobe is close to Gaussian, so this is nearly unbiased; with 8x
   padding the residual bias is far below 0.1 %).

Hz = (cycles per row) / t_row. Matching accepts the nearest listed frequency only within half
the channel spacing.

Input: on real photos feed `receiver.vision.tone_profile.tone_profile` (the LED's whole striped
extent, log intensity), not the half-maximum envelope's row profile: a saturated LED's
envelope holds only ~3-4 stripe periods, and the record length, not this estimator, limits the
accuracy (Luxapose photos: 2000 Hz LED +4.0 % from the envelope, +1.1 % from the tone profile;
its stripe edges themselves say +0.9 %). Estimators tried on the 13 real LEDs and rejected:
a rectangular-window least-squares sinusoid (harmonics of the 50 % wave pull it, errors up to
2 %), stripe-edge and stripe-centre regressions (the dim partial stripes at the ends of the
extent move them by up to 2 %), envelope normalisation by a running max/min before the FFT
(no gain), polynomial detrending up to degree 4 (no gain).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from receiver.decode.ook import trim_rows
from receiver.decode.settings import ToneSettings
from receiver.core.settings import resolve_settings
from receiver.core import protocol

MIN_SPACING_HZ = protocol.TONE_MIN_SPACING_HZ
# The frequency band a decoder searches: from FMIN_SHARE of the map's lowest tone to FMAX_SHARE
# of its highest (the envelope's and the harmonics' lines stay outside).
FMIN_SHARE = 0.5
FMAX_SHARE = 1.5
# Least spectral peak quality (the peak's power over the spectrum's median power) of a frame the
# decoder averages. Tone has no CRC, so this gate keeps non-LED blobs out: pure noise profiles of
# 30-300 rows reach about 25.
MIN_QUALITY = 30.0


@lru_cache(maxsize=64)
def _ramp_and_window(n: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Centred row ramp, its squared norm and the Hann window for n rows (cached: profiles of
    a tracked blob keep their length from frame to frame)."""
    r = np.arange(n) - 0.5 * (n - 1)
    return r, float(r @ r), 0.5 - 0.5 * np.cos(2.0 * np.pi * (np.arange(n) + 0.5) / n)


def _nfft(m: int) -> int:
    """Smallest power of two >= m (m >= 1): `1 << int(np.ceil(np.log2(m)))` in integers."""
    return 1 << (m - 1).bit_length()


def _peak_cycles_per_row(x: np.ndarray, k_lo: float, k_hi: float, pad_factor: int
                         ) -> tuple[float, float]:
    """Refined spectral peak of a (detrended) profile within [k_lo, k_hi] cycles/row.
    Returns (cycles_per_row or nan, quality = peak / median power above k_lo)."""
    n = x.size
    r, rr, win = _ramp_and_window(n)
    x = x - np.add.reduce(x) / n  # x.mean(), without its Python-level wrapper
    x -= r * ((r @ x) / rr)  # linear trend of the brightness envelope
    x *= win
    nfft = _nfft(n * pad_factor)
    z = np.fft.rfft(x, nfft)
    re, im = z.real, z.imag
    spec = re * re
    spec += im * im
    k0 = math.ceil(k_lo * nfft)
    k1 = min(math.floor(k_hi * nfft), spec.size - 1)
    if k1 - k0 < 3:
        return float("nan"), 0.0
    kp = k0 + int(spec[k0:k1 + 1].argmax())
    if kp == k0 or kp == k1:
        # The maximum sits on the edge of the searched band: the line is outside it (e.g. below
        # the lowest frequency a record this short can hold), and the edge value would depend
        # on the record length, not on the LED. No estimate.
        return float("nan"), 0.0
    # noise floor over everything above the low limit, not just the searched band (a narrow
    # band would be filled by the peak's own main lobe)
    tail = spec[k0:]
    floor = np.partition(tail, tail.size // 2)[tail.size // 2]  # median, without a full sort
    quality = float(spec[kp] / max(floor, 1e-30))
    # parabola through the log power of the padded bins around the peak: the Hann main lobe
    # is close to a Gaussian, whose log is a parabola, so this is nearly unbiased
    kp = min(max(kp, 1), spec.size - 2)
    la, lb, lc = np.log(spec[kp - 1:kp + 2] + 1e-30).tolist()
    den = la - 2.0 * lb + lc
    delta = 0.5 * (la - lc) / den if den < 0 else 0.0
    return (kp + min(max(delta, -1.0), 1.0)) / nfft, quality


def stripe_frequency_hz(profile, row_readout_us: float, weights=None, *, fmin_hz: float = 500.0,
                        fmax_hz: float | None = None, min_row_frac: float = 0.25,
                        pad_factor: int = 8, min_cycles: float = 1.5) -> tuple[float, float]:
    """Stripe frequency of one blob's row profile.

    profile: float (R,) mean gray per row, top to bottom; weights: (R,) pixels per row or None.
    fmin_hz [500]: lowest frequency searched; fmax_hz [None = 0.45 / t_row, below the row
    Nyquist limit]. min_row_frac [0.25]: rows narrower than this fraction of the widest are
    trimmed. pad_factor [8]: FFT zero padding for the coarse peak. min_cycles [1.5]: the blob
    must span at least this many stripe periods.
    Returns (freq_hz, quality): quality = peak power / median power of the spectrum above
    fmin_hz (a spectral SNR; pure noise gives ~5-25); freq_hz is nan when there is no usable peak.
    """
    t_row_s = row_readout_us * 1e-6
    x = np.asarray(profile, dtype=np.float64)
    a, b = trim_rows(weights, x.size, min_row_frac)
    x = x[a:b]
    n = x.size
    k_hi = (0.45 if fmax_hz is None else min(fmax_hz * t_row_s, 0.5))
    k_lo = max(fmin_hz * t_row_s, min_cycles / max(n, 1))
    if n < 8 or k_lo >= k_hi:
        return float("nan"), 0.0
    k, quality = _peak_cycles_per_row(x, k_lo, k_hi, pad_factor)
    return float(k / t_row_s), quality


def default_spacing_hz(table: dict[int, float]) -> float:
    """Channel spacing of a frequency table: the smallest gap between its frequencies,
    never below the protocol's 50 Hz minimum (a one-entry table gets 50 Hz)."""
    f = np.sort(np.asarray(list(table.values()), dtype=np.float64))
    gap = float(np.diff(f).min()) if f.size > 1 else MIN_SPACING_HZ
    return max(gap, MIN_SPACING_HZ)


def match_tone(freq_hz: float, table: dict[int, float], *, spacing_hz: float | None = None
               ) -> int | None:
    """ID whose listed frequency is nearest to `freq_hz`, accepted only when closer than half
    the channel spacing (PROTOCOL.md section 4: there is no CRC, so the gap is the check).
    `spacing_hz` defaults to `default_spacing_hz(table)`. None for nan or no match."""
    if not table or not np.isfinite(freq_hz):
        return None
    spacing = default_spacing_hz(table) if spacing_hz is None else spacing_hz
    ids = list(table)
    f = np.asarray([table[i] for i in ids], dtype=np.float64)
    j = int(np.argmin(np.abs(f - freq_hz)))
    return ids[j] if abs(f[j] - freq_hz) < 0.5 * spacing else None


@dataclass(frozen=True)
class ToneState:
    """`led_id`: matched ID or None; `freq_hz`: quality-weighted mean stripe frequency over
    the frames so far (nan before any); `frames`: frames fed."""

    led_id: int | None
    freq_hz: float
    frames: int


class ToneDecoder:
    """Per-blob tone decoder: averages the stripe frequency over frames, then matches it.

    table: {id: freq_hz} of the map's tone LEDs; row_readout_us: t_row. A frequency matches a
    listed one within half the map's spacing (`default_spacing_hz`); frames below MIN_QUALITY
    are ignored. Tunables: `ToneSettings` (receiver.decode.settings), given as `settings=` or as keyword
    overrides of its fields.
    """

    def __init__(self, table: dict[int, float], row_readout_us: float, *,
                 settings: ToneSettings | None = None, **overrides):
        s = self.settings = resolve_settings(settings, ToneSettings, overrides)
        if row_readout_us <= 0:
            raise ValueError("tone decoding needs a rolling shutter (row_readout_us > 0)")
        self.table = dict(table)
        self.row_readout_us = row_readout_us
        self.min_quality = MIN_QUALITY
        self.decay_per_frame = s.decay_per_frame
        f = list(self.table.values()) or [1000.0]
        self.fmin_hz = FMIN_SHARE * min(f)
        self.fmax_hz = FMAX_SHARE * max(f)
        self.frames = 0
        self._sum = 0.0
        self._w = 0.0
        # the table's spacing and frequencies, once (match_tone derived them every frame)
        self._spacing = default_spacing_hz(self.table)
        self._ids = list(self.table)
        self._freqs = [float(self.table[i]) for i in self._ids]

    def step(self, profile, weights=None, t_s=None) -> ToneState:
        """Feed one frame's row profile (see `stripe_frequency_hz`); `t_s` is unused."""
        self.frames += 1
        f, q = stripe_frequency_hz(profile, self.row_readout_us, weights, fmin_hz=self.fmin_hz,
                                   fmax_hz=self.fmax_hz)
        self._sum *= self.decay_per_frame
        self._w *= self.decay_per_frame
        if np.isfinite(f) and q >= self.min_quality:
            self._sum += q * f
            self._w += q
        if self._w <= 0:
            return ToneState(None, float("nan"), self.frames)
        fm = self._sum / self._w
        return ToneState(self._match(fm), fm, self.frames)

    def _match(self, freq_hz: float) -> int | None:
        """`match_tone(freq_hz, self.table)` in plain floats (the same arithmetic: the first
        nearest frequency, within half the map's spacing)."""
        if not self._ids or not math.isfinite(freq_hz):
            return None
        d = [abs(f - freq_hz) for f in self._freqs]
        j = d.index(min(d))
        return self._ids[j] if d[j] < 0.5 * self._spacing else None
