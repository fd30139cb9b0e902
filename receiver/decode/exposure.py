"""Exposure-aware chip estimation: the row profile as the chip stream averaged over the exposure.

A rolling-shutter row r of one frame integrates the LED over `[t_r, t_r + t_exp]` (PROTOCOL.md
section 2), and the lens spreads each row over its neighbours (Gaussian blur). In chip units,
with the row's exposure starting at chip time `tau_r = tau_0 + r / p` (p rows per chip) and
lasting `e = t_exp * rate` chips, row r sees

    y_r = sum_k c_k h(tau_r - k),    h = (box of length e over one chip) * Gaussian(blur),

with c_k in {0, 1} the chips: a linear, finite-memory channel (thesis eq. 3 integrated over the
exposure). When e is a sizeable fraction of a chip the stripes no longer have edges on a chip
grid; each row then mixes up to ceil(e) + 2 chips, and the chips are recovered here by
maximum-likelihood sequence estimation (Viterbi over the chips, states = the last chips a row
still sees) for each of `phases` sub-chip offsets tau_0; the offset with the smallest residual
wins. Soft chips are the max-log likelihood ratios (best path with the chip ON against the best
with it OFF, forward-backward), scaled by their median so that they read like the plain
sampler's (~ +-1): the packet assembly, sync search and CRC of `receiver.decode.ook` take them
unchanged.

The measured profile is not y itself: gain and offset vary slowly across a blob (vignetting,
diffuser falloff, a dark bezel) and a phone's tone curve bends the levels. Both are undone
before the fit: the running minimum and maximum over `norm_chips` chips give the local OFF and
ON levels (Manchester keeps both in every such window), and the normalised levels are mapped
through their empirical distribution onto the model's own distribution of y (a monotone tone
curve changes levels, not their order).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import cv2

from firmware_tx.framing import ook_packet

# A chip whose weight in a row is below this fraction of the kernel's peak is ignored there.
KERNEL_FLOOR = 0.03
# Chips a row may mix at most (2^(this - 1) Viterbi states); longer kernels are truncated.
MAX_MEMORY = 6
# Fine grid of the tabulated kernel, points per chip.
KERNEL_FINE = 64


@lru_cache(maxsize=32)
def chip_kernel(e_chips: float, blur_chips: float) -> tuple[np.ndarray, np.ndarray]:
    """(d, h): the weight h(d) of a chip in a row whose exposure starts d chips after the chip's
    start (box of e_chips over a one-chip rectangle, normalised to the row's mean level, then a
    Gaussian of blur_chips); read-only tables."""
    span = 4.0 * blur_chips
    d = np.arange(-e_chips - 1.0 - span - 0.5, 1.0 + span + 0.5, 1.0 / KERNEL_FINE)
    if e_chips > 1e-6:
        h = np.clip(np.minimum(d + e_chips, 1.0) - np.maximum(d, 0.0), 0.0, None) / e_chips
    else:
        h = ((d > -1.0) & (d <= 0.0)).astype(float)  # an instant sample at d sees chip k if k <= -d... < k+1
    if blur_chips > 0:
        g = np.arange(-int(span * KERNEL_FINE) - 1, int(span * KERNEL_FINE) + 2) / (blur_chips * KERNEL_FINE)
        g = np.exp(-0.5 * g * g)
        h = np.convolve(h, g / g.sum(), mode="same")
    d.setflags(write=False)
    h.setflags(write=False)
    return d, h


@lru_cache(maxsize=32)
def model_quantiles(period_rows: float, e_chips: float, blur_chips: float, n: int = 257) -> np.ndarray:
    """Quantiles (n,) of the noise-free row level y of random Manchester packets seen with this
    exposure and blur at random sub-chip offsets: the target of the level mapping."""
    ids = np.random.default_rng(0).integers(0, 1 << 16, 64)
    chips = np.concatenate([np.frombuffer(bytes(ook_packet(int(i))), np.uint8) for i in ids]).astype(float)
    d, h = chip_kernel(e_chips, blur_chips)
    rng = np.random.default_rng(1)
    tau = np.sort(rng.uniform(8.0, chips.size - 8.0, 20000))
    k = np.floor(tau)[:, None] + np.arange(-int(e_chips) - 4, 6)[None, :]
    y = (np.interp(tau[:, None] - k, d, h, left=0.0, right=0.0) * chips[k.astype(int)]).sum(axis=1)
    q = np.quantile(y, np.linspace(0.0, 1.0, n))
    q.setflags(write=False)
    return q


def envelopes(x: np.ndarray, win: int) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): running minimum and maximum of x over `win` samples, each smoothed by a
    running mean of `win` (edges: the window's part inside x)."""
    row = np.ascontiguousarray(x, dtype=np.float64)[None, :]
    k = np.ones((1, win), np.uint8)
    out = []
    for op in (cv2.erode, cv2.dilate):
        e = op(row, k, borderType=cv2.BORDER_REPLICATE)
        out.append(cv2.blur(e, (win, 1), borderType=cv2.BORDER_REPLICATE)[0])
    return out[0], out[1]


