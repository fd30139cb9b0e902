"""Small frozen records passed between receiver stages.

Image coordinates: pixels, x to the right, y down, origin at the centre of the top-left
pixel, as OpenCV uses them; they are *distorted* (as seen in the frame) unless a name says
`undist`. Times: seconds from the source's own clock (never wall-clock taken in a stage).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Blob:
    """One LED candidate in full-resolution pixel coordinates.

    `hull`: (K, 2) float64 envelope polygon through pixel centres. `x0, y0, x1, y1`: bounding
    box of the envelope, half-open ([x0, x1) x [y0, y1)). `border`: the envelope touches the
    image border. `peak`: brightest gray value. `level`: the gray threshold used for it.
    `background`: the frame's background gray level.
    """

    cx: float
    cy: float
    area_px: float
    hull: np.ndarray
    x0: int
    y0: int
    x1: int
    y1: int
    border: bool
    peak: float
    level: float
    background: float


@dataclass(frozen=True)
class Frame:
    """One video frame. `gray` is (H, W) uint8; `index` counts frames the source delivered
    (0-based, gaps mean dropped frames); `t_s` is the source's timestamp in seconds."""

    index: int
    t_s: float
    gray: np.ndarray


@dataclass(frozen=True)
class PairObservation:
    """One S2-PSK pair in one frame (a street-light head's two halves, or a car's two
    taillights; receiver.vision.pairing), what the vehicle locator works from.

    `key`: the pair's stable key for its whole life (its founding tracks' ids). `led_id`: the
    decoded S2-PSK ID or None; `kind`: "SL" (0x00-0x7F), "FV" (0x80-0xFF) or None.
    `a_px`, `b_px`: (x, y) centroids of emitters A and B, distorted image px (where the pair
    puts them this frame). `area_a_px`, `area_b_px`: their envelope areas, px^2.
    `separation_px`: |b - a|, px. `both_visible`: one emitter's own blob was seen in this frame and the other's
    within the last `receiver.vision.pairing.BOTH_SEEN_FRAMES` frames, as separate blobs (an
    S2-PSK head lights one emitter at a time for half its symbols, and far heads merge when
    both are lit): the pair's separation is then a measurement. When False (one emitter hidden
    or long unseen) the separation and areas are the pair's prediction, and no range may be
    taken from them.
    `a_seen`, `b_seen`: emitter A's / B's own blob as measured when last seen, ((cx, cy) distorted
    px, area px^2, age in frames: 0 = this frame), or None when never seen alone. Unlike `a_px`,
    `b_px` (the pair's rigid model, to the nearest whole pixel) these are measurements: two of
    age 0 give the pair's separation to a fraction of a pixel. `founding`: the founding tracks'
    ids (the key unless the pair is aliased: receiver.vision.pairing `Pair.alias`; None: the key).
    `a_saturated`, `b_saturated`: emitter A's / B's own blob, when last seen, peaked at the
    sensor's white level (receiver.vision.detect.SATURATED_GRAY): its area is then blur and bloom (2-3x
    the emitter's true image area), no measure of range or size (False: unknown or unclipped).
    """

    key: tuple[int, int]
    led_id: int | None
    kind: str | None
    a_px: tuple[float, float]
    b_px: tuple[float, float]
    area_a_px: float
    area_b_px: float
    separation_px: float
    both_visible: bool
    a_seen: tuple | None = None
    b_seen: tuple | None = None
    founding: tuple[int, int] | None = None
    a_saturated: bool = False
    b_saturated: bool = False


