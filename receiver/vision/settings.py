"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.core.settings import MAX_IMAGE_SIDE_PX, knob

# Fewest pixels of a downsampled search image (100 x 100): fewer leave nothing of a light to find.
MIN_DETECT_PX = 10_000


@dataclass(frozen=True)
class DetectSettings:
    """What a user may set of `detect` (receiver.vision.detect), each [default]: the pipeline
    sets them from the camera, the map and the kind of input. The detector's fixed constants
    (half-maximum edges, the clipped-light level, the shape tests, the row pooling) are
    receiver.vision.detect's module constants, each documented there.

      stripe_gap_px [8 rows]: longest dark stripe (full resolution) bridged inside one light:
        about a chip or tone half-period of rows (the pipeline sets it); larger also merges
        lights stacked closer than that.
      max_detect_px [1.2e6 px]: frames larger than this are searched on a downsampled copy
        (an integer factor), the envelopes then refined in full resolution; at least
        MIN_DETECT_PX. Cost: the search is linear in the pixels searched.
      k_mad [8 sigmas], min_contrast [24 gray]: the threshold is the background median plus
        k_mad noise sigmas, at least min_contrast above it (`auto_level`; a clean dark frame
        has no measurable noise).
      fine_noise [False]: that noise sigma resolved below one gray level (`noise_sigma`, for a
        dark, clipped background) and at least the noise next to the lights: for S2-PSK
        maps, whose far emitters peak 20-50 gray over ~0.4.
      min_area_px [12 px^2]: smaller envelopes are specks.
      max_aspect [4]: the stripe-bridged component's box may be at most this elongated (0:
        no shape test); components under shape_min_rows [0 rows] are exempt (far
        street-light heads seen from below are one or two rows tall).
      stripe_check_rows [0 rows]: a blob spanning at least this many rows (about a stripe
        period) whose row profile is flat (stripe depth under detect.MIN_STRIPE_DEPTH) is not
        a transmitter (single photos, where nothing is tracked); 0 = no check.
      min_rel_area [0]: drop blobs smaller than this fraction of the frame's largest (single
        photos of a lamp set, where reflections look like small dim lamps; 0 = off, since a
        moving camera sees near and far lights together).
    """

    stripe_gap_px: int = knob(8, 0, MAX_IMAGE_SIDE_PX)
    max_detect_px: int = knob(1_200_000, MIN_DETECT_PX)
    k_mad: float = 8.0
    min_contrast: float = 24.0
    fine_noise: bool = False
    min_area_px: float = 12.0
    max_aspect: float = 4.0
    shape_min_rows: int = 0
    stripe_check_rows: int = knob(0, 0, MAX_IMAGE_SIDE_PX)
    min_rel_area: float = 0.0


@dataclass(frozen=True)
class TrackSettings:
    """What a user may set of `Tracker` (receiver.vision.track), each [default]; the gate's
    growth with the light's size, the area ratio and the velocity smoothing are
    receiver.vision.track's module constants.

      gate_px [30 px]: fixed part of the association gate (a light's motion between frames).
      max_missed [10 frames]: frames a track survives without a blob (an S2-PSK emitter is
        dark in about half the frames, a blob may also leave the view briefly).
    """

    gate_px: float = knob(30.0, 0.0, MAX_IMAGE_SIDE_PX)
    max_missed: int = 10


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
