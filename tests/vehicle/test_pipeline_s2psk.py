"""S2-PSK plumbing of the pipeline: pairing, per-frame intensities -> pair_xor -> decoder.

The decoder itself is the decoder module's (receiver.decode.s2psk, tested on its own); here a
recording stand-in replaces it, so the test checks exactly what the pipeline feeds it: the right
two blobs, one sample per frame with the frame time, a soft XOR whose sign is the transmitted
symbol (PROTOCOL.md section 3, thesis polarity), and the ID reaching both emitters' tracks.
"""

from __future__ import annotations

import types

import cv2
import numpy as np
import pytest

from firmware_tx.framing import s2psk_packet
from firmware_tx.schedule import make_schedule
from receiver.io.camera import CameraModel
from receiver.io.ledmap import parse_map
from receiver.decode.settings import S2pskSettings
from receiver.pipeline import Receiver, ReceiverSettings
from receiver.core.records import Frame

LED_ID = 0x2A
CLK_HZ, SYMCLK = 200.0, 16
FPS = 30.0
A_XY, B_XY = (400.0, 300.0), (700.0, 304.0)  # px; 15 px radius, same row band
OTHER_XY = (300.0, 100.0)  # a steady lamp: never paired


def _camera():
    K = np.array([[800.0, 0, 511.5], [0, 800.0, 383.5], [0, 0, 1]])
    return CameraModel(1024, 768, K, np.zeros(5), row_readout_us=0.0, exposure_us=100.0, fps=FPS)


def _map():
    return parse_map({"leds": [{"id": LED_ID, "mode": "s2psk", "x": 0, "y": 0, "z": 5,
                                "rate_hz": CLK_HZ, "symbol_clocks": SYMCLK, "baseline_m": 1.0}]})


def _render(k, rng, t0_s=0.0123):
    """Global-shutter frame k: each emitter is on or off at the frame instant."""
    sch = make_schedule("s2psk", LED_ID, CLK_HZ, SYMCLK)
    t = t0_s + k / FPS + rng.normal(0, 50e-6)
    lv = sch.levels[int(t * sch.tick_hz) % len(sch.levels)]
    img = (8.0 + rng.normal(0, 2.0, (768, 1024))).astype(np.float32)
    for (x, y), on in ((A_XY, lv & 1), (B_XY, lv & 2), (OTHER_XY, True)):
        x0, y0 = int(x) - 16, int(y) - 16
        patch = img[y0:y0 + 33, x0:x0 + 33]
        patch[_DISC] += 192.0 if on else 0.0
    sym_index = int(t * CLK_HZ / SYMCLK) % 30
    return np.clip(img, 0, 255).astype(np.uint8), s2psk_packet(LED_ID)[sym_index], t


_yy, _xx = np.mgrid[-16:17, -16:17]
_DISC = _xx ** 2 + _yy ** 2 <= 15 ** 2


class StandInDecoder:
    """Records what the pipeline feeds; reports the ID after `after` samples."""

    instances: list = []

    def __init__(self, clk_hz=200.0, symbol_clocks=16, *, settings=None, after=20):
        self.clk_hz, self.symbol_clocks = clk_hz, symbol_clocks
        self.inverted = bool(settings is not None and settings.inverted)
        self.samples: list[tuple[float, float]] = []
        self.after = after
        StandInDecoder.instances.append(self)

    def step(self, t_s, soft_xor, decode=True):
        self.samples.append((t_s, soft_xor))
        done = len(self.samples) >= self.after
        return types.SimpleNamespace(led_id=LED_ID if done else None, kind="SL" if done else None,
                                     samples=len(self.samples), confidence=1.0)


def _pair_xor(a, b, a_on, b_on, a_off=0.0, b_off=0.0):
    """Soft XOR of normalised intensities: > 0 when one emitter is on and the other off."""
    na = (a - a_off) / max(a_on - a_off, 1e-9)
    nb = (b - b_off) / max(b_on - b_off, 1e-9)
    return float(np.clip(abs(na - nb) * 2 - 1, -1, 1))


@pytest.fixture
def stand_in(monkeypatch):
    # the decoder the policy makes and the soft XOR the pair decoding computes
    monkeypatch.setattr("receiver.decode.policy.S2pskDecoder", StandInDecoder)
    monkeypatch.setattr("receiver.decode.pair_decoding.pair_xor", _pair_xor)
    StandInDecoder.instances = []


def test_pair_found_fed_every_frame_and_id_on_both_tracks(stand_in):
    rx = Receiver(_camera(), _map())
    rng = np.random.default_rng(5)
    truth = {}
    for k in range(40):
        gray, sym, t = _render(k, rng)
        truth[round(k / FPS, 9)] = sym
        res = rx.process(Frame(k, k / FPS, gray))
        assert "pair" in res.stage_ms
    # Two decoders: one fed from pairing on, one also fed the frames before the pair formed
    # (the founding tracks' history); the one that decodes first keeps the pair.
    live, early = StandInDecoder.instances
    for dec in (live, early):
        assert (dec.clk_hz, dec.symbol_clocks, dec.inverted) == (CLK_HZ, SYMCLK, False)
    # One sample per frame with the frame's own timestamp: the early decoder from both
    # emitters' first blobs on (it reaches `after` first and is fed to the end), the other
    # from pairing on (`min_frames` later) until then.
    ts = [t for t, _ in early.samples]
    t_live = [t for t, _ in live.samples]
    assert np.allclose(np.diff(ts), 1 / FPS) and np.allclose(np.diff(t_live), 1 / FPS)
    assert ts[0] <= t_live[0] - 3 / FPS + 1e-9 and abs(ts[-1] - 39 / FPS) < 1e-9 and t_live[-1] < ts[-1]
    # The soft XOR carries the symbol (thesis polarity: anti-phase = 1), also in frames where
    # one or both emitters are dark and no blob was detected.
    agree = [(x > 0) == bool(truth[round(t, 9)]) for t, x in early.samples]
    assert np.mean(agree) >= 0.9
    (pair,) = rx.pairer.pairs
    assert {round(pair.a.blob.cx), round(pair.b.blob.cx)} == {400, 700}
    leds = {round(o.cx): o for o in res.leds}
    for x in (400, 700):  # both emitters listed with the ID, also one dark in this frame
        assert leds[x].id == LED_ID and leds[x].mode == "s2psk" and leds[x].kind == "SL"
    assert leds[300].id is None  # the steady lamp


