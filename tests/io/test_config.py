"""camera.yaml / map.json contract (INTERFACES.md): round trips, xy addressing, one-line errors."""

import json
import math

import numpy as np
import pytest

from receiver.io.ledmap import LedMap, load_map, parse_map, save_map
from receiver.io.camera import load_camera, save_camera
from receiver.core.errors import InputError

CAMERA = """%YAML:1.0
---
image_width: 1280
image_height: 720
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1000., 0., 640., 0., 1000., 360., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.04, 0.01, 0., 0., 0. ]
pixel_size_um: 3.0
focal_length_mm: 3.0
row_readout_us: 15.0
exposure_us: 20.0
fps: 30.0
"""


def test_camera_round_trip_and_eq18_focal(tmp_path):
    p = tmp_path / "camera.yaml"
    p.write_text(CAMERA)
    cam = load_camera(str(p))
    assert (cam.width, cam.height, cam.fx, cam.cy) == (1280, 720, 1000.0, 360.0)
    assert cam.focal_px == pytest.approx(1000.0)  # f / rho = 3 mm / 3 um
    assert cam.rolling_shutter and cam.dist[0] == pytest.approx(-0.04)
    save_camera(str(tmp_path / "again.yaml"), cam)
    again = load_camera(str(tmp_path / "again.yaml"))
    assert np.array_equal(again.K, cam.K) and np.array_equal(again.dist, cam.dist)
    assert again.row_readout_us == cam.row_readout_us
    half = cam.scaled(640, 360)
    assert half.fx == 500.0 and half.row_readout_us == 30.0 and half.pixel_size_um == 6.0


@pytest.mark.parametrize("text,reason", [
    (b"\x00\xff\x13garbage", "not a readable"),
    (b"%YAML:1.0\n---\nimage_width: 1280\n", "image_height"),
    (b"%YAML:1.0\n---\nimage_width: 1280\nimage_height: 720\n", "camera_matrix"),
    (CAMERA.replace("fps: 30.0", "fps: -1").encode(), "must not be negative"),
    (CAMERA.replace("rows: 3\n   cols: 3", "rows: 2\n   cols: 3").encode(), "camera_matrix"),
])
def test_bad_camera_files_are_one_line_errors(tmp_path, text, reason):
    p = tmp_path / "camera.yaml"
    p.write_bytes(text)
    with pytest.raises(InputError) as e:
        load_camera(str(p))
    assert reason in str(e.value) and "\n" not in str(e.value)


def test_missing_files():
    with pytest.raises(InputError, match="not found"):
        load_camera("/nonexistent/camera.yaml")
    with pytest.raises(InputError, match="not found"):
        load_map("/nonexistent/map.json")


def test_map_round_trip_and_areas(tmp_path):
    obj = {"units": "m", "addressing": "map", "leds": [
        {"id": 42, "mode": "ook", "x": 2.0, "y": 0.0, "z": 3.0, "shape": "square", "size": [0.1, 0.1], "rate_hz": 20000},
        {"id": 7, "mode": "ook", "x": 1.0, "y": 1.0, "z": 3.0, "shape": "circle", "size": [0.2]},
        {"id": 9, "mode": "tone", "x": 0.0, "y": 0.0, "z": 2.5, "freq_hz": 2000},
        {"id": 3, "mode": "s2psk", "x": 0.0, "y": 6.0, "z": 7.0, "shape": "rect", "size": [0.3, 0.1],
         "symbol_clocks": 16, "baseline_m": 1.0}]}
    p = tmp_path / "map.json"
    p.write_text(json.dumps(obj))
    m = load_map(str(p))
    assert m.lookup(42).area_m2 == pytest.approx(0.01)
    assert m.lookup(7).area_m2 == pytest.approx(math.pi * 0.01)
    assert m.lookup(9).area_m2 is None and m.lookup(9).freq_hz == 2000
    assert m.lookup(3).area_m2 == pytest.approx(0.03) and m.lookup(1234) is None
    save_map(str(tmp_path / "again.json"), m)
    assert load_map(str(tmp_path / "again.json")) == m


def test_xy_addressing_resolves_ids_from_their_bits():
    m = parse_map({"units": "m", "addressing": "xy", "ceiling_z": 3.0, "shape": "square",
                   "size": [0.1, 0.1], "rate_hz": 20000, "leds": []})
    led = m.lookup(0x1432)  # x = 0x14 = 20 dm, y = 0x32 = 50 dm
    assert (led.x, led.y, led.z) == (2.0, 5.0, 3.0) and led.area_m2 == pytest.approx(0.01)
    assert isinstance(m, LedMap) and m.lookup(0x10000) is None


@pytest.mark.parametrize("obj,reason", [
    ([], "JSON object"),
    ({"units": "ft", "leds": []}, "units"),
    ({"leds": [{"id": 1, "x": 0, "y": 0, "z": 0}, {"id": 1, "x": 0, "y": 0, "z": 0}]}, "twice"),
    ({"leds": [{"id": 1, "x": 0, "y": 0}]}, "'z'"),
    ({"leds": [{"id": -1, "x": 0, "y": 0, "z": 0}]}, "'id'"),
    ({"leds": [{"id": 1, "x": 0, "y": 0, "z": 0, "shape": "hexagon", "size": [1]}]}, "shape"),
    ({"leds": [{"id": 1, "x": 0, "y": 0, "z": 0, "shape": "rect", "size": [1]}]}, "rect"),
    ({"leds": [{"id": 1, "mode": "tone", "x": 0, "y": 0, "z": 0}]}, "freq_hz"),
    ({"leds": [{"id": 1, "x": "a", "y": 0, "z": 0}]}, "'x'"),
    ({"addressing": "xy", "leds": []}, "ceiling_z"),
    ({"leds": []}, "no LEDs"),
])
def test_bad_maps_are_one_line_errors(obj, reason):
    with pytest.raises(InputError) as e:
        parse_map(obj)
    assert reason in str(e.value) and "\n" not in str(e.value)


def test_map_not_json(tmp_path):
    p = tmp_path / "map.json"
    p.write_bytes(b"\xff\xfe{")
    with pytest.raises(InputError, match="not valid JSON"):
        load_map(str(p))
