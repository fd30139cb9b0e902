"""Test signals with known truth for the decoders (no camera renderer needed).

Everything is built from `firmware_tx.schedule.make_schedule(...)`, the same waveform the LED
driver emits, with *exact* exposure integrals: a sensor row (or a global-shutter frame) exposed
over [t, t + t_exp] reads the mean of the periodic, piecewise-constant drive waveform over that
interval, computed from the cumulative sum of one period of ticks (no sampling error).

Rolling shutter (PROTOCOL.md section 2): row r of a frame starting at t0 is exposed over
[t0 + r*t_row, t0 + r*t_row + t_exp].
"""

from __future__ import annotations

import numpy as np

from firmware_tx.schedule import make_schedule


def pin_waveform(schedule, pin=0, flip_units=()):
    """One period of one pin's drive level, float64 (N ticks,), with the given stream units
    (chips / symbols) inverted to emulate transmission errors."""
    lv = np.frombuffer(bytes(schedule.levels), dtype=np.uint8)
    w = ((lv >> pin) & 1).astype(np.float64)
    for u in flip_units:
        k = schedule.ticks_per_unit
        w[u * k:(u + 1) * k] = 1.0 - w[u * k:(u + 1) * k]
    return w


def exposure_mean(wave, tick_hz, t_start_s, exposure_s):
    """Mean of the periodic waveform `wave` (one period, one value per tick at `tick_hz`) over
    [t, t + exposure_s] for every t in `t_start_s`; exposure 0 samples the level at t."""
    t = np.asarray(t_start_s, dtype=np.float64)
    n = len(wave)
    cum = np.concatenate(([0.0], np.cumsum(wave)))

    def integral(u):  # integral of the waveform from 0 to u ticks
        per, rem = np.divmod(u, n)
        i = np.floor(rem).astype(np.int64)
        i = np.minimum(i, n - 1)
        return per * cum[-1] + cum[i] + (rem - i) * wave[i]

    u0 = t * tick_hz
    if exposure_s <= 0:
        return wave[np.floor(np.mod(u0, n)).astype(np.int64) % n]
    u1 = u0 + exposure_s * tick_hz
    return (integral(u1) - integral(u0)) / (u1 - u0)


def blob_weights(n_rows, width_px=None):
    """Envelope pixels per row of a round blob n_rows tall (chord lengths), float32."""
    width_px = n_rows if width_px is None else width_px
    y = (np.arange(n_rows) + 0.5) / n_rows * 2.0 - 1.0
    return np.maximum(1.0, width_px * np.sqrt(np.clip(1.0 - y * y, 0.0, 1.0))).astype(np.float32)


def row_profile(wave, tick_hz, row_readout_us, exposure_us, n_rows, t0_s, *, gain=150.0,
                offset=20.0, falloff=0.3, noise=0.0, rng=None, width_px=None):
    """Rolling-shutter row profile of one blob: (profile float32 (R,), weights float32 (R,)).

    Gain falls off towards the blob's top and bottom (`falloff` = relative loss at the edge,
    as Lambertian emission and the LED's shape do), a constant `offset` (ambient), and
    Gaussian pixel noise of std `noise` gray levels, averaged over each row's pixels.
    """
    r = np.arange(n_rows, dtype=np.float64)
    s = exposure_mean(wave, tick_hz, t0_s + r * row_readout_us * 1e-6, exposure_us * 1e-6)
    y = (r + 0.5) / n_rows * 2.0 - 1.0
    g = gain * (1.0 - falloff * y * y)
    w = blob_weights(n_rows, width_px)
    prof = offset + g * s
    if noise > 0:
        prof = prof + rng.normal(0.0, 1.0, n_rows) * noise / np.sqrt(w)
    return prof.astype(np.float32), w


def ook_frames(led_id, rate_hz, row_readout_us, exposure_us, n_rows, n_frames, rng, *,
               flip_chips=(), **kw):
    """`n_frames` OOK row profiles of one LED, each at a random phase of the chip stream.

    Returns a list of (profile, weights). `flip_chips`: packet chip indices sent inverted.
    """
    sch = make_schedule("ook", led_id, int(rate_hz))
    wave = pin_waveform(sch, 0, flip_chips)
    period_s = len(wave) / sch.tick_hz
    out = []
    for _ in range(n_frames):
        out.append(row_profile(wave, sch.tick_hz, row_readout_us, exposure_us, n_rows,
                               rng.uniform(0.0, period_s), rng=rng, **kw))
    return out


def tone_profile(freq_hz, row_readout_us, exposure_us, n_rows, rng, **kw):
    """Row profile of a tone-mode LED (50 % square wave) at a random phase."""
    sch = make_schedule("tone", 0, freq_hz)
    wave = pin_waveform(sch, 0)
    return row_profile(wave, sch.tick_hz, row_readout_us, exposure_us, n_rows,
                       rng.uniform(0.0, 1.0 / freq_hz), rng=rng, **kw)


def s2psk_samples(led_id, clk_hz, symbol_clocks, n_frames, rng, *, fps=30.0, jitter_s=0.002,
                  exposure_s=0.0005, drop_prob=0.0, noise=0.0, gains=(180.0, 140.0),
                  offsets=(10.0, 15.0), t0_s=None):
    """Frame-rate samples of an S2-PSK emitter pair (global shutter, same instant for A, B).

    Returns (t_s (F,), a (F,), b (F,)) mean gray levels of the two blobs; frames are at
    1/fps with Gaussian timestamp jitter (the timestamp is the exposure start), a random
    start phase, and dropped frames removed with probability `drop_prob`.
    """
    sch = make_schedule("s2psk", led_id, clk_hz, symbol_clocks)
    wa, wb = pin_waveform(sch, 0), pin_waveform(sch, 1)
    period_s = len(wa) / sch.tick_hz
    t0 = rng.uniform(0.0, period_s) if t0_s is None else t0_s
    t = t0 + np.arange(n_frames) / fps + rng.normal(0.0, jitter_s, n_frames)
    t = np.sort(t)
    keep = rng.uniform(size=n_frames) >= drop_prob
    t = t[keep]
    a = offsets[0] + gains[0] * exposure_mean(wa, sch.tick_hz, t, exposure_s)
    b = offsets[1] + gains[1] * exposure_mean(wb, sch.tick_hz, t, exposure_s)
    if noise > 0:
        a = a + rng.normal(0.0, noise, len(t))
        b = b + rng.normal(0.0, noise, len(t))
    return t, a, b
