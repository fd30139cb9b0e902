"""The receiver orchestrator: frame -> blobs -> tracks -> decoded LEDs -> position.

    rx = Receiver(camera, led_map, positioner=None)
    for frame in source:
        result = rx.process(frame)      # FrameResult

Stages, each stamped with the injected clock (`FrameResult.stage_ms`, receiver.core.budget):
`detect` (receiver.vision.detect), `track` (receiver.vision.track), `pair` (S2-PSK pairs and their soft XOR,
receiver.vision.pairing + receiver.decode.s2psk), `decode` (row profiles -> OOK / tone decoders),
`report` (the frame's LED observations), `locate` (the positioner, when one is given).

What is decoded follows the map (`ModePlan`): one OOK decoder per distinct OOK chip rate in the
map (an OOK ID counts only when the map lists it at that rate, or any ID under "xy"
addressing), tone decoding against the map's `freq_hz` table, S2-PSK pairing when the map has
S2-PSK lights or a `taillight` block. An ID is reported only when the decoder's check passed
(CRC for OOK / S2-PSK, the half-spacing window for tone) and the map knows it (or the
addressing is "xy", or it is a vehicle FV-ID); it then stays with the track.
"""

from __future__ import annotations

import importlib
import math
import time
from dataclasses import dataclass

import numpy as np

from receiver.core.budget import StageTimer
from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap
from receiver.vision.detect import detect
from receiver.vision.profile import mean_in_mask, row_profile, stripe_depth
from receiver.vision.envelope import merge_envelopes_many
from receiver.decode.frameclock import FrameClock
from receiver.vision.pairing import Pairer
from receiver.core.records import Frame, FrameResult, LedObservation
from receiver.vision.tone_profile import tone_profile
from receiver.vision.track import Track, Tracker

DEFAULT_OOK_RATE_HZ = 20000.0  # PROTOCOL.md section 2
DEFAULT_S2PSK_CLK_HZ = 200.0  # PROTOCOL.md section 3
DEFAULT_SYMBOL_CLOCKS = 16
FV_ID_MIN = 0x80  # S2-PSK IDs from here on are vehicles (PROTOCOL.md section 3)
# Smallest S2-PSK emitter blob (px): a 0.4 x 0.3 m head half at ~150 m with a 1200 px focal
# length (recordings/vehicle); specks below it are noise.
S2PSK_MIN_AREA_PX = 6.0
# Longest OFF run of an OOK stream in chips: the sync's OFF run (PROTOCOL.md section 1).
OOK_MAX_OFF_CHIPS = 4
# Rows added to the longest expected dark stripe (exposure edges, JPEG ringing).
STRIPE_GAP_MARGIN_ROWS = 2
# Dark-stripe gap bridged when the camera has a global shutter (no stripes).
GLOBAL_SHUTTER_GAP_PX = 2
# Photos: blobs smaller than this fraction of the biggest are reflections (receiver.vision.detect).
STILL_MIN_REL_AREA = 0.25
# Tone match check in maps that also hold OOK lights: stripe runs within this of half a period.
TONE_RUN_TOL = 0.35
# A rate in the map matches a decoder's rate within this relative tolerance.
RATE_MATCH_REL = 0.01


