"""The overlay: format by extension (stills, videos players open), an error for one it cannot
write, and text scaled to the image."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.cli import main as occloc
from receiver.core.errors import InputError
from receiver.io.overlay import OverlayWriter, scale_for
from tests.io.test_overlay import _frame

STATIC = Path(__file__).resolve().parents[2] / "recordings" / "indoor-static"
REC_VEH = Path(__file__).resolve().parents[2] / "recordings" / "vehicle"


def _text_rows(img) -> int:
    """Rows of the top-left text block with white text pixels."""
    band = img[: img.shape[0] // 4, : img.shape[1] // 3]
    return int((band.min(axis=2) > 200).any(axis=1).sum())


def test_text_scales_with_the_image(tmp_path):
    gray, res = _frame()
    small = OverlayWriter(str(tmp_path / "a.png"), (320, 240), 30.0).annotate(gray, res)
    big_gray = cv2.resize(gray, (3200, 2400), interpolation=cv2.INTER_NEAREST)
    big = OverlayWriter(str(tmp_path / "b.png"), (3200, 2400), 30.0).annotate(big_gray, res)
    assert scale_for((320, 240)) == 1.0 and scale_for((7712, 4352)) == pytest.approx(4352 / 720)
    # the same lines of text, about 3.3 x taller on the 10 x larger image (scale 2400 / 720)
    assert _text_rows(big) >= 2.5 * _text_rows(small) > 0


@pytest.mark.parametrize("name", ["still.jpg", "still.png", "clip.mp4", "clip.avi"])
def test_each_extension_gives_a_file_its_readers_open(tmp_path, name):
    gray, res = _frame()
    path = tmp_path / name
    w = OverlayWriter(str(path), (320, 240), 30.0)
    for _ in range(3):
        w.write(gray, res)
    w.close()
    if name.startswith("still"):
        assert cv2.imread(str(path)).shape == (240, 320, 3)
    else:
        cap = cv2.VideoCapture(str(path))
        ok, img = cap.read()
        assert ok and img.shape == (240, 320, 3) and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3


def test_an_extension_it_cannot_write_is_an_error(tmp_path, capsys):
    with pytest.raises(InputError):
        OverlayWriter(str(tmp_path / "x.gif"), (320, 240), 30.0)
    out = tmp_path / "x.gif"
    assert occloc(["run", str(STATIC), "--max-frames", "1", "--overlay", str(out),
                   "--out", str(tmp_path / "o.jsonl")]) == 2
    assert "cannot write .gif" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "o.jsonl").exists()


def test_vehicle_inset_shows_the_host_and_the_cars_in_their_zone_colours(tmp_path):
    from receiver.core.records import FrameResult, PairObservation
    from receiver.io.ledmap import load_map
    from receiver.io.overlay import RED, ZONE_COLOURS
    veh = REC_VEH / "map.json"
    led_map = load_map(str(veh))
    xs = [l.x for l in led_map.leds.values()]
    gray = np.zeros((720, 1280), np.uint8)
    fv = [{"id": 142, "distance_m": 14.0, "angle_deg": 0.0, "zone": "critical", "road_x": min(xs) + 20.0, "road_y": 0.0},
          {"id": 206, "distance_m": 45.0, "angle_deg": 1.0, "zone": "safe", "road_x": min(xs) + 51.0, "road_y": 3.5}]
    res = FrameResult(0, 0.0, 1.0, [], position=None,
                      vehicle={"hv": {"x": min(xs) + 6.0, "y": 0.0}, "fv": fv})
    img = OverlayWriter(str(tmp_path / "v.png"), (1280, 720), 30.0, None, led_map).annotate(gray, res)
    inset = img[8:8 + 150, 1280 - 200 - 8:1280 - 8]
    for zone in ("critical", "safe"):
        assert (inset == ZONE_COLOURS[zone]).all(axis=2).sum() >= 9, zone   # a car's dot
    assert (inset == (255, 255, 255)).all(axis=2).sum() >= 10                # the host's cross and frame
    # two pairs whose labels would be drawn at the same place: moved apart, both readable
    pairs = (PairObservation((1, 2), 0x81, "FV", (600.0, 400.0), (650.0, 400.0), 30.0, 30.0, 50.0, True),
             PairObservation((3, 4), 0x82, "FV", (602.0, 402.0), (652.0, 402.0), 30.0, 30.0, 50.0, True))
    res2 = FrameResult(0, 0.0, 1.0, [], pairs=pairs)
    one = OverlayWriter(str(tmp_path / "p.png"), (1280, 720), 30.0).annotate(gray, FrameResult(0, 0.0, 1.0, [], pairs=pairs[:1]))
    two = OverlayWriter(str(tmp_path / "p.png"), (1280, 720), 30.0).annotate(gray, res2)
    cyan_rows = lambda im: int(((im == (255, 255, 0)).all(axis=2)[:398]).any(axis=1).sum())  # label rows above the lines
    assert cyan_rows(two) >= 1.8 * cyan_rows(one) > 0


def test_vehicle_inset_is_the_hosts_surroundings_not_the_whole_road(tmp_path):
    """On a road map hundreds of metres long, a car 14 m ahead is drawn well apart from the host
    (the inset shows the host's surroundings), and only the nearby street lights are drawn."""
    from receiver.core.records import FrameResult
    from receiver.io.ledmap import load_map
    from receiver.io.overlay import ZONE_COLOURS
    led_map = load_map(str(REC_VEH / "map.json"))
    xs = [l.x for l in led_map.leds.values()]
    assert max(xs) - min(xs) > 300
    host = {"x": min(xs) + 100.0, "y": 0.0}
    fv = [{"id": 142, "distance_m": 14.0, "angle_deg": 0.0, "zone": "critical", "road_x": host["x"] + 14.0, "road_y": 0.0}]
    img = OverlayWriter(str(tmp_path / "v.png"), (1280, 720), 30.0, None, led_map).annotate(
        np.zeros((720, 1280), np.uint8), FrameResult(0, 0.0, 1.0, [], position=None, vehicle={"hv": host, "fv": fv}))
    inset = img[8:8 + 150, 1280 - 200 - 8:1280 - 8]
    car = np.argwhere((inset == ZONE_COLOURS["critical"]).all(axis=2)).mean(axis=0)
    white = np.argwhere((inset[4:-4, 4:-4] == (255, 255, 255)).all(axis=2)).mean(axis=0) + 4  # the host's cross
    assert np.hypot(*(car - white)) >= 14, (car, white)  # at least a pixel per metre (the whole road: 0.5)


def test_show_without_a_display_is_a_one_line_error_before_any_work(tmp_path, capsys, monkeypatch):
    from receiver.io.overlay import LiveWindow
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "o.jsonl"
    assert occloc(["run", str(STATIC), "--max-frames", "1", "--show", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["occloc: --show needs a display (DISPLAY is not set): use --overlay FILE to write the picture instead"]
    assert not out.exists() and list(tmp_path.iterdir()) == []
    # a display named but not there (Tk cannot reach it): the same kind of error, not a traceback
    monkeypatch.setenv("DISPLAY", ":97")
    with pytest.raises(InputError, match="--show cannot open a window"):
        LiveWindow(None)


def test_inset_of_a_large_photo_keeps_the_lights_inside_its_frame_and_centred(tmp_path):
    """On a 33 MP photo (drawing scale 6) the map's lights are dots of 12 px: the margin grows
    with them, so none touches the inset's frame, and the map sits in the middle."""
    from receiver.core.records import FrameResult
    from receiver.io.ledmap import load_map
    from receiver.io.overlay import INSET, YELLOW, scale_for
    led_map = load_map(str(STATIC / "map.json"))
    size = (7712, 4352)
    k = scale_for(size)
    img = OverlayWriter(str(tmp_path / "p.jpg"), size, 30.0, None, led_map).annotate(
        np.zeros(size[::-1], np.uint8), FrameResult(0, 0.0, 1.0, [], position={"x": 2.0, "y": 2.0, "z": 1.0}))
    iw, ih = int(INSET[0] * k), int(INSET[1] * k)
    inset = img[8:8 + ih, size[0] - iw - 8:size[0] - 8]
    ys, xs = np.nonzero((inset == YELLOW).all(axis=2))
    assert xs.size and xs.min() > 4 and ys.min() > 4 and xs.max() < iw - 5 and ys.max() < ih - 5
    assert abs((xs.min() + xs.max()) / 2 - iw / 2) < 0.05 * iw and abs((ys.min() + ys.max()) / 2 - ih / 2) < 0.05 * ih


def test_labels_keep_off_the_text_block_and_inside_the_image():
    """A light at the top left: its label is not drawn over the frame/position text (nor off the
    image), but just below it."""
    from receiver.core.records import FrameResult, LedObservation
    gray = np.zeros((720, 1280), np.uint8)
    c = np.array([[10, 2], [160, 2], [160, 200], [10, 200]], float)
    led = LedObservation(track=5, cx=85.0, cy=100.0, area_px=30000.0, contour=c, id=4505, mode="ook")
    res = FrameResult(0, 0.0, 1.0, [led], position={"x": 1.0, "y": 2.0, "z": 1.0, "method": "outline", "n_leds": 5})
    img = OverlayWriter("x.png", (1280, 720), 30.0).annotate(gray, res)
    green = (img == (0, 255, 0)).all(axis=2)
    green[:, 8:12] = False; green[:, 158:162] = False   # the envelope's sides
    green[:5, :] = False                                 # its top edge
    rows = np.nonzero(green[:, 20:150].any(axis=1))[0]
    white_rows = np.nonzero((img[:, :300] == (255, 255, 255)).all(axis=2).any(axis=1))[0]
    assert rows.size and white_rows.size and rows.min() > white_rows.max(), (rows.min(), white_rows.max())
