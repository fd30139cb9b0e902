"""The receiver orchestrator: frame -> blobs -> tracks -> decoded LEDs -> position.

    rx = Receiver(camera, led_map, positioner=None)
    for frame in source:
        result = rx.process(frame)      # FrameResult

Stages, each stamped with the injected clock (`FrameResult.stage_ms`, receiver.core.budget):
`detect` (receiver.vision.detect), `track` (receiver.vision.track and the envelope merge,
receiver.vision.envelope), `pair` (S2-PSK pairs, receiver.vision.pairing, and their soft XOR
decoded by receiver.decode.s2psk), `decode` (row profiles -> OOK / tone decoders, by the
policy of receiver.decode.policy; a light still without its ID is also told which map IDs the
positioner's tracked pose puts where it is, `MapPrior` of receiver.locate.map_prior, made from
the frames before this one), `report` (the frame's LED and pair observations), `locate`
(the positioner, when one is given: it returns the observations with their ranges).

Data between stages are the records of receiver.core.records; every tunable is in
`ReceiverSettings` (nested per stage), and `Receiver.settings` is what a run actually used
(the map- and camera-dependent defaults resolved).
"""

from __future__ import annotations

import dataclasses
import math
import operator
import time
from dataclasses import dataclass, field

import numpy as np

from receiver.core.budget import StageTimer
from receiver.core.native import require
from receiver.core.records import Frame, FrameResult, LedObservation, PairObservation, frozen_record, led_observation
from receiver.core.settings import resolve_settings
from receiver.decode.frameclock import FrameClock
from receiver.decode.policy import DecodePolicy, LightDecoder, ModePlan
from receiver.decode.pair_decoding import PairDecoding
from receiver.decode.settings import OokSettings, PolicySettings, S2pskSettings, ToneSettings
from receiver.io.camera import CameraModel
from receiver.io.ledmap import LedMap
from receiver.locate.map_prior import near_ids
from receiver.vision.camera_motion import CameraMotion, MotionEstimate, MotionSettings
from receiver.vision.detect import SATURATED_GRAY, Scratch, detect
from receiver.vision.envelope import EnvelopeHistory
from receiver.vision.motion import pair_dx, vertical_shift
from receiver.vision.outline import stripe_edge_points_batch
from receiver.vision.pairing import TUNING, Pairer
from receiver.vision.profile import peak_in_mask, row_profile
from receiver.vision.settings import DetectSettings, PairSettings, TrackSettings
from receiver.vision.track import Track, Tracker
from receiver.vision.track import preload as preload_assignment

# Detection of faint far emitters, the default with S2-PSK lights in the map (a far street-light
# head's half is 1-5 px^2 peaking 20-50 gray): the threshold follows the measured background
# noise (receiver.vision.detect.noise_sigma, resolved below one gray) at 12 sigmas, ~5 gray on a
# dark sensor of ~0.4 gray noise (at 8 a truncated noise of 2 gray lights single-pixel specks),
# with a floor of 4 gray (8-bit rounding); noise then lights no pixel, so the area floor is one
# lit pixel (hull area with the half-pixel rim: pi / 4). Components under 3 rows skip the shape
# test (a sub-pixel-tall panel seen from below is one or two rows several px wide) and the aspect
# limit is 12 (two blurred halves of a far head side by side are ~18 x 4 px; a near head seen
# from below is a 23 x 6 px bar at 27 m).
S2PSK_FAINT_DETECT = dict(min_area_px=0.75, k_mad=12.0, fine_noise=True, min_contrast=4.0, shape_min_rows=3, max_aspect=12.0)
# While some track has no ID, the CLOCK_REFS tallest decoded OOK tracks of each chip rate are
# measured every frame (their packet position, `OokDecoder.row0_coordinate`) to give the frame's
# clock (receiver.decode.frameclock), the timing hint that lets small lights whose frames barely
# overlap be assembled. Rolling shutter only. Cost: one row profile and packet match per reference
# per frame, only while a light lacks its ID; more references outvote a slipped one.
CLOCK_REFS = 3
# Frames whose blobs vote for the camera's frame-to-frame shift (receiver.vision.motion).
SHAKE_FRAMES = 3
# Photos: blobs smaller than this fraction of the biggest are reflections (receiver.vision.detect).
STILL_MIN_REL_AREA = 0.25