@dataclass(frozen=True)
class ModePlan:
    """Which decoders run, from the map: OOK chip rates (Hz), tone table {id: freq_hz},
    S2-PSK clocks {(clk_hz, symbol_clocks)}."""

    ook_rates: tuple[float, ...]
    tone_table: dict[int, float]
    s2psk: tuple[tuple[float, int], ...]

    @classmethod
    def from_map(cls, led_map: LedMap) -> "ModePlan":
        rates = {float(led.rate_hz or DEFAULT_OOK_RATE_HZ) for led in led_map.by_mode("ook")}
        if led_map.addressing == "xy":
            rates.add(float(led_map.default_rate_hz or DEFAULT_OOK_RATE_HZ))
        tones = {led.id: float(led.freq_hz) for led in led_map.by_mode("tone")}
        s2 = {(float(led.rate_hz or DEFAULT_S2PSK_CLK_HZ), int(led.symbol_clocks or DEFAULT_SYMBOL_CLOCKS))
              for led in led_map.by_mode("s2psk")}
        if led_map.taillight is not None and not s2:
            s2.add((DEFAULT_S2PSK_CLK_HZ, DEFAULT_SYMBOL_CLOCKS))
        return cls(tuple(sorted(rates)), tones, tuple(sorted(s2)))

    def stripe_gap_px(self, camera: CameraModel) -> int:
        """Longest dark stripe (rows) inside one lit LED, for detection's stripe merging."""
        if not camera.rolling_shutter:
            return GLOBAL_SHUTTER_GAP_PX
        gaps = [OOK_MAX_OFF_CHIPS * 1e6 / (r * camera.row_readout_us) for r in self.ook_rates]
        gaps += [1e6 / (2 * f * camera.row_readout_us) for f in self.tone_table.values()]
        if not gaps:
            return GLOBAL_SHUTTER_GAP_PX
        return int(math.ceil(max(gaps))) + STRIPE_GAP_MARGIN_ROWS

    def stripe_period_px(self, camera: CameraModel) -> float:
        """Rows within which a striped LED always shows a dark and a lit stripe."""
        if not camera.rolling_shutter:
            return 0.0
        per = [2 * OOK_MAX_OFF_CHIPS * 1e6 / (r * camera.row_readout_us) for r in self.ook_rates]
        per += [1e6 / (f * camera.row_readout_us) for f in self.tone_table.values()]
        return max(per) if per else 0.0

    def expect_stripes(self, camera: CameraModel) -> bool:
        """Every light stripes at full depth: rolling shutter, no S2-PSK, and an exposure no
        longer than the shortest ON/OFF run (one OOK chip, half a tone period; a longer
        exposure averages the stripes away)."""
        if not camera.rolling_shutter or self.s2psk or not (self.ook_rates or self.tone_table):
            return False
        shortest_us = [1e6 / r for r in self.ook_rates] + [1e6 / (2 * f) for f in self.tone_table.values()]
        return camera.exposure_us <= min(shortest_us)


def tone_runs_match(profile: np.ndarray, weights: np.ndarray, freq_hz: float, row_readout_us: float,
                    *, tol: float = TONE_RUN_TOL, min_weight_frac: float = 0.3) -> bool:
    """Do the profile's stripes have the runs of a `freq_hz` square wave? The median length of
    its interior ON and OFF runs (rows, split at the mid level) must be half a period within
    `tol`. Guards a tone match against an OOK light whose stripe spectrum happens to peak near
    a listed tone: OOK runs are 1-4 chips, a tone's are all half a period."""
    good = weights >= min_weight_frac * weights.max() if weights.size else weights
    idx = np.flatnonzero(good)
    if idx.size < 3:
        return False
    p = profile[idx[0]:idx[-1] + 1]
    lo, hi = np.percentile(p, [10, 90])
    on = p > 0.5 * (lo + hi)
    edges = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    runs = np.diff(edges)  # interior runs only: the first and last are cut by the envelope
    if runs.size == 0:
        return False
    half_rows = 1e6 / (2.0 * freq_hz * row_readout_us)
    return abs(float(np.median(runs)) / half_rows - 1.0) <= tol


def pair_owners(pairs) -> dict[int, object]:
    """track id -> the S2-PSK pair (receiver.vision.pairing.Pair) whose emitter it is this frame.
    A pair follows its emitters itself: the tracks whose blob it explained this frame
    (`Pair.tracks`) are its emitters, whichever track they are. A blob two pairs explain (an
    emitter of a wide, still undecoded pairing lying on another light) belongs to the decoded
    one; otherwise to the later pair."""
    owner: dict[int, object] = {}
    for p in pairs:
        for t in p.tracks:
            other = owner.get(t.track_id)
            if other is None or other.led_id is None or p.led_id is not None:
                owner[t.track_id] = p
    return owner


