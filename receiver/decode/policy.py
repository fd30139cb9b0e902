"""The decoding policy: which decoders a light gets, when it is decoded, when an ID counts.

What is decoded follows the map (`ModePlan`): one OOK decoder per distinct OOK chip rate in the
map (an OOK ID counts only when the map lists it at that rate, or any ID under "xy"
addressing), tone decoding against the map's `freq_hz` table, S2-PSK decoding of pairs when
the map has S2-PSK lights or a `taillight` block. An ID is reported only when the decoder's
check passed (CRC for OOK / S2-PSK, the half-spacing window for tone) and the map knows it (or
the addressing is "xy", or it is a vehicle FV-ID, `accept`).

`LightDecoder` holds one tracked OOK / tone light's decoders and its ID (the tracker's tracks
carry geometry only); `PairDecoder` one S2-PSK pair's. The receiver keeps one per track / pair
key and drops it with its track.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from receiver.core import protocol
from receiver.decode.exposure import ExposureLearner, exposure_verdict
from receiver.decode.ook import OokDecoder, PeriodLearner, candidate_tables, crc8_table
from receiver.decode.pieces import FrameJitter, chips_verdict, word_bits
from receiver.decode.s2psk import S2pskDecoder, codebook
from receiver.decode.settings import OOK_TUNING, OokSettings, PolicySettings, S2pskSettings, ToneSettings
from receiver.decode.tone import ToneDecoder
from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap
from receiver.vision.detect import MIN_STRIPE_DEPTH
from receiver.vision.profile import stripe_depth
from receiver.vision.tone_profile import tone_profile

# Longest OFF run of an OOK stream in chips: the sync's OFF run (PROTOCOL.md section 1).
OOK_MAX_OFF_CHIPS = 4
# `DecodePolicy.chip_notes`: the chips a frame of the last CHIPS_SEEN striped OOK light images
# per rate, judged once CHIPS_MIN_IMAGES are there.
CHIPS_SEEN = 512
CHIPS_MIN_IMAGES = 10
# Rows added to the longest expected dark stripe (exposure edges, JPEG ringing).
STRIPE_GAP_MARGIN_ROWS = 2
# Dark-stripe gap bridged when the camera has a global shutter (no stripes).
GLOBAL_SHUTTER_GAP_PX = 2
# Tone match check in maps that also hold OOK lights: stripe runs within this of half a period.
TONE_RUN_TOL = 0.35
# Consecutive frames a tone match must hold before it is reported when the map also holds OOK or
# S2-PSK lights (tone has no CRC, and an OOK stripe pattern can show a spectral line near a
# listed tone for a frame or two); with a tone-only map or photos the first match is reported.
TONE_CONFIRM_FRAMES = 3
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
        rates = {float(led.rate_hz or protocol.OOK_RATE_HZ) for led in led_map.by_mode("ook")}
        if led_map.addressing == "xy":
            rates.add(float(led_map.default_rate_hz or protocol.OOK_RATE_HZ))
        tones = {led.id: float(led.freq_hz) for led in led_map.by_mode("tone")}
        s2 = {(float(led.rate_hz or protocol.S2PSK_CLOCK_HZ), int(led.symbol_clocks or protocol.S2PSK_SYMBOL_CLOCKS))
              for led in led_map.by_mode("s2psk")}
        if led_map.taillight is not None and not s2:
            s2.add((protocol.S2PSK_CLOCK_HZ, protocol.S2PSK_SYMBOL_CLOCKS))
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


def map_rates_hz(led_map: LedMap | None) -> tuple[list[float], list[float]]:
    """The map's OOK chip rates and tone frequencies (Hz) as the receiver decodes them
    (`ModePlan.from_map`: an OOK light without `rate_hz` runs at the protocol's rate)."""
    if led_map is None:
        return [], []
    plan = ModePlan.from_map(led_map)
    return list(plan.ook_rates), sorted(set(plan.tone_table.values()))


def tone_runs_match(profile: np.ndarray, weights: np.ndarray, freq_hz: float, row_readout_us: float,
                    *, tol: float = TONE_RUN_TOL, min_weight_frac: float = 0.3) -> bool:
    """Do the profile's stripes have the runs of a `freq_hz` square wave? The median length of
    its interior ON and OFF runs (rows, split at the mid level) must be half a period within
    `tol`. Guards a tone match against an OOK light whose stripe spectrum happens to peak near
    a listed tone: OOK runs are 1-4 chips, a tone's are all half a period."""
    good = weights >= min_weight_frac * weights.max() if weights.size else weights
    idx = good.nonzero()[0]
    if idx.size < 3:
        return False
    p = profile[idx[0]:idx[-1] + 1]
    lo, hi = np.percentile(p, [10, 90])
    on = p > 0.5 * (lo + hi)
    edges = np.diff(on.astype(np.int8)).nonzero()[0] + 1
    runs = np.diff(edges)  # interior runs only: the first and last are cut by the envelope
    if runs.size == 0:
        return False
    half_rows = 1e6 / (2.0 * freq_hz * row_readout_us)
    return abs(float(np.median(runs)) / half_rows - 1.0) <= tol


def accept(led_map: LedMap, mode: str, led_id: int | None, rate: float = 0.0) -> bool:
    """Is a check-passed decode an ID of this map (at this rate)?"""
    if led_id is None:
        return False
    led = led_map.leds.get(led_id)
    if led is None:
        if mode == "ook":
            return led_map.addressing == "xy"
        return mode == "s2psk" and led_id >= protocol.FV_ID_MIN and led_map.taillight is not None
    if led.mode != mode:
        return False
    if mode in ("ook", "s2psk") and rate:
        want = float(led.rate_hz or (protocol.OOK_RATE_HZ if mode == "ook" else protocol.S2PSK_CLOCK_HZ))
        return abs(want - rate) <= RATE_MATCH_REL * want
    return True


class LightDecoder:
    """One tracked OOK / tone light: its decoders, their latest states and its ID.

    `striped`: its row profile has shown stripes (or it needs none); `led_id`, `mode`: the ID
    and mode reported for it (None until decoded); `freq_hz`: the tone decoder's latest
    measured stripe frequency (NaN when none); `pieces_ref`: it shows short pieces of its
    packet, and so can measure the frames' jitter for the other lights (receiver.decode.pieces):
    while a light without its ID wants that (`measures_jitter`), it is fed every frame, its ID
    known or not."""

    def __init__(self, decoders: dict):
        self.decoders = decoders  # (mode, rate) -> decoder
        self.states: dict = {}
        self.led_id: int | None = None
        self.mode: str | None = None
        self.striped = False
        self._tone_last: int | None = None
        self._tone_run = 0
        self.pieces_ref = False
        self.jitters: tuple = ()  # the FrameJitter of each rate it shows pieces of

    def wants_near(self) -> bool:
        """It has no ID, and an OOK decoder of it holds pieces enough that this frame's makes a
        decision (`PieceAssembler.decide`): only then are the pose's map IDs asked for."""
        if self.led_id is not None or not self.pieces_ref:
            return False
        for (mode, _), dec in self.decoders.items():
            pa = dec.pieces if mode == "ook" else None
            if pa is not None and len(pa.pieces) + 1 >= pa.min_frames:
                return True
        return False

    def measures_jitter(self) -> bool:
        """It shows short pieces, and a light still without its ID wants the frames' jitter."""
        return self.pieces_ref and any(j.wanted() for j in self.jitters)

    @property
    def freq_hz(self) -> float:
        st = self.states.get(("tone", 0.0))
        return float(getattr(st, "freq_hz", float("nan"))) if st is not None else float("nan")

    def decoder(self, mode: str, rate: float):
        return self.decoders.get((mode, rate))


class DecodePolicy:
    """Makes and runs the decoders of a receiver's lights (one `LightDecoder` per track, one
    `PairDecoder` dict per S2-PSK pair) by `PolicySettings` and the map's `ModePlan`."""

    def __init__(self, camera: CameraModel, led_map: LedMap, plan: ModePlan, settings: PolicySettings,
                 *, ook: OokSettings, tone: ToneSettings, s2psk: S2pskSettings, min_stripe_rows: int,
                 still: bool = False):
        self.camera, self.led_map, self.plan, self.settings = camera, led_map, plan, settings
        # frames a tone match holds before it is reported (TONE_CONFIRM_FRAMES); `still`: photos
        self.tone_confirm_frames = 1 if still or not (plan.ook_rates or plan.s2psk) else TONE_CONFIRM_FRAMES
        self.ook, self.tone, self.s2psk = ook, tone, s2psk
        self.min_stripe_rows = min_stripe_rows
        if plan.ook_rates:
            crc8_table()  # built once here, not inside the first decoded frame
        if plan.s2psk and s2psk.soft_min_z > 0:
            codebook()  # the soft decoder's hypotheses: here, not inside the first soft decode
        # Rows per chip is a constant of this camera and the rate: one learner per rate serves
        # every track, so a new track does not refine it again for its first frames.
        self.period_learners = {rate: PeriodLearner() for rate in plan.ook_rates}
        # the map's IDs per OOK rate (map addressing): the candidates of a light whose frames
        # show only short pieces of its packet (receiver.decode.pieces)
        self.candidates = {}
        if led_map.addressing != "xy" and camera.rolling_shutter:
            for rate in plan.ook_rates:
                ids = sorted(led.id for led in led_map.by_mode("ook")
                             if accept(led_map, "ook", led.id, rate))
                # their tables made once, shared by every light's decoder
                self.candidates[rate] = candidate_tables(np.array(ids, dtype=np.int64))
            if self.candidates and not still:  # a video's lights may be decided near the pose
                word_bits()  # the 65,536 packets' bits (`PieceAssembler._decide_near`), not inside a frame
        # each frame's start jitter, measured by the lights of the frame for one another
        self.frame_jitters = {rate: FrameJitter() for rate in self.candidates}
        # frames each light took to its ID pieced together from short pieces, per rate (`chip_notes`)
        self.pieces_took: dict = {rate: [] for rate in self.candidates}
        # chips per frame of the striped OOK lights' images, per rate (`chip_notes`)
        self.chips_seen = ({rate: deque(maxlen=CHIPS_SEEN) for rate in plan.ook_rates}
                           if camera.rolling_shutter else {})
        # the exposure, when the camera file does not state it, is learned from the stripes
        self.exposure_learners = ({rate: ExposureLearner() for rate in plan.ook_rates}
                                  if camera.rolling_shutter and camera.exposure_us <= 0 else {})

    def exposure_notes(self) -> list[tuple[bool, str]]:
        """(readable, text) per OOK chip rate: the exposure (camera file, or learned from the
        stripes so far) against the chips (`receiver.decode.exposure.exposure_verdict`)."""
        out = []
        if not self.camera.rolling_shutter:
            return out
        for rate in self.plan.ook_rates:
            exp_us = self.camera.exposure_us
            how = "camera file"
            if exp_us <= 0:
                lr = self.exposure_learners.get(rate)
                if lr is None or lr.exposure_rows is None:
                    out.append((True, f"exposure unknown (not in the camera file, not yet seen in stripes) "
                                      f"for the {rate / 1000:g} kHz OOK chips"))
                    continue
                exp_us, how = lr.exposure_rows * self.camera.row_readout_us, "from the stripes' edges"
            ok, text = exposure_verdict(exp_us, rate)
            out.append((ok, f"{text} ({how})"))
        return out

    def absorb_notes(self, earlier: "DecodePolicy | None") -> "DecodePolicy":
        """This policy with `earlier`'s note evidence added (the policy of another receiver of
        the same map, e.g. an earlier photo's): its chips a frame, and its exposure estimates
        where this one has not learned the exposure. Call it once this policy is done decoding
        (its exposure learners also serve its decoders). Returns self, the tally to pass on."""
        if earlier is None or earlier is self:
            return self
        for rate, seen in earlier.chips_seen.items():
            if rate in self.chips_seen:  # the earlier images first: the deque keeps the latest
                both = deque(seen, maxlen=CHIPS_SEEN)
                both.extend(self.chips_seen[rate])
                self.chips_seen[rate] = both
        for rate, took in earlier.pieces_took.items():
            if rate in self.pieces_took:
                self.pieces_took[rate] = took + self.pieces_took[rate]
        for rate, lr in self.exposure_learners.items():
            old = earlier.exposure_learners.get(rate)
            if lr.exposure_rows is None and old is not None:
                lr.estimates = old.estimates + lr.estimates
                if len(lr.estimates) >= lr.frames:
                    lr.exposure_rows = float(np.median(lr.estimates))
        return self

    def chip_notes(self) -> list[str]:
        """Per OOK chip rate whose lights' images showed at most `OokSettings.pieces_max_chips`
        chips a frame (median over the striped light images fed): a line with the numbers, how
        many frames an ID needs (`receiver.decode.pieces.chips_verdict`; and how many it took the
        lights decoded so far), and the chip rate or image height that would give more."""
        out = []
        limit = float(self.ook.pieces_max_chips)
        for rate, seen in self.chips_seen.items():
            if len(seen) < CHIPS_MIN_IMAGES or limit <= 0:
                continue
            med = float(np.median(np.fromiter(seen, float)))
            if med > limit or med <= 0:
                continue
            _, text = chips_verdict(med, rate, max_chips=limit, min_frames=OOK_TUNING.pieces_min_frames,
                                    mapped=rate in self.candidates)
            took = self.pieces_took.get(rate)
            if took:
                text += (f" ({len(took)} light{'s' if len(took) > 1 else ''} pieced together here after a median of "
                         f"{float(np.median(took)):.0f} frames)")
            out.append(text)
        return out

    def new_light(self) -> LightDecoder:
        cam = self.camera
        decoders = {}
        for rate in self.plan.ook_rates:
            decoders[("ook", rate)] = OokDecoder(rate, cam.row_readout_us, cam.exposure_us, settings=self.ook,
                                                 period_learner=self.period_learners[rate],
                                                 exposure_learner=self.exposure_learners.get(rate),
                                                 candidates=self.candidates.get(rate),
                                                 frame_jitter=self.frame_jitters.get(rate))
        if self.plan.tone_table:
            decoders[("tone", 0.0)] = ToneDecoder(self.plan.tone_table, cam.row_readout_us, settings=self.tone)
        return LightDecoder(decoders)

    def new_pair_decoders(self) -> dict:
        """One S2-PSK decoder per (clock, symbol clocks) of the map: a pair is any of them."""
        return {(clk, nsym): S2pskDecoder(clk, nsym, settings=self.s2psk) for clk, nsym in self.plan.s2psk}

    def pair_due(self, led_id: int | None, frame_index: int, uid: int) -> bool:
        """Decode an S2-PSK pair's samples in this frame? One whose ID is known only every
        `redecode_every_frames` frames (staggered by pair); its samples are stored every frame.
        (`due` asks the same of a light, staggered by its track id.)"""
        return led_id is None or not (frame_index + uid) % self.settings.redecode_every_frames

    def due(self, light: LightDecoder, frame_index: int, track_id: int) -> bool:
        """Decode this light in this frame? A light whose ID is known feeds its decoders only
        every `redecode_every_frames` frames (staggered by track), unless it measures the frames'
        jitter for the others (`LightDecoder.measures_jitter`)."""
        return light.measures_jitter() or self.pair_due(light.led_id, frame_index, track_id)

    def step_light(self, light: LightDecoder, gray: np.ndarray, blob, profile_wy, t_s: float,
                   ticks: dict | None = None, near: tuple = ()) -> None:
        """Feed one frame of one light: `blob` its envelope, `profile_wy` its row profile
        (profile, weights, y0) as `receiver.vision.profile.row_profile` gives it; `near` the map
        IDs the tracked pose puts where the light is (receiver.locate.map_prior), which its
        OOK decoders' pieces may be tested against."""
        profile, weights, y0 = profile_wy
        if not light.striped:
            tall = blob.y1 - blob.y0 >= max(self.min_stripe_rows, 3)
            if tall and stripe_depth(profile, weights, background=blob.background) < MIN_STRIPE_DEPTH:
                return
            light.striped = True
        found: tuple[str, int] | None = None
        tone_id = None
        for (mode, rate), dec in light.decoders.items():
            if mode == "tone":  # the LED's whole striped extent, log intensity (tone_profile.py)
                st = dec.step(*tone_profile(gray, blob)[:2], t_s)
            else:
                if rate in self.chips_seen:  # this image's chips a frame (`chip_notes`)
                    self.chips_seen[rate].append(len(profile) * rate * self.camera.row_readout_us * 1e-6)
                if ticks and ticks.get(rate) is not None:
                    st = dec.step(profile, weights, t_s, clock=ticks[rate], y0=y0, near=near)
                else:
                    st = dec.step(profile, weights, t_s, y0=y0, near=near)
            light.states[(mode, rate)] = st
            jitter = getattr(dec.pieces, "frame_jitter", None) if mode == "ook" else None
            if jitter is not None and jitter not in light.jitters and dec.pieces.added > 0:
                light.pieces_ref = True
                light.jitters += (jitter,)
            if mode == "tone":
                tone_id = st.led_id if accept(self.led_map, mode, st.led_id) else None
                if tone_id is not None and self.plan.ook_rates and not tone_runs_match(
                        profile, weights, self.plan.tone_table[tone_id], self.camera.row_readout_us):
                    tone_id = None
            elif found is None and accept(self.led_map, mode, st.led_id, rate):
                found = (mode, st.led_id)
        if found is not None:  # a CRC-checked ID beats a tone match, and stays
            if light.led_id is None and found[0] == "ook":
                for (mode, rate), dec in light.decoders.items():
                    if mode == "ook" and dec.pieces_took and rate in self.pieces_took:
                        self.pieces_took[rate].append(dec.pieces_took)
            light.mode, light.led_id = found
            return
        if light.mode == "ook":
            return
        # Tone: no CRC, so the match must hold `tone_confirm_frames` frames in a row and the
        # light follows the decoder (a lost match clears the ID).
        same = tone_id is not None and tone_id == light._tone_last
        light._tone_run = light._tone_run + 1 if same else int(tone_id is not None)
        light._tone_last = tone_id
        ok = tone_id is not None and light._tone_run >= self.tone_confirm_frames
        light.led_id, light.mode = (tone_id, "tone") if ok else (None, None)

    def step_pair(self, decoders: dict, t_s: float, xor: float, decode: bool = True):
        """Feed one pair's soft XOR of this frame; (accepted state or None, latest state).
        `decode` False: the samples are only stored (`pair_due`)."""
        found = state = None
        for (clk, _), dec in decoders.items():
            st = dec.step(t_s, xor, decode)
            # (accept() is False for no ID: not asked then, ~35 steps a frame on vehicle)
            if found is None and st.led_id is not None and accept(self.led_map, "s2psk", st.led_id, clk):
                found = st
            state = found or st
        return found, state