@dataclass(frozen=True)
class ReceiverSettings:
    """Everything tunable in a receiver, one record per stage (each documents its fields).

    `detect` [None: from the map and camera: the stripe gap from the chip / tone periods, the
    S2-PSK emitter minimum area, the photo filters]; `envelope_frames` [None: 3 when lights
    stripe (rolling shutter, no S2-PSK, not photos), else 1]: a striped LED's envelope is the
    hull of its blobs in the last this many frames (receiver.vision.envelope; the rows hidden
    by OFF chips in one frame are lit in another, so the caps, area eta and centroid, are
    recovered); `motion`: the camera-motion estimate of `PairSettings.shake` "motion"
    (receiver.vision.camera_motion); PROTOCOL.md's inverted S2-PSK polarity is
    `S2pskSettings.inverted`. `Receiver.settings` holds the resolved record: no None left where
    a default was derived.
    """

    detect: DetectSettings | None = None
    track: TrackSettings = field(default_factory=TrackSettings)
    pair: PairSettings = field(default_factory=PairSettings)
    ook: OokSettings = field(default_factory=OokSettings)
    tone: ToneSettings = field(default_factory=ToneSettings)
    s2psk: S2pskSettings = field(default_factory=S2pskSettings)
    policy: PolicySettings = field(default_factory=PolicySettings)
    envelope_frames: int | None = None
    motion: MotionSettings = field(default_factory=MotionSettings)


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


def pair_observation(p, white_gray: float = math.inf) -> PairObservation:
    """The record of one live pair in this frame (see `PairObservation`); `white_gray`: the gray
    level at which a blob's peak is clipped (receiver.vision.detect.SATURATED_GRAY)."""
    a, b = p.a.blob, p.b.blob
    return frozen_record(PairObservation, dict(
        key=p.key, led_id=p.reported_id, kind=p.kind, a_px=(a.cx, a.cy), b_px=(b.cx, b.cy),
        area_a_px=a.area_px, area_b_px=b.area_px, separation_px=math.hypot(b.cx - a.cx, b.cy - a.cy),
        both_visible=p.both_seen, a_seen=_seen(p.obs_a, p.frames), b_seen=_seen(p.obs_b, p.frames),
        founding=p.founding, a_saturated=_clipped(p.obs_a, a, white_gray), b_saturated=_clipped(p.obs_b, b, white_gray)))


def _clipped(obs, blob, white_gray: float) -> bool:
    """Whether an emitter's own blob (else the pair's current one) peaked at `white_gray`."""
    src = blob if obs is None else obs[0]
    return bool(src.peak >= white_gray)


def _seen(obs, frames: int):
    """PairObservation.a_seen / b_seen of a pair's (blob, frames count) record, or None."""
    if obs is None:
        return None
    blob, f = obs
    return (blob.cx, blob.cy), blob.area_px, frames - f


def _with_pair_ranges(leds: list[LedObservation], pair_of: dict, pairs: list, ranges) -> list[LedObservation]:
    """Each S2-PSK emitter observation with its pair's range (`ranges` aligned with `pairs`;
    an entry is (distance_m, sigma_m, estimator) or None: no range from half a pair)."""
    by_uid = {p.uid: r for p, r in zip(pairs, ranges) if r is not None}
    if not by_uid:
        return leds
    out = []
    for o in leds:
        p = pair_of.get(o.track)
        r = by_uid.get(p.uid) if p is not None else None
        out.append(o if r is None else led_observation(**{**o.__dict__, "distance_m": round(float(r[0]), 5),
                                                          "distance_estimator": r[2]}))
    return out


# the compiled LED records of `_report` (receiver/vision/_track.pyx `led_records`), the one
# implementation (the module is `Tracker.step`'s too)
_kt = require("receiver.vision._track")


# an observation's sort key (its track id), read in C
_TRACK = operator.attrgetter("track")
_ID = operator.attrgetter("id")


def _intensity(gray: np.ndarray, track: Track) -> float:
    """An S2-PSK emitter's intensity: the highest gray in its envelope (profile.peak_in_mask)."""
    return peak_in_mask(gray, track.blob)