def _decode_info(t: Track, pair) -> dict:
    """Extra output fields of one LED: the measured tone frequency, the S2-PSK ID kind."""
    out = {}
    if pair is not None:
        if pair.kind is not None:
            out["kind"] = pair.kind
        return out
    st = t.states.get(("tone", 0.0))
    if st is not None and math.isfinite(getattr(st, "freq_hz", float("nan"))):
        out["freq_hz"] = round(float(st.freq_hz), 1)
    return out


def _intensity(gray: np.ndarray, track: Track) -> float:
    return mean_in_mask(gray, track.blob)


class Receiver:
    """Streaming receiver (init/process). One instance per camera stream.

    camera, led_map: receiver.io models (camera already scaled to the frame size).
    positioner: object with `step(t_s, leds) -> LocateResult`, or None (no distances/position).
    clock: seconds, monotonic; stamps the stages (tests inject a fake).
    detect_kw, tracker_kw, pairer_kw, ook_kw, tone_kw, s2psk_kw: keyword overrides for
    receiver.vision.detect.detect, Tracker, Pairer and the decoders.
    s2psk_inverted [False]: offer PROTOCOL.md's inverted polarity (thesis polarity default).
    redecode_every [8]: a track whose ID is known feeds its decoders only every this many
        frames (staggered by track), to keep the frame budget with many lights (issue 4: 16
        lights in 2 ms median); tracks without an ID are decoded every frame. 8 frames re-check
        a known ID every 0.27 s at 30 fps (a changed ID is taken after the decoder's
        `switch_frames` consecutive CRC-valid checks). 1 = always.
    stripe_check [None = from the map and camera, `ModePlan.expect_stripes`]: when every light
        must show rolling-shutter stripes, a new track is reported and decoded only once its
        row profile shows stripes (depth >= `min_stripe_depth` [0.8]) or it is shorter than a
        stripe period; flat bright regions (lamps, windows) stay silent.
    still [False]: the frames are unrelated photos (see STILL_MIN_REL_AREA).
    envelope_frames [None: 3 when lights stripe, else 1]: a striped LED's envelope is the
        hull of its blobs in the last this many frames, each moved by the track's velocity:
        the rows hidden by OFF chips in one frame are lit in another, so the caps (area eta,
        centroid) are recovered. 1 = this frame only.
    tone_confirm_frames [None: 1 for a tone-only map or photos, else 3]: consecutive frames a
        tone match must hold before it is reported; with OOK lights in the map, an OOK stripe
        pattern can show a spectral line near a listed tone for a frame or two.
    frame_clock [True], clock_refs [3]: while some track has no ID, the `clock_refs` tallest
        decoded OOK tracks of each chip rate are measured every frame (their frame's packet
        position against their known packet, `OokDecoder.row0_coordinate`) to give the
        frame's clock (receiver.decode.frameclock); undecoded OOK decoders get it as a timing hint,
        so small lights whose frames barely overlap are still assembled. Rolling shutter only.
    """

    def __init__(self, camera: CameraModel, led_map: LedMap, *, positioner=None,
                 clock=time.perf_counter, detect_kw: dict | None = None, tracker_kw: dict | None = None,
                 pairer_kw: dict | None = None, ook_kw: dict | None = None, tone_kw: dict | None = None,
                 s2psk_kw: dict | None = None, s2psk_inverted: bool = False, redecode_every: int = 8,
                 stripe_check: bool | None = None, min_stripe_depth: float = 0.8, still: bool = False,
                 tone_confirm_frames: int | None = None, envelope_frames: int | None = None,
                 frame_clock: bool = True, clock_refs: int = 3):
        self.camera, self.led_map = camera, led_map
        self.positioner = positioner
        self.clock = clock
        self.plan = ModePlan.from_map(led_map)
        kw = dict(stripe_gap_px=self.plan.stripe_gap_px(camera))
        if self.plan.s2psk:
            # One half of a far street-light head is a few px: the pairing sees it alone in
            # the frames where only that half is lit (receiver.vision.pairing).
            kw["min_area_px"] = S2PSK_MIN_AREA_PX
        kw.update(detect_kw or {})
        self.detect_kw = kw
        # The flat-region test runs once per new track on the row profile the decoders need
        # anyway, instead of in every frame's detection (receiver.vision.detect.stripe_depth).
        self.stripe_check = self.plan.expect_stripes(camera) if stripe_check is None else stripe_check
        self.min_stripe_rows = int(math.ceil(self.plan.stripe_period_px(camera)))
        self.min_stripe_depth = min_stripe_depth
        if tone_confirm_frames is None:
            tone_confirm_frames = 1 if still or not (self.plan.ook_rates or self.plan.s2psk) else 3
        self.tone_confirm_frames = max(1, int(tone_confirm_frames))
        if envelope_frames is None:
            envelope_frames = 3 if camera.rolling_shutter and not self.plan.s2psk and not still else 1
        self.envelope_frames = max(1, int(envelope_frames))
        if still:
            # One photo: no tracking to weed out reflections, so detection itself drops flat
            # regions first and then blobs much smaller than the biggest light.
            self.detect_kw = dict(expect_stripes=self.stripe_check, min_stripe_rows=self.min_stripe_rows,
                                  min_stripe_depth=min_stripe_depth, min_rel_area=STILL_MIN_REL_AREA,
                                  **self.detect_kw)
        self.tracker = Tracker(**(tracker_kw or {}))
        self.pairer = Pairer(**(pairer_kw or {})) if self.plan.s2psk else None
        self.ook_kw, self.tone_kw = ook_kw or {}, tone_kw or {}
        self.s2psk_kw = dict(s2psk_kw or {})
        self.s2psk_inverted = s2psk_inverted
        self.redecode_every = max(1, int(redecode_every))
        self._decoders = self._import_decoders()
        self._period_learners: dict = {}  # chip rate -> decode_ook.PeriodLearner (`_attach`)
        self.clocks = ({rate: FrameClock() for rate in self.plan.ook_rates}
                       if frame_clock and camera.rolling_shutter and not still else {})
        self.clock_refs = clock_refs
        self.frames = 0
        self.decoded_ids: set[int] = set()
        self.last_counts: dict[str, int] = {}

    def _import_decoders(self) -> dict:
        wanted = {"ook": bool(self.plan.ook_rates), "tone": bool(self.plan.tone_table),
                  "s2psk": bool(self.plan.s2psk)}
        mods = {mode: importlib.import_module(f"receiver.decode.{mode}") for mode, on in wanted.items() if on}
        if "ook" in mods:
            mods["ook"].crc8_table()  # built once here, not inside the first decoded frame
        return mods

    # -- decoder plumbing ----------------------------------------------------------------

    def _attach(self, track: Track) -> None:
        cam = self.camera
        if "ook" in self._decoders:
            ook = self._decoders["ook"]
            # Rows per chip is a constant of this camera and the rate: one learner per rate
            # serves every track, so a new track does not refine it again for its first frames.
            for rate in self.plan.ook_rates:
                if rate not in self._period_learners:
                    self._period_learners[rate] = ook.PeriodLearner(
                        self.ook_kw.get("period_frames", ook.PERIOD_FRAMES))
                track.decoders[("ook", rate)] = ook.OokDecoder(
                    rate, cam.row_readout_us, cam.exposure_us,
                    period_learner=self._period_learners[rate], **self.ook_kw)
        if "tone" in self._decoders:
            track.decoders[("tone", 0.0)] = self._decoders["tone"].ToneDecoder(
                self.plan.tone_table, cam.row_readout_us, **self.tone_kw)

    def _merge_all(self, seen: list[Track], k: int, shape) -> None:
        """Set each seen track's `envelope`: this frame's blob merged with its last
        `envelope_frames - 1` blobs (all tracks in one batch, receiver.vision.detect.merge_envelopes_many)."""
        if self.envelope_frames <= 1:
            for t in seen:
                t.envelope = t.blob
            return
        items = []
        for t in seen:
            keep = [(kh, h) for kh, h in t.history if 0 < k - kh < self.envelope_frames]
            # Moved by the tracker's px/frame velocity (its jitter from the hidden caps limits how
            # much a static scene gains; a moving one needs the motion).
            items.append((t.blob, [h + (t.vx * (k - kh), t.vy * (k - kh)) for kh, h in keep]))
            t.history = keep + [(k, t.blob.hull)]
        for t, env in zip(seen, merge_envelopes_many(items, shape)):
            t.envelope = env

    def _accept(self, mode: str, led_id: int | None, rate: float = 0.0) -> bool:
        """Is a check-passed decode an ID of this map (at this rate)?"""
        if led_id is None:
            return False
        led = self.led_map.leds.get(led_id)
        if led is None:
            if mode == "ook":
                return self.led_map.addressing == "xy"
            return mode == "s2psk" and led_id >= FV_ID_MIN and self.led_map.taillight is not None
        if led.mode != mode:
            return False
        if mode in ("ook", "s2psk") and rate:
            want = float(led.rate_hz or (DEFAULT_OOK_RATE_HZ if mode == "ook" else DEFAULT_S2PSK_CLK_HZ))
            return abs(want - rate) <= RATE_MATCH_REL * want
        return True

    def _clock_frame(self, gray: np.ndarray, tracks: list[Track], k: int, skip) -> dict:
        """{rate: ClockTick or None} of this frame, measured on decoded OOK tracks; empty
        when every seen track has its ID (nobody needs a clock)."""
        if not self.clocks or not any(t.seen and t.led_id is None and t.track_id not in skip
                                      for t in tracks):
            return {}
        ticks = {}
        for rate, clock in self.clocks.items():
            clock.begin(k)
            refs = [t for t in tracks if t.seen and t.mode == "ook" and t.track_id not in skip
                    and getattr(t.decoders.get(("ook", rate)), "led_id", None) is not None]
            refs.sort(key=lambda t: t.blob.y1 - t.blob.y0, reverse=True)
            n = 0
            for t in refs:
                if n >= self.clock_refs:
                    break
                profile, weights, y0 = row_profile(gray, t.envelope or t.blob)
                u = t.decoders[("ook", rate)].row0_coordinate(profile, weights, y0)
                if u is not None:
                    clock.observe(t.track_id, u)
                    n += 1
            ticks[rate] = clock.close()
        return ticks

    def _decode_track(self, gray: np.ndarray, t: Track, t_s: float, ticks: dict | None = None) -> None:
        profile, weights, y0 = row_profile(gray, t.envelope or t.blob)
        if not t.striped:
            tall = t.blob.y1 - t.blob.y0 >= max(self.min_stripe_rows, 3)
            if tall and stripe_depth(profile, weights, background=t.blob.background) < self.min_stripe_depth:
                return
            t.striped = True
        found: tuple[str, int] | None = None
        tone_id = None
        for (mode, rate), dec in t.decoders.items():
            if mode == "tone":  # the LED's whole striped extent, log intensity (tone_profile.py)
                st = dec.step(*tone_profile(gray, t.envelope or t.blob)[:2], t_s)
            elif ticks and ticks.get(rate) is not None:
                st = dec.step(profile, weights, t_s, clock=ticks[rate], y0=y0)
            else:
                st = dec.step(profile, weights, t_s)
            t.states[(mode, rate)] = st
            if mode == "tone":
                tone_id = st.led_id if self._accept(mode, st.led_id) else None
                if tone_id is not None and self.plan.ook_rates and not tone_runs_match(
                        profile, weights, self.plan.tone_table[tone_id], self.camera.row_readout_us):
                    tone_id = None
            elif found is None and self._accept(mode, st.led_id, rate):
                found = (mode, st.led_id)
        if found is not None:  # a CRC-checked ID beats a tone match, and stays
            t.mode, t.led_id = found
            return
        if t.mode == "ook":
            return
        # Tone: no CRC, so the match must hold `tone_confirm_frames` frames in a row and the
        # track follows the decoder (a lost match clears the ID).
        t.tone_run = t.tone_run + 1 if tone_id is not None and tone_id == t.tone_last else int(tone_id is not None)
        t.tone_last = tone_id
        ok = tone_id is not None and t.tone_run >= self.tone_confirm_frames
        t.led_id, t.mode = (tone_id, "tone") if ok else (None, None)

    def _new_pair_decoders(self) -> dict:
        """One S2-PSK decoder per (clock, symbol clocks) of the map: a pair is any of them."""
        kw = dict(self.s2psk_kw)
        kw.setdefault("inverted", self.s2psk_inverted)
        return {(clk, nsym): self._decoders["s2psk"].S2pskDecoder(clk, nsym, **kw)
                for clk, nsym in self.plan.s2psk}

    # -- the frame ----------------------------------------------------------------------

    def process(self, frame: Frame) -> FrameResult:
        timer = StageTimer(self.clock)
        gray = frame.gray
        blobs = detect(gray, **self.detect_kw)
        timer.stamp("detect")
        tracks = self.tracker.step(frame.index, blobs)
        self._merge_all([t for t in tracks if t.seen], frame.index, gray.shape)
        timer.stamp("track")

        pair_of: dict[int, object] = {}
        if self.pairer is not None:
            s2 = self._decoders["s2psk"]
            for p in self.pairer.step(gray, tracks, _intensity):
                if p.decoder is None:
                    p.decoder = self._new_pair_decoders()
                a, b = self.pairer.sample(p, gray, _intensity)
                x = s2.pair_xor(a, b, p.levels_a.on, p.levels_b.on, p.levels_a.off, p.levels_b.off)
                found = None
                for (clk, _), dec in p.decoder.items():
                    st = dec.step(frame.t_s, x)
                    if found is None and self._accept("s2psk", st.led_id, clk):
                        found = st
                    p.state = found or st
                if found is not None:
                    p.led_id, p.kind = found.led_id, getattr(found, "kind", None)
            pair_of = pair_owners(self.pairer.pairs)
            # An S2-PSK ID belongs to the pair, not to a blob track: a track no pair explains
            # this frame (it may have jumped to another light's blob) carries none.
            for t in tracks:
                p = pair_of.get(t.track_id)
                if p is not None:
                    t.led_id, t.mode = p.led_id, ("s2psk" if p.led_id is not None else t.mode)
                elif t.mode == "s2psk":
                    t.led_id, t.mode = None, None
            timer.stamp("pair")

        ticks = self._clock_frame(gray, tracks, frame.index, pair_of)
        for t in tracks:
            if not t.seen or t.track_id in pair_of:
                continue
            if not self.stripe_check:
                t.striped = True
            if not t.decoders:
                self._attach(t)
            if t.led_id is not None and (frame.index + t.track_id) % self.redecode_every:
                continue
            if t.decoders:
                self._decode_track(gray, t, frame.t_s, ticks)
        timer.stamp("decode")

        leds, info = [], {}
        for t in tracks:
            if not t.seen or not (t.striped or t.track_id in pair_of):
                continue
            b = t.envelope or t.blob
            extra = _decode_info(t, pair_of.get(t.track_id))
            if extra:
                info[t.track_id] = extra
            leds.append(LedObservation(track=t.track_id, cx=b.cx, cy=b.cy, area_px=b.area_px,
                                       contour=b.hull, border=b.border, id=t.led_id, mode=t.mode,
                                       peak=b.peak))
            if t.led_id is not None:
                self.decoded_ids.add(t.led_id)
        leds.sort(key=lambda o: o.track)
        timer.stamp("report")  # the frame's LED observations (the latency counts every stage)
        position, distances = None, {}
        if self.positioner is not None:
            res = self.positioner.step(frame.t_s, leds)
            position, distances = res.position, dict(res.distances)
            timer.stamp("locate")
        self.frames += 1
        self.last_counts = {"blobs": len(blobs), "tracks": len(tracks),
                            "decoded": sum(o.id is not None for o in leds),
                            "pairs": len(self.pairer.pairs) if self.pairer else 0}
        return FrameResult(frame.index, frame.t_s, timer.total_ms, leds, position, None,
                           dict(timer.stage_ms), distances, info)
