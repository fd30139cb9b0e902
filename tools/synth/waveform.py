"""Exposure integrals of the firmware's drive waveforms.

The light an LED puts into one image row is the mean of its drive level over that row's
exposure window (PROTOCOL.md section 2). The waveform is not re-implemented here: it is
`firmware_tx.schedule.make_schedule(...)`'s `levels` (one byte per tick, bit 0 = pin A,
bit 1 = pin B), periodic, piecewise constant between tick starts
``tick_start_us(i) = i * 1e6 // tick_hz`` microseconds.

The mean over [t0, t0 + E] is computed exactly from the cumulative integral over one period,
``F(tau) = floor(tau/P) * C_n + C_j + level_j * (tau' - b_j)``, with the tick starts `b_j`
of the first period (the firmware's whole-microsecond grid) and period ``P = n / tick_hz``.
For rates whose tick is a whole number of microseconds (every default: 20 kHz chips,
200 Hz S2-PSK clock) this is the firmware's timing exactly; otherwise the firmware's
rounding of tick starts to whole microseconds differs from period to period by < 1 us,
and the first period's rounding is used for all periods.

Each LED has its own clock: LED time ``tau = (t + phase_s) * (1 + clock_ppm * 1e-6)``.
"""

from __future__ import annotations

import numpy as np

from firmware_tx.schedule import Schedule, make_schedule


class LedDrive:
    """Drive waveform of one emitter (one pin of one schedule) with its own clock.

    Args:
      schedule: a `firmware_tx.schedule.Schedule`.
      pin: 0 = pin A (OOK, tone, S2-PSK emitter A), 1 = pin B (S2-PSK emitter B).
      phase_s: LED time at t = 0 (seconds), i.e. where in its stream the LED is at t = 0.
      clock_ppm: clock-rate error of the LED's oscillator in parts per million.
      off_level: relative light output when the pin is low (0 = off; a dimming floor > 0).
    """

    def __init__(self, schedule: Schedule, pin: int = 0, phase_s: float = 0.0,
                 clock_ppm: float = 0.0, off_level: float = 0.0):
        self.schedule = schedule
        self.pin = int(pin)
        self.phase_s = float(phase_s)
        self.clock_scale = 1.0 + float(clock_ppm) * 1e-6
        lv = np.frombuffer(bytes(schedule.levels), dtype=np.uint8)
        on = ((lv >> self.pin) & 1).astype(np.float64)
        self.level = off_level + (1.0 - off_level) * on
        n = len(lv)
        starts_us = np.array([schedule.tick_start_us(i) for i in range(n)], dtype=np.float64)
        self.period_s = n / schedule.tick_hz
        self.starts_s = starts_us * 1e-6
        widths = np.diff(np.append(self.starts_s, self.period_s))
        self.cum = np.concatenate([[0.0], np.cumsum(self.level * widths)])

    def led_time(self, t_s):
        """LED clock time of camera time `t_s` (seconds, array or scalar)."""
        return (np.asarray(t_s, dtype=np.float64) + self.phase_s) * self.clock_scale

    def _integral(self, tau: np.ndarray) -> np.ndarray:
        k = np.floor(tau / self.period_s)
        rem = tau - k * self.period_s
        j = np.clip(np.searchsorted(self.starts_s, rem, side="right") - 1, 0, len(self.starts_s) - 1)
        return k * self.cum[-1] + self.cum[j] + self.level[j] * (rem - self.starts_s[j])

    def level_at(self, t_s) -> np.ndarray:
        """Instantaneous relative output at camera time(s) `t_s`."""
        tau = self.led_time(t_s)
        rem = np.mod(tau, self.period_s)
        j = np.clip(np.searchsorted(self.starts_s, rem, side="right") - 1, 0, len(self.starts_s) - 1)
        return self.level[j]

    def exposure_mean(self, t_start_s, exposure_s: float) -> np.ndarray:
        """Mean relative output over ``[t_start_s, t_start_s + exposure_s]`` (vectorised)."""
        if exposure_s <= 0:
            return self.level_at(t_start_s)
        tau0 = self.led_time(t_start_s)
        tau1 = self.led_time(np.asarray(t_start_s, dtype=np.float64) + exposure_s)
        return (self._integral(tau1) - self._integral(tau0)) / (tau1 - tau0)


def led_drive(mode: str, led_id: int, rate_hz: float, symclk: int = 16, pin: int = 0, **kw) -> LedDrive:
    """`LedDrive` for a driver configuration, built with firmware_tx's own scheduler."""
    rate = int(rate_hz) if float(rate_hz).is_integer() else rate_hz
    return LedDrive(make_schedule(mode, led_id, rate, symclk), pin=pin, **kw)