class Receiver:
    """Streaming receiver (init/process). One instance per camera stream.

    camera, led_map: receiver.io models (camera already scaled to the frame size).
    positioner: object with `step(t_s, leds) -> LocateResult` (its `leds` are the given
        observations with their ranges), or None (no distances, no position).
    vehicle: the vehicle locator (receiver.locate.vehicle.VehicleLocator: `step(t_s, pairs,
        speed_mps) -> VehicleResult`), or None: street lights and taillight pairs are then
        decoded but not ranged, and `FrameResult.vehicle` stays None.
    speed: `speed(t_s) -> m/s or None`, the host vehicle's odometry (optional).
    clock: seconds, monotonic; stamps the stages (tests inject a fake).
    still [False]: the frames are unrelated photos (see STILL_MIN_REL_AREA).
    settings: ReceiverSettings; `overrides`: its top-level fields by name (e.g.
        `envelope_frames=1`), and the policy's (`redecode_every_frames`, `stripe_check`).
    """

    def __init__(self, camera: CameraModel, led_map: LedMap, *, positioner=None, vehicle=None, speed=None,
                 clock=time.perf_counter, still: bool = False, settings: ReceiverSettings | None = None,
                 **overrides):
        policy_names = {f.name for f in dataclasses.fields(PolicySettings)}
        policy_kw = {k: overrides.pop(k) for k in list(overrides) if k in policy_names}
        s = resolve_settings(settings, ReceiverSettings, overrides)
        if policy_kw:
            s = dataclasses.replace(s, policy=dataclasses.replace(s.policy, **policy_kw))
        self.camera, self.led_map = camera, led_map
        self.positioner = positioner
        # the positioner's prediction of where the map's lights appear (`map_prior`), if it has one
        self._map_prior = getattr(positioner, "map_prior", None) if not still else None
        if not still:             # before the first frame, not inside the second one's latency
            preload_assignment()
        self.speed = speed
        self.clock = clock
        self.plan = plan = ModePlan.from_map(led_map)
        self.vehicle = vehicle if plan.s2psk else None
        self.settings = s = self._resolve(s, camera, plan, still)
        self.min_stripe_rows = int(math.ceil(plan.stripe_period_px(camera)))
        self.stripe_check = s.policy.stripe_check
        self.scratch = Scratch()  # detection's work buffers, kept across frames
        self.tracker = Tracker(settings=s.track)
        self.envelopes = EnvelopeHistory(s.envelope_frames)
        self.pairer = (Pairer(settings=s.pair, new_id=self.tracker.new_id, white_gray=SATURATED_GRAY)
                       if plan.s2psk else None)
        self.policy = DecodePolicy(camera, led_map, plan, s.policy, ook=s.ook, tone=s.tone, s2psk=s.s2psk,
                                   min_stripe_rows=self.min_stripe_rows, still=still)
        self.lights: dict[int, LightDecoder] = {}  # track id -> its decoding state
        self.pair_decoding = PairDecoding(self.policy)  # every live pair's S2-PSK decoders
        self.clocks = ({rate: FrameClock() for rate in plan.ook_rates}
                       if camera.rolling_shutter and not still else {})
        self._prev_xy: list = []  # the last frames' blob centroids, shifted to the previous frame's view
        self.shift = None  # this frame's common image shift, px (S2-PSK maps)
        # the camera-motion estimate from all blobs (`shake` "motion"), and its latest frame's
        self.motion = (CameraMotion((camera.cx, camera.cy), s.motion)
                       if plan.s2psk and s.pair.shake == "motion" else None)
        self.motion_estimate: MotionEstimate | None = None
        self.frames = 0
        self.decoded_ids: set[int] = set()
        self.last_counts: dict[str, int] = {}

    @staticmethod
    def _resolve(s: ReceiverSettings, camera: CameraModel, plan: ModePlan, still: bool) -> ReceiverSettings:
        """The settings with every map- and camera-derived default filled in."""
        pol = s.policy
        stripe_check = plan.expect_stripes(camera) if pol.stripe_check is None else pol.stripe_check
        pol = dataclasses.replace(pol, stripe_check=stripe_check,
                                  redecode_every_frames=max(1, int(pol.redecode_every_frames)))
        env = s.envelope_frames
        if env is None:
            env = 3 if camera.rolling_shutter and not plan.s2psk and not still else 1
        det = s.detect
        if det is None:
            kw = dict(stripe_gap_px=plan.stripe_gap_px(camera))
            if plan.s2psk:
                # One half of a far street-light head is a few px: the pairing sees it alone
                # in the frames where only that half is lit (receiver.vision.pairing).
                kw.update(S2PSK_FAINT_DETECT)
            if still:
                # One photo: no tracking to weed out reflections, so detection itself drops
                # flat regions first and then blobs much smaller than the biggest light.
                kw.update(stripe_check_rows=max(1, int(math.ceil(plan.stripe_period_px(camera)))) if stripe_check else 0,
                          min_rel_area=STILL_MIN_REL_AREA)
            det = DetectSettings(**kw)
        return dataclasses.replace(s, detect=det, policy=pol, envelope_frames=max(1, int(env)))

    def _light(self, track_id: int) -> LightDecoder:
        light = self.lights.get(track_id)
        if light is None:
            light = self.lights[track_id] = self.policy.new_light()
        return light

    def _clock_frame(self, gray: np.ndarray, seen: list[Track], env: dict, k: int, skip,
                     profiles: dict, lights: list[LightDecoder] | None = None) -> dict:
        """{rate: ClockTick or None} of this frame, measured on decoded OOK tracks; empty
        when every seen track has its ID (nobody needs a clock). `profiles`: this frame's row
        profiles by track id, filled here and reused by the decoders. `lights`: each seen
        track's `LightDecoder` (looked up here when None)."""
        if not self.clocks:
            return {}
        if lights is None:
            lights = [self._light(t.track_id) for t in seen]
        for t, light in zip(seen, lights):
            if light.led_id is None and t.track_id not in skip:
                break
        else:
            return {}
        ticks = {}
        for rate, clock in self.clocks.items():
            clock.begin(k)
            refs = []
            for t in seen:
                light = self._light(t.track_id)
                dec = light.decoder("ook", rate)
                if light.mode == "ook" and t.track_id not in skip and getattr(dec, "led_id", None) is not None:
                    refs.append(t)
            refs.sort(key=lambda t: t.blob.y1 - t.blob.y0, reverse=True)
            n = 0
            for t in refs:
                if n >= CLOCK_REFS:
                    break
                prof = profiles.get(t.track_id)
                if prof is None:
                    prof = profiles[t.track_id] = row_profile(gray, env[t.track_id])
                profile, weights, y0 = prof
                u = self.lights[t.track_id].decoder("ook", rate).row0_coordinate(profile, weights, y0)
                if u is not None:
                    clock.observe(t.track_id, u)
                    n += 1
            ticks[rate] = clock.close()
        return ticks

    def _pairs(self, gray: np.ndarray, frame: Frame, tracks: list[Track]) -> dict:
        """Follow and decode the S2-PSK pairs; {track id: owning pair} of this frame."""
        from receiver.vision.profile import peak_in_masks  # every emitter of the frame in one call

        def intensities(g, ts):
            return peak_in_masks(g, [t.blob for t in ts])
        live = self.pairer.step(gray, tracks, _intensity, shift=self.shift, t_s=frame.t_s, intensities=intensities)
        samples = self.pairer.sample_all(live, gray, intensities)
        # the far heads also read by their whole flux (below), all in one call
        by_flux = [p for p in live if p.led_id is None and self.pairer.reads_flux(p)]
        fluxes = dict(zip([p.uid for p in by_flux], self.pairer.sample_fluxes(by_flux, gray)))
        for p, (a, b) in zip(live, samples):
            flux = (fluxes[p.uid], self.pairer.flux_on(p)) if p.uid in fluxes else None
            self.pair_decoding.step(p, frame.t_s, frame.index, a, b, flux)
        self.pair_decoding.keep({p.uid for p in live})
        pair_of = pair_owners(self.pairer.pairs)
        # An S2-PSK ID belongs to the pair, not to a blob track: a track no pair explains
        # this frame (it may have jumped to another light's blob) carries none.
        for t in tracks:
            p = pair_of.get(t.track_id)
            light = self._light(t.track_id)
            if p is not None:
                light.led_id, light.mode = p.reported_id, ("s2psk" if p.reported_id is not None else light.mode)
            elif light.mode == "s2psk":
                light.led_id, light.mode = None, None
        return pair_of

    def _frame_shift(self, blobs) -> tuple[float, float] | None:
        """The frame's common image shift (dx, dy) px from the camera's shake, or None (`shake`
        "pitch", or not measurable): `PairSettings.shake` "vertical" or "pairs"
        (receiver.vision.motion), or "motion" (receiver.vision.camera_motion: every blob on
        the lights it belongs to, the pairs' shift one candidate among the blobs' own; none in
        the first frame)."""
        shake = self.settings.pair.shake
        if self.pairer is None or shake not in ("vertical", "pairs", "motion"):
            return None
        xy = np.array([(b.cx, b.cy) for b in blobs], float).reshape(-1, 2)
        shift = self._pairs_shift(blobs, xy, "pairs" if shake == "motion" else shake)
        if self.motion is not None:
            est = self.motion_estimate = self.motion.step(xy, np.array([b.area_px for b in blobs], float),
                                                          candidates=() if shift is None else (shift,))
            shift = (est.dx_px, est.dy_px) if self.motion.frames > 1 else None
        s_ = shift or (0.0, 0.0)
        # the older frames' blobs, moved by this frame's shift (as if seen in this view)
        self._prev_xy = [xy] + [old + s_ for old in self._prev_xy[:SHAKE_FRAMES - 1]]
        return shift

    def _pairs_shift(self, blobs, xy: np.ndarray, shake: str) -> tuple[float, float] | None:
        """The shift of `shake` "vertical" (pitch from every blob) or "pairs" (and the yaw that
        puts the blobs where the pairs expect them)."""
        # Road vibration shifts every far light alike, in pitch and yaw, by up to several px per
        # frame: the blobs' common displacement (receiver.vision.motion) goes into every track's
        # and pair's prediction.
        ps = self.settings.pair
        r = ps.shake_radius_px
        votes = [self.pairer.shift_votes(xy, r)]
        for old in self._prev_xy[1:]:  # older frames vote too (each head blinks)
            votes.append((xy[None, :, :] - old[:, None, :]).reshape(-1, 2))
        prev = self._prev_xy[0] if self._prev_xy else np.zeros((0, 2))
        dy = vertical_shift(prev, xy, radius_px=r, extra=np.concatenate(votes))
        shift = None if dy is None else (0.0, dy)
        if shift is not None and shake == "pairs":
            # the horizontal shift (yaw) that puts the blobs where the pairs expect them
            k = TUNING
            dx = pair_dx(self.pairer.dx_offsets(blobs, xy, dy, r), radius_px=r, sigma_px=k.shake_sigma_px,
                         step_px=k.shake_step_px, zero_rel=k.shake_zero_rel)
            shift = (dx or 0.0, dy)
        return shift

    def _report(self, gray: np.ndarray, seen: list[Track], lights: list[LightDecoder], env: dict,
                pair_of: dict) -> tuple[list[LedObservation], dict, tuple]:
        """The frame's observations: (LEDs sorted by track, {LED id: its S2-PSK pair}, the pairs'
        records). `lights`: each seen track's `LightDecoder`."""
        # A reported pair's blobs, and the blobs by its emitters it did not take (not paired anew
        # while it lives), are reported as the pair's emitters below; a pair coasting longer than
        # `report_coast_frames` reports nothing, so the blobs near it stay in the output.
        covered = {t.track_id for p in self.pairer.pairs if p.misses <= self.pairer.report_coast_frames
                   for t in p.nearby} if self.pairer is not None else ()
        decoded = self.decoded_ids
        # The LED records, and the outline points of decoded OOK / tone LEDs for the positioner
        # (receiver.vision.outline: `want`, measured in one batch, then set in their records).
        leds, want, want_fields = _kt.led_records(seen, lights, env, pair_of, covered, decoded, self.positioner is not None,
                                          bool(self.plan.tone_table), LedObservation)
        if want:
            edges = stripe_edge_points_batch(gray, [env[k] for k in want])
            for fields, e in zip(want_fields, edges):
                if fields is not None:
                    fields["edge_px"] = e
        emitter_of = {}  # LED id -> its S2-PSK pair
        if self.pairer is not None:
            for oid, b, p in self.pairer.emitters():
                emitter_of[oid] = p
                rid = p.reported_id
                leds.append(led_observation(oid, b.cx, b.cy, b.area_px, b.hull, b.border, rid,
                                            "s2psk" if rid is not None else None, b.peak, kind=p.kind))
                if rid is not None:
                    decoded.add(rid)
        leds.sort(key=_TRACK)
        white = SATURATED_GRAY
        pairs = tuple(pair_observation(p, white) for p in self.pairer.pairs) if self.pairer is not None else ()
        return leds, emitter_of, pairs

    # -- the frame ----------------------------------------------------------------------

    def process(self, frame: Frame) -> FrameResult:
        timer = StageTimer(self.clock)
        gray = frame.gray
        k = frame.index
        blobs = detect(gray, settings=self.settings.detect, scratch=self.scratch)
        timer.stamp("detect")
        shift = self._frame_shift(blobs) if self.pairer is not None else None
        self.shift = shift
        tracks = self.tracker.step(k, blobs, shift=shift)
        lights_of = self.lights
        for t in self.tracker.ended:
            lights_of.pop(t.track_id, None)
        seen = [t for t in tracks if t.seen]
        env = self.envelopes.step(seen, k, gray.shape)
        timer.stamp("track")

        pair_of: dict[int, object] = {}
        if self.pairer is not None:
            pair_of = self._pairs(gray, frame, tracks)
            timer.stamp("pair")

        # Each seen track's decoding state, looked up once for the clock, decode and report loops.
        get = lights_of.get
        lights = [get(t.track_id) or self._light(t.track_id) for t in seen]
        profiles: dict[int, tuple] = {}  # track id -> its row profile in this frame
        ticks = self._clock_frame(gray, seen, env, k, pair_of, profiles, lights) if self.clocks else {}
        policy = self.policy
        stripe_check = self.stripe_check
        # Where the map's lights should be in this frame, from the pose tracked so far
        # (receiver.locate.map_prior), while a light that shows short pieces lacks its ID.
        prior = None
        if self._map_prior is not None and any(li.wants_near() for li in lights):
            prior = self._map_prior(frame.t_s)
        every = policy.settings.redecode_every_frames
        t_s = frame.t_s
        for t, light in zip(seen, lights):
            tid = t.track_id
            if tid in pair_of:
                continue
            if not stripe_check:
                light.striped = True
            # `DecodePolicy.due` written out (a light with an ID is fed every `redecode_every_frames`
            # frames, staggered by track, unless it measures the frames' jitter for the others):
            # most lights of a frame are skipped here
            if (light.led_id is not None and (k + tid) % every and not light.measures_jitter()) or not light.decoders:
                continue
            blob = env[tid]
            prof = profiles.get(tid)
            near = near_ids(prior, blob.cx, blob.cy) if prior is not None and light.wants_near() else ()
            policy.step_light(light, gray, blob, prof if prof is not None else row_profile(gray, blob), t_s, ticks,
                              near)
        timer.stamp("decode")

        leds, emitter_of, pairs = self._report(gray, seen, lights, env, pair_of)
        timer.stamp("report")  # the frame's observations (the latency counts every stage)
        position = vehicle = None
        if self.positioner is not None:
            res = self.positioner.step(t_s, leds)
            position, leds = res.position, res.leds
            timer.stamp("locate")
        if self.vehicle is not None:
            speed = self.speed(t_s) if self.speed is not None else None
            vres = self.vehicle.step(t_s, pairs, speed)
            vehicle = vres.vehicle
            leds = _with_pair_ranges(leds, emitter_of, self.pairer.pairs, vres.ranges)
            timer.stamp("vehicle")
        self.frames += 1
        self.last_counts = {"blobs": len(blobs), "tracks": len(tracks),
                            "decoded": len(leds) - list(map(_ID, leds)).count(None), "pairs": len(pairs)}
        # FrameResult(...) by `frozen_record`'s construction (every field, in order); the timer
        # is this frame's own, so its dict is the record's
        res = object.__new__(FrameResult)
        res.__dict__.update(frame=k, t_s=t_s, latency_ms=timer.total_ms, leds=leds, position=position,
                            vehicle=vehicle, stage_ms=timer.stage_ms, pairs=pairs)
        return res
