"""Ranging against known geometry: eq. 18 on the axis, the oblique estimator off the axis with
lens distortion and camera tilt, and the contour edge-bias correction on rasterized blobs."""

import math

import cv2
import numpy as np
import pytest

from receiver.io.camera import CameraModel
from receiver.io.ledmap import Led
from receiver.locate.pose import ypr_to_rotation
from receiver.core.records import LedObservation
from receiver.io.ledmap import LedMap
from receiver.locate.ranging import (Ranger, contour_geometry, distance_eq18, led_outline_world,
                                     polygon_area_perimeter, project_world, range_sigma_m, steiner_area)
from receiver.locate.settings import PositionerSettings

LED = Led(id=1, mode="ook", x=0.0, y=0.0, z=3.0, shape="square", size=(0.1, 0.1))


def estimate_distance(contour, area_px, cam, estimator, R_cw=None, edge_offset_px=0.5):
    """(distance m, estimator) of LED through the product's ranging stage (`Ranger`)."""
    ranger = Ranger(cam, LedMap(leds={LED.id: LED}),
                    PositionerSettings(ranging=estimator, edge_offset_px=edge_offset_px,
                                       border_margin_px=-math.inf))  # outlines may leave the frame here
    obs = LedObservation(track=0, cx=float(contour[:, 0].mean()), cy=float(contour[:, 1].mean()),
                         area_px=area_px, contour=contour, id=LED.id, mode="ook")
    (o,) = ranger.range_leds([obs], R_cw)
    return o.distance_m, o.distance_estimator


def camera(dist=(0, 0, 0, 0, 0)):
    K = np.array([[800.0, 0, 640.0], [0, 800.0, 480.0], [0, 0, 1]])
    return CameraModel(1280, 960, K, np.array(dist, float))


def test_eq18_on_axis_is_exact():
    # Fronto-parallel 10 cm square at 2 m under f = 800 px: 40 x 40 px.
    assert distance_eq18(1600.0, 0.01, 800.0) == pytest.approx(2.0)
    assert math.isnan(distance_eq18(0.0, 0.01, 800.0))


@pytest.mark.parametrize("ypr,C", [((0, 90, 0), (0.9, -0.6, 1.0)),
                                   ((30, 70, 10), (1.2, 0.4, 0.8)),
                                   ((-60, 80, -5), (-0.5, 0.9, 1.4))])
def test_oblique_removes_foreshortening_and_distortion(ypr, C):
    cam = camera((-0.1, 0.03, 0.001, -0.001, 0.0))
    R = ypr_to_rotation(*ypr)
    C = np.array(C)
    contour = project_world(led_outline_world(LED, 32), cam, R, C)
    area_px, _ = polygon_area_perimeter(contour)
    d_true = float(np.linalg.norm(LED.xyz - C))
    d_obl, name = estimate_distance(contour, area_px, cam, "oblique", R_cw=R, edge_offset_px=0)
    d_18, name18 = estimate_distance(contour, area_px, cam, "eq18")
    assert (name, name18) == ("oblique-pose", "eq18")
    assert abs(d_obl / d_true - 1) < 1e-3
    # eq. 18 ignores all of it (its error can cancel when the camera tilts towards the LED).
    assert abs(d_18 / d_true - 1) > 3 * abs(d_obl / d_true - 1)


def test_oblique_assuming_camera_looks_up():
    cam = camera()
    R = ypr_to_rotation(0, 90, 0)
    C = np.array([1.0, 0.7, 1.0])
    contour = project_world(led_outline_world(LED, 16), cam, R, C)
    d, name = estimate_distance(contour, 0.0, cam, "oblique", edge_offset_px=0)
    assert name == "oblique-up"
    assert d == pytest.approx(np.linalg.norm(LED.xyz - C), rel=1e-3)


def rasterize_square(side_px, angle_deg, cx=100.3, cy=100.7, size=200):
    """Binary image of a rotated square, thresholded at half coverage (8x supersampled)."""
    ss = 8
    img = np.zeros((size * ss, size * ss), np.uint8)
    rect = ((cx * ss + (ss - 1) / 2, cy * ss + (ss - 1) / 2), (side_px * ss, side_px * ss), angle_deg)
    cv2.fillPoly(img, [np.round(cv2.boxPoints(rect)).astype(np.int32)], 255)
    cover = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return (cover >= 128).astype(np.uint8)


@pytest.mark.parametrize("side_px", [8, 15, 30])
def test_edge_offset_corrects_contour_area_bias(side_px):
    for angle in (0, 17, 40):
        mask = rasterize_square(side_px, angle)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        poly = contours[0].reshape(-1, 2).astype(float)
        area, perim = polygon_area_perimeter(poly)
        true = side_px ** 2
        corrected = steiner_area(area, perim, 0.5)
        # The raw polygon misses about half a pixel all around; the correction recovers most of
        # it (rotated edges leave a staircase whose perimeter over-counts a little).
        assert abs(corrected - true) < 0.6 * abs(area - true)
        assert abs(corrected / true - 1) < 0.6 / side_px + 0.01


def test_contour_geometry_and_sigma():
    cam = camera()
    sq = np.array([[600, 440], [680, 440], [680, 520], [600, 520]], float)
    g = contour_geometry(sq, cam, edge_offset_px=0.0)
    assert g["area_px"] == pytest.approx(6400.0)
    assert g["area_norm"] == pytest.approx(6400.0 / 800 ** 2)
    assert np.allclose(g["centroid_norm"], [0.0, 0.0])
    assert contour_geometry(sq[:2], cam) is None
    # Bigger blobs range better: sigma_d/d falls like 1/sqrt(eta).
    s_small = range_sigma_m(2.0, 100.0, 40.0, edge_sigma_px=0.1, model_rel_sigma=0.0)
    s_big = range_sigma_m(2.0, 10000.0, 400.0, edge_sigma_px=0.1, model_rel_sigma=0.0)
    assert s_small == pytest.approx(10 * s_big)


def test_with_range_equals_dataclasses_replace():
    """`ranging._with_range` (the annotation's fast copy) gives the record `dataclasses.replace`
    gives: every field the same object, the two range fields changed, the original untouched."""
    import dataclasses

    from receiver.core.records import LedObservation
    from receiver.locate.ranging import _with_range

    obs = LedObservation(track=3, cx=10.5, cy=20.25, area_px=99.0, contour=np.zeros((4, 2)), id=7, mode="ook",
                         peak=200.0, edge_px=(np.ones((6, 2)), np.ones(6)))
    fast = _with_range(obs, 2.34567, "outline")
    ref = dataclasses.replace(obs, distance_m=2.34567, distance_estimator="outline")
    assert type(fast) is LedObservation and fast is not obs
    for f in dataclasses.fields(LedObservation):
        assert getattr(fast, f.name) is getattr(ref, f.name) or getattr(fast, f.name) == getattr(ref, f.name), f.name
    assert (fast.distance_m, fast.distance_estimator) == (2.34567, "outline")
    assert obs.distance_m is None and obs.distance_estimator is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.distance_m = 1.0
