"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.core.settings import MAX_IMAGE_SIDE_PX, knob

# Fewest pixels of a downsampled search image (100 x 100): fewer leave nothing of a light to find.
MIN_DETECT_PX = 10_000


@dataclass(frozen=True)
class DetectSettings:
    """Tunables of `detect` (defaults in brackets).

      stripe_gap_px [8]: longest dark stripe (rows, full resolution) bridged inside one LED;
        the pipeline sets it from the chip/tone period. Larger also merges LEDs stacked closer.
      join_x_px [2]: horizontal gaps (columns, full resolution; at least one search pixel)
        bridged, so a stripe broken by a dark spot of the diffuser stays one LED.
      max_detect_px [1.2e6]: frames above this pixel count are searched downsampled (at least
        MIN_DETECT_PX).
      k_mad [8], min_contrast [24]: threshold, see `auto_level`.
      fine_noise [False]: the noise sigma of that threshold resolved below one gray level
        (`noise_sigma`: a dark, clipped background of MAD 0); the pipeline sets it, with a
        small `min_contrast`, for S2-PSK maps, whose far emitters peak 20-50 gray over ~0.4.
      refine_frac [0.5]: per-blob edge level between background (0) and peak (1): half
        maximum is the true edge of a blurred sharp-edged light (symmetric PSF), so the hull
        through the outermost lit pixel centres lies half a pixel inside it on average.
      saturated_gray [250], saturated_frac [0.03], min_refine_contrast [6]: a blob whose
        peak reaches `saturated_gray` is clipped (real phone photos: a saturated core in a
        dimmer, still striped glow); its edge level is background + max(saturated_frac *
        (255 - background), min_refine_contrast), which keeps the glow and gives the decoders
        many more stripe rows.
      min_area_px [12]: smaller envelopes are specks. max_area_frac [0.05]: larger than this
        fraction of the frame is a window or a lamp, not a transmitter.
      max_aspect [4], min_fill [0.25]: the stripe-bridged component's bounding box may be at
        most this elongated, and its contour must fill at least this fraction of the box (a
        disc fills 0.79, a 45-degree square 0.5, a thin diagonal bar almost nothing); border
        blobs are exempt, and so are components under shape_min_rows [0] rows tall (full
        resolution; the pipeline sets 3 for S2-PSK maps: far street-light heads seen from below
        are one or two rows tall and several px wide).
      expect_stripes [False]: reject blobs whose row profile is flat (stripe depth below
        `min_stripe_depth` [0.8]) when they span at least `min_stripe_rows` rows (set it to
        about one stripe period; 0 = always checked).
      min_rel_area [0]: drop blobs smaller than this fraction of the frame's largest blob
        (for single photos of a lamp set, where reflections look like small dim lamps;
        0 = off, since a moving camera sees near and far lights together).
      level [None]: fixed global threshold instead of `auto_level`.
      row_pool [2]: 2 = at full resolution, with stripes to bridge (stripe_gap_px >= 4), the
        components are searched on the maximum of every 2 rows: the close and contour pass
        cost half as much. Every gap the full-resolution search bridges is bridged, the boxes
        are the full-resolution search's and the envelopes are taken in full resolution within
        them, so the blobs are the same (a frame where component boxes overlap is searched in
        full resolution), except that the pooled rows may join lights the full-resolution
        search keeps apart: stacked up to 4 rows closer than stripe_gap_px, touching diagonally
        (within join_x_px columns) across a pair of pooled rows, or within a row or two of
        each other at the top or bottom edge (the pooled close reaches the edge from up to 2
        rows farther); and the `min_fill` test uses the pooled component's area (times 2),
        which can decide otherwise within a few % of `min_fill`. 1 = off (full resolution).
        Other values are refused: with 3 rows the pooled close can reach the bottom edge from
        a row less far than the full-resolution one and split what it joins.
    
    """

    stripe_gap_px: int = knob(8, 0, MAX_IMAGE_SIDE_PX)
    join_x_px: int = knob(2, 0, MAX_IMAGE_SIDE_PX)
    max_detect_px: int = knob(1_200_000, MIN_DETECT_PX)
    k_mad: float = 8.0
    min_contrast: float = 24.0
    fine_noise: bool = False
    refine_frac: float = 0.5
    saturated_gray: float = 250.0
    saturated_frac: float = 0.03
    min_refine_contrast: float = 6.0
    min_area_px: float = 12.0
    max_area_frac: float = 0.05
    max_aspect: float = 4.0
    min_fill: float = 0.25
    shape_min_rows: int = 0
    expect_stripes: bool = False
    min_stripe_depth: float = 0.8
    min_stripe_rows: int = 0
    min_rel_area: float = 0.0
    level: float | None = None
    row_pool: int = knob(2, 1, 2)