@dataclass(frozen=True)
class LedObservation:
    """One LED blob in one frame, after detection, tracking, decoding and (when a locator ran)
    ranging.

    `cx, cy`: sub-pixel centroid of the blob envelope (the filled hull of its rolling-shutter
    stripes), px. `area_px`: envelope area eta (px^2), the LED's projected area for eq. 18.
    `contour`: (K, 2) float64 envelope polygon, px. `border`: the blob touches the image
    border (area and centroid are then biased). `id`/`mode` are None until decoded.
    `peak`: brightest pixel value in the blob (0-255). `distance_m`, `distance_estimator`: the
    range to the LED and the estimator that gave it (receiver.locate.ranging), None when not
    ranged. `freq_hz`: a tone LED's measured stripe frequency (Hz, 0.1 Hz), else None.
    `kind`: an S2-PSK light's "SL" or "FV" once decoded, else None. An S2-PSK pair's emitter
    (receiver.vision.pairing `Pairer.emitters`) is reported also when dark: then `track` is the
    emitter's own id (never a track's) and `cx, cy, area_px` are the pair's model of it.
    `edge_px`: ((N, 2) distorted px, (N,) 1-sigma px) sub-pixel ends of the blob's lit stripes,
    points on the LED's outline (receiver.vision.outline.stripe_edge_points), or None when not
    measured (S2-PSK, undecoded, photos of unknown sizes); not part of the JSON output.
    """

    track: int
    cx: float
    cy: float
    area_px: float
    contour: np.ndarray
    border: bool = False
    id: int | None = None
    mode: str | None = None
    peak: float = 0.0
    distance_m: float | None = None
    distance_estimator: str | None = None
    freq_hz: float | None = None
    kind: str | None = None
    edge_px: tuple[np.ndarray, np.ndarray] | None = None


@dataclass(frozen=True)
class LocateResult:
    """What a locator makes of one frame's LED observations.

    `position`: the INTERFACES.md `position` object (x, y, z, method, n_leds, plus optional
    extras such as `raw`, `cov`, `yaw_deg`...) or None when it cannot be computed. `leds`: the
    frame's observations, each ranged one with its `distance_m` and `distance_estimator`.
    """

    position: dict | None
    leds: list[LedObservation]


@dataclass(frozen=True)
class FrameResult:
    """Everything the receiver made of one frame.

    `frame`, `t_s`: the source's index and timestamp; `latency_ms`: processing time of this
    frame (injected clock); `leds`: the LEDs seen in this frame, each carrying its own ID,
    range and decode details; `position`: INTERFACES.md position object or None; `vehicle`:
    the INTERFACES.md vehicle object or None; `stage_ms`: per stage; `pairs`: the S2-PSK pairs
    followed in this frame."""

    frame: int
    t_s: float
    latency_ms: float
    leds: list[LedObservation]
    position: dict | None = None
    vehicle: dict | None = None
    stage_ms: dict[str, float] = field(default_factory=dict)
    pairs: tuple[PairObservation, ...] = ()


def frozen_record(cls, fields: dict):
    """`cls(**fields)` of a frozen dataclass without `__post_init__` or slots, built without its
    generated `__init__` (one `object.__setattr__` per field: several times the cost; the
    receiver builds a few records per LED and frame). `fields` must name every field, in order
    (tests/pipeline/test_pipeline.py and tests/engine/test_detect_kernels.py compare with the constructor)."""
    o = object.__new__(cls)
    o.__dict__.update(fields)
    return o


def led_observation(track: int, cx: float, cy: float, area_px: float, contour: np.ndarray, border: bool = False,
                    id: int | None = None, mode: str | None = None, peak: float = 0.0,
                    distance_m: float | None = None, distance_estimator: str | None = None,
                    freq_hz: float | None = None, kind: str | None = None,
                    edge_px: tuple[np.ndarray, np.ndarray] | None = None,
                    ) -> LedObservation:
    """`LedObservation(...)` with the same arguments, by `frozen_record`."""
    return frozen_record(LedObservation, dict(
        track=track, cx=cx, cy=cy, area_px=area_px, contour=contour, border=border, id=id, mode=mode, peak=peak,
        distance_m=distance_m, distance_estimator=distance_estimator, freq_hz=freq_hz, kind=kind, edge_px=edge_px))