def linearise(x: np.ndarray, period_rows: float, e_chips: float, blur_chips: float,
              norm_chips: float) -> np.ndarray:
    """Profile levels mapped onto the model's level scale y in [0, 1] (module docstring)."""
    lo, hi = envelopes(x, max(3, int(round(norm_chips * period_rows))))
    xn = (x - lo) / np.maximum(hi - lo, 1e-6)
    q = model_quantiles(period_rows, e_chips, blur_chips)
    ranks = (np.argsort(np.argsort(xn, kind="stable"), kind="stable") + 0.5) / xn.size
    return np.interp(ranks, np.linspace(0.0, 1.0, q.size), q)


@lru_cache(maxsize=256)
def _trellis(R: int, period_rows: float, e_chips: float, blur_chips: float, phases: int):
    """The frame-independent part of `mlse_chips` for R rows (cached: the same few blob
    heights recur): (L, k0, n, pred (P, R, 2^L) model level of every row under every pattern
    of its L chips, idx (P * R * 2^L) the branch-metric bin of each), or None when too short.
    A row whose exposure starts at chip time tau sees chips k with tau - k inside the
    kernel's support; its newest chip decides at which Viterbi step it is scored."""
    d, h = chip_kernel(e_chips, blur_chips)
    tau = (np.arange(phases) / phases)[:, None] + np.arange(R)[None, :] / period_rows  # (P, R)
    hmax = float(h.max())
    ok = d[h >= KERNEL_FLOOR * hmax]
    last = np.floor(tau - ok.min()).astype(np.int64)
    first = np.ceil(tau - ok.max()).astype(np.int64)
    L = int(min(MAX_MEMORY, max(1, int((last - first).max()) + 1)))
    wts = np.interp(tau[..., None] - (last[..., None] - np.arange(L)), d, h, left=0.0, right=0.0)
    wts[wts < KERNEL_FLOOR * hmax] = 0.0
    k0 = int(last.min()) - L + 1  # first chip any row sees (state history starts here)
    n = int(last.max()) - k0 + 1
    if n < L + 2:
        return None
    pats = (np.arange(1 << L)[:, None] >> np.arange(L)[None, :]) & 1  # (2^L, L): bit j = chip (k - j)
    pred = wts @ pats.T.astype(float)  # (P, R, 2^L)
    idx = ((np.arange(phases)[:, None] * n + (last - k0))[..., None] * (1 << L) + np.arange(1 << L)).ravel()
    for a in (pred, idx):
        a.setflags(write=False)
    return L, k0, n, pred, idx


def mlse_chips(z: np.ndarray, w: np.ndarray, period_rows: float, e_chips: float, blur_chips: float,
               phases: int = 8):
    """Maximum-likelihood chip sequence of one frame's linearised profile.

    z: (R,) levels on the model scale (`linearise`), w: (R,) row weights (pixels). Tries
    `phases` sub-chip offsets tau_0 = j / phases. Returns (llr, first_chip, tau0, resid):
    llr (n,) max-log ratios (positive = ON) of chips first_chip .. first_chip + n - 1 (chip
    indices relative to tau_0's chip 0), the winning tau_0 (chip time of row 0's exposure
    start) and its weighted residual per row; None when the profile is too short.
    """
    t = _trellis(z.size, float(period_rows), float(e_chips), float(blur_chips), int(phases))
    if t is None:
        return None
    L, k0, n, pred, idx = t
    P = phases
    S = 1 << (L - 1)  # states: the last L - 1 chips, newest in bit 0
    err = w[None, :, None] * (z[None, :, None] - pred) ** 2
    # branch metrics per (phase, step, pattern): rows whose newest chip is this step's chip
    bm = np.bincount(idx, err.ravel(), P * n << L).reshape(P, n, 1 << L)
    # Viterbi: the pattern of step k is (state before: chips k-1..k-L+1) << 1 | chip k; the
    # state after is the pattern's low L - 1 bits
    pat_prev = np.arange(1 << L) >> 1  # state before (chips k-1 .. k-L+1)
    pat_next = np.arange(1 << L) & (S - 1)
    by_next = np.argsort(pat_next, kind="stable")  # the two patterns ending in each state
    alpha = np.zeros((P, n, S))
    a = np.zeros((P, S))
    for k in range(n):
        cand = a[:, pat_prev] + bm[:, k]  # (P, 2^L)
        a = cand[:, by_next].reshape(P, S, 2).min(axis=2)
        alpha[:, k] = a
    total = alpha[:, -1].min(axis=1)  # (P,)
    p = int(np.argmin(total))
    # backward pass for the winning phase only
    beta = np.zeros((n, S))
    b = np.zeros(S)
    for k in range(n - 1, -1, -1):
        beta[k] = b
        # pattern at step k: (state_{k-1}, chip k); b over the state after step k-1
        cand = bm[p, k] + b[pat_next]
        b = cand.reshape(S, 2).min(axis=1)  # patterns 2s, 2s + 1 follow state s
    through = alpha[p] + beta  # (n, S): best total metric through state s after step k
    on = through[:, 1::2].min(axis=1)  # bit 0 of the state = chip k
    off = through[:, 0::2].min(axis=1)
    llr = off - on
    wsum = float(w.sum())
    resid = float(total[p]) / max(wsum, 1e-9)
    return llr, k0, p / phases, resid