@dataclass(frozen=True)
class TrackSettings:
    """Tunables of `Tracker` (defaults in brackets).

      gate_px [30]: fixed part of the association gate, px.
      gate_size [1.5]: plus this many blob diameters (sqrt(area)), so big near lights may move
        more per frame than small far ones.
      max_area_ratio [4]: larger area change between frames is another light.
      max_missed [10]: frames a track survives without a blob (an S2-PSK emitter is dark in
        about half the frames, a blob may also leave the view briefly).
      velocity_gain [0.5]: smoothing of the px/frame velocity estimate (1 = last step only).
    
    """

    gate_px: float = 30.0
    gate_size: float = 1.5
    max_area_ratio: float = knob(4.0, 1.0)
    max_missed: int = 10
    velocity_gain: float = knob(0.5, 0.0, 1.0)


@dataclass(frozen=True)
class PairSettings:
    """What a user may set of the S2-PSK pairing (receiver.vision.pairing.Pairer): two emitters
    (a car's taillights, the two halves of a street-light head) that blink as one transmitter.
    The pairing's internal constants (gates in emitter sizes, smoothing gains) are
    receiver.vision.pairing.TUNING, each documented there.

    row_band [1.0 diameters]: the two emitters' rows differ by at most this many blob diameters
        (heads and taillights are level; roll and blur add less than one diameter).
    max_area_ratio [2.5]: their blob areas differ by at most this factor (the emitters of one
        light are the same size; a rolling-shutter clock edge may cut one).
    min_baseline [1.2 diameters], max_baseline [25 diameters]: their horizontal distance (a car's
        taillights are ~9 diameters apart, a head's halves 1.5-4).
    min_swing [20 gray]: an emitter counts as blinking when its on and off levels differ by this
        much (S2-PSK lights each emitter half of the time; 20 is ~10 sigma of a dark sensor).
    match_min_px [3 px]: the smallest gate around a pair's predicted emitter (blur and centroid
        noise of a 1-2 px far half).
    max_missed [10 frames]: a pair ends after this many frames without a blob it explains (both
        emitters are dark in about a quarter of the frames, in runs of 1-3).
    give_up_frames [200 frames]: a pair without an ID after this long is a wrong pairing and ends
        (2.8 packets of 2.4 s at 30 fps).
    unseen_give_up_frames [60 frames]: an undecoded two-track pair one of whose emitters never had
        a blob of its own for this long ends too (each emitter is lit alone in ~1/4 of the
        frames); 0 = never.
    backlog_frames [90 frames]: history kept per unpaired track so a new pair's decoder starts
        from the light's first frames (3 s: longer than one 2.4 s packet); 0 = off.
    shake ["pairs"]: the camera-shake estimate that moves every track's and pair's prediction:
        "pairs" (pitch from all blobs, yaw from where the pairs expect their blobs,
        receiver.vision.motion), "vertical" (pitch only), "pitch" (the pairs' median vertical
        offset alone) or "motion" (every blob on the light it belongs to, each light with its
        own motion, the camera's offset kept as several hypotheses; the "pairs" shift is one
        candidate among the blobs' own: receiver.vision.camera_motion).
    shake_radius_px [14 px]: the largest frame-to-frame image shift searched (0.5 degrees at a
        1500 px focal length).
    """

    row_band: float = 1.0
    max_area_ratio: float = knob(2.5, 1.0)
    min_baseline: float = 1.2
    max_baseline: float = 25.0
    min_swing: float = 20.0
    match_min_px: float = 3.0
    max_missed: int = 10
    give_up_frames: int = 200
    unseen_give_up_frames: int = 60
    backlog_frames: int = 90
    shake: str = "pairs"
    shake_radius_px: float = knob(14.0, 0.0, MAX_IMAGE_SIDE_PX)