def test_inverted_polarity_option_reaches_the_decoder(stand_in):
    rx = Receiver(_camera(), _map(), settings=ReceiverSettings(s2psk=S2pskSettings(inverted=True)))
    rng = np.random.default_rng(6)
    for k in range(12):
        rx.process(Frame(k, k / FPS, _render(k, rng)[0]))
    assert StandInDecoder.instances and StandInDecoder.instances[0].inverted


def test_real_decoder_gets_the_id_from_the_pipeline():
    """With receiver.decode.s2psk itself: the 30-symbol packet lasts 2.4 s (72 frames)."""
    rx = Receiver(_camera(), _map())
    rng = np.random.default_rng(7)
    first = None
    for k in range(150):
        res = rx.process(Frame(k, k / FPS, _render(k, rng)[0]))
        for o in res.leds:
            assert o.id in (None, LED_ID)
            if o.id is not None and first is None:
                first = k
    assert first is not None and first < 150
    (pair,) = rx.pairer.pairs
    assert pair.led_id == LED_ID and pair.kind == "SL"


# A far street-light head (PROTOCOL.md section 3: the two halves of one head): two 7x5 px
# halves whose centres are 9 px apart, blurred so that the 2 px gap between them fills in
# when both are lit. A and B are then never two blobs of one frame: symbol 0 shows one merged
# blob or nothing, symbol 1 one half alone. The head drifts slowly (camera motion).
HEAD_XY = (500.0, 400.0)  # px, midpoint at frame 0
HEAD_SEP_PX = 9.0
HEAD_DRIFT_PX = (0.15, -0.1)  # px per frame


def _render_head(k, rng, led_id=LED_ID, t0_s=0.0311):
    sch = make_schedule("s2psk", led_id, CLK_HZ, SYMCLK)
    t = t0_s + k / FPS + rng.normal(0, 50e-6)
    lv = sch.levels[int(t * sch.tick_hz) % len(sch.levels)]
    img = np.zeros((768, 1024), np.float32)
    mx, my = HEAD_XY[0] + HEAD_DRIFT_PX[0] * k, HEAD_XY[1] + HEAD_DRIFT_PX[1] * k
    centres = ((mx - HEAD_SEP_PX / 2, my), (mx + HEAD_SEP_PX / 2, my))
    for (x, y), on in zip(centres, (lv & 1, lv & 2)):
        if on:
            x0, y0 = int(round(x)) - 3, int(round(y)) - 2
            img[y0:y0 + 5, x0:x0 + 7] = 230.0
    img = cv2.GaussianBlur(img, (0, 0), 1.0) + 8.0 + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), centres


def test_far_head_whose_halves_merge_decodes_with_the_real_decoder():
    """The pair follows the head itself (receiver.vision.pairing): the one blob track jumps between
    A, B and the merged blob, yet the samples come from the right places, the ID arrives
    after about one packet (2.4 s = 72 frames) and stays on the head's blobs."""
    rx = Receiver(_camera(), _map())
    rng = np.random.default_rng(11)
    first, after, right = None, 0, 0
    for k in range(150):
        gray, centres = _render_head(k, rng)
        res = rx.process(Frame(k, k / FPS, gray))
        for o in res.leds:
            assert o.id in (None, LED_ID)
            if o.id is not None and first is None:
                first = k
            if first is not None and k > first:
                after += 1
                right += o.id == LED_ID
    assert first is not None and first <= 100
    assert after >= 20 and right == after  # once decoded, every blob of the head carries it
    (pair,) = [p for p in rx.pairer.pairs if p.led_id == LED_ID]
    for e, (x, y) in zip((pair.a, pair.b), centres):
        assert abs(e.cx - x) <= 1.5 and abs(e.cy - y) <= 1.5


def test_a_blob_two_pairs_explain_belongs_to_the_decoded_pair():
    """A wide, undecoded pairing whose emitter lies on another head explains that head's blob
    too: the blob stays the decoded head's emitter (it carries its ID), whatever the order."""
    from types import SimpleNamespace
    from receiver.pipeline import pair_owners
    blob_track, other = SimpleNamespace(track_id=7), SimpleNamespace(track_id=8)
    head = SimpleNamespace(led_id=92, tracks=[blob_track])
    wide = SimpleNamespace(led_id=None, tracks=[blob_track, other])
    for pairs in ([head, wide], [wide, head]):
        owners = pair_owners(pairs)
        assert owners[7] is head and owners[8] is wide
    decoded_too = SimpleNamespace(led_id=29, tracks=[blob_track])
    assert pair_owners([head, decoded_too])[7] is decoded_too  # both decoded: the later one