def ramp_exposure_rows(x: np.ndarray, period_rows: float, norm_chips: float = 16.0,
                       steep_frac: float = 0.4) -> float | None:
    """Exposure (rows) of one row profile from its stripes' edges, or None (too short or flat).

    A row reads the mean of the LED over its exposure, so its level changes from row to row
    by at most t_row / t_exp of the ON-OFF swing, and by that much at every row whose
    exposure window gains a chip edge at one end without losing one at the other: the edges
    are ramps t_exp long. With the levels normalised by the local OFF and ON envelopes, the
    median of the steep row-to-row steps (above `steep_frac` of the 98th percentile step:
    the rows inside ramps) is t_row / t_exp. Blur widens the ramps (by about its sigma) and
    an exposure shorter than a row reads as one row."""
    if x.size < 4 * period_rows:
        return None
    # envelopes over up to `norm_chips` chips: at long exposures only the sync's runs reach
    # the full ON and OFF levels, and a narrower envelope would shrink the swing
    lo, hi = envelopes(x, max(3, min(int(round(norm_chips * period_rows)), x.size)))
    d = np.abs(np.diff((x - lo) / np.maximum(hi - lo, 1e-6)))
    top = float(np.percentile(d, 98))
    if top <= 0:
        return None
    step = float(np.median(d[d > steep_frac * top]))
    return 1.0 / min(max(step, 1e-3), 1.0)


class ExposureLearner:
    """Exposure of one camera (rows) learned from OOK row profiles when the camera file does not
    state it: the median of `frames` per-profile estimates (`ramp_exposure_rows`). Shared by
    the decoders of one chip rate, as `receiver.decode.ook.PeriodLearner` is."""

    def __init__(self, frames: int = 8):
        self.frames = frames
        self.estimates: list[float] = []
        self.exposure_rows: float | None = None

    def add(self, x: np.ndarray, period_rows: float) -> None:
        if self.exposure_rows is not None:
            return
        e = ramp_exposure_rows(x, period_rows)
        if e is not None:
            self.estimates.append(e)
            if len(self.estimates) >= self.frames:
                self.exposure_rows = float(np.median(self.estimates))


# Longest exposure (chips) whose chips the model still reads: at two chips a row averages a
# whole Manchester pair (always half ON), and only the pair boundaries carry the data.
MAX_EXPOSURE_CHIPS = 1.8
# From this exposure (chips) up, the exposure model reads the chips (`OokSettings.exposure_model`
# "auto"): shorter exposures leave flat chip middles, which the plain sampler reads.
MODEL_FROM_CHIPS = 0.5


def exposure_verdict(exposure_us: float, rate_hz: float) -> tuple[bool, str]:
    """(readable, one-line text with the numbers) for OOK chips at `rate_hz` seen with this
    exposure; when not readable, the text names the longest exposure and the fastest chip
    rate that would be."""
    chip_us = 1e6 / rate_hz
    e = exposure_us / chip_us
    head = f"exposure {exposure_us:.0f} us is {e:.2f} chips of the {rate_hz / 1000:g} kHz OOK chips ({chip_us:.0f} us)"
    if e >= MAX_EXPOSURE_CHIPS:
        return False, (f"{head}: IDs are not reliably read beyond {MAX_EXPOSURE_CHIPS:g} chips (a row then averages "
                       f"whole Manchester pairs); use an exposure <= {MAX_EXPOSURE_CHIPS * chip_us:.0f} us or "
                       f"chips at <= {MAX_EXPOSURE_CHIPS * 1e3 / exposure_us:.1f} kHz")
    if e >= MODEL_FROM_CHIPS:
        return True, f"{head}: read by the exposure model (up to {MAX_EXPOSURE_CHIPS:g} chips)"
    return True, f"{head}: sharp stripes"
