"""Intrinsics from rendered chessboard views (receiver.calibrate.intrinsics, `occloc calibrate intrinsics`)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from receiver.calibrate.intrinsics import ViewCollector, calibrate_views, parse_board
from receiver.cli import main as occloc
from receiver.core.errors import InputError
from receiver.io.camera import load_camera

ROOT = Path(__file__).resolve().parents[2]
W, H = 800, 600
K_TRUE = np.array([[820.0, 0.0, 405.0], [0.0, 815.0, 296.0], [0.0, 0.0, 1.0]])
DIST_TRUE = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])
COLS, ROWS, SQ = 9, 6, 0.03  # inner corners, 30 mm squares
SS = 4  # supersampling


def render_view(rvec, tvec, rng, *, blur=0.0) -> np.ndarray:
    """A chessboard of (COLS+1) x (ROWS+1) squares seen by K_TRUE/DIST_TRUE, each square's
    edges densely projected (distortion bends them), filled at SS x resolution and area-averaged."""
    big = np.full((H * SS, W * SS), 200, np.uint8)
    t = np.linspace(0, 1, 9)[:-1]
    polys = []
    for i in range(-1, COLS):
        for j in range(-1, ROWS):
            if (i + j) % 2:
                continue
            x0, y0 = i * SQ, j * SQ
            c = [(x0, y0), (x0 + SQ, y0), (x0 + SQ, y0 + SQ), (x0, y0 + SQ)]
            pts = []
            for k in range(4):
                a, b = np.array(c[k]), np.array(c[(k + 1) % 4])
                pts += [a + (b - a) * s for s in t]
            obj = np.hstack((np.array(pts), np.zeros((len(pts), 1))))
            img, _ = cv2.projectPoints(obj, rvec, tvec, K_TRUE, DIST_TRUE)
            polys.append(np.round((img.reshape(-1, 2) + 0.5) * SS * 16 - 0.5 * 16).astype(np.int32))
    cv2.fillPoly(big, polys, 30, lineType=cv2.LINE_8, shift=4)
    img = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA).astype(np.float32)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    img += rng.normal(0, 1.5, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def random_poses(n, rng):
    out = []
    centre = np.array([(COLS - 1) * SQ / 2, (ROWS - 1) * SQ / 2, 0.0])
    for _ in range(n):
        ang = np.radians(rng.uniform(-40, 40, 3)) * np.array([1, 1, 0.5])
        R, _ = cv2.Rodrigues(ang)
        z = rng.uniform(0.45, 0.7)
        off = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), z])
        t = off - R @ centre
        out.append((ang.reshape(3, 1), t.reshape(3, 1)))
    return out


@pytest.fixture(scope="module")
def board_folder(tmp_path_factory):
    rng = np.random.default_rng(11)
    folder = tmp_path_factory.mktemp("board")
    for k, (r, t) in enumerate(random_poses(20, rng)):
        cv2.imwrite(str(folder / f"v{k:02d}.png"), render_view(r, t, rng))
    r, t = random_poses(1, rng)[0]
    cv2.imwrite(str(folder / "v20_dup.png"), cv2.imread(str(folder / "v00.png"), cv2.IMREAD_GRAYSCALE))
    cv2.imwrite(str(folder / "v21_blur.png"), render_view(r, t, rng, blur=4.0))
    return folder


def test_recovers_intrinsics(board_folder):
    col = ViewCollector(parse_board(f"chess:{COLS}x{ROWS}", SQ * 1000))
    for k, p in enumerate(sorted(board_folder.glob("*.png"))):
        col.add(k, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
    assert col.stats.duplicate >= 1 and col.stats.blurred >= 1
    res = calibrate_views(col)
    K = res.K
    for got, want in ((K[0, 0], 820.0), (K[1, 1], 815.0), (K[0, 2], 405.0), (K[1, 2], 296.0)):
        assert abs(got / want - 1) < 0.003, (got, want)
    assert 0 < res.rms_px < 0.3
    assert len(res.per_view_px) == len(res.frames) >= 12


def test_cli_writes_camera_keeping_existing_keys(board_folder, tmp_path, capsys):
    existing = tmp_path / "old.yaml"
    existing.write_text((ROOT / "recordings" / "indoor-static" / "camera.yaml").read_text())
    out = tmp_path / "new.yaml"
    assert occloc(["calibrate", "intrinsics", str(board_folder), "--board", f"chess:{COLS}x{ROWS}",
                   "--square-mm", "30", "--out", str(out), "--camera", str(existing)]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["rms_px"] > 0 and len(line["per_view_px"]) == line["views"]
    cam = load_camera(str(out))
    assert (cam.width, cam.height) == (W, H)
    assert abs(cam.fx / 820 - 1) < 0.003 and abs(cam.cy / 296 - 1) < 0.003
    old = load_camera(str(existing))
    # kept from EXISTING (scaled to the frames' size): row time per row, exposure, fps
    assert cam.exposure_us == old.exposure_us and cam.fps == old.fps and cam.row_readout_us > 0
    # never overwrite an input
    assert occloc(["calibrate", "intrinsics", str(board_folder), "--board", f"chess:{COLS}x{ROWS}",
                   "--square-mm", "30", "--out", str(existing), "--camera", str(existing)]) == 2


def test_no_board_is_one_line_error(tmp_path, capsys):
    folder = tmp_path / "empty"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), rng.integers(0, 255, (240, 320), np.uint8))
    col = ViewCollector(parse_board("chess:9x6", 30))
    for i, p in enumerate(sorted(folder.glob("*.png"))):
        col.add(i, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
    with pytest.raises(InputError):
        calibrate_views(col)
    rc = occloc(["calibrate", "intrinsics", str(folder), "--board", "chess:9x6", "--square-mm", "30",
                 "--out", str(tmp_path / "c.yaml")])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and err[-1].startswith("occloc: no usable board view")
    assert not (tmp_path / "c.yaml").exists()


def test_board_specs():
    b = parse_board("charuco:7x5:DICT_4X4_50", 30, 22)
    assert b.kind == "charuco" and b.charuco() is not None
    for bad in ("chess:9", "charuco:7x5:NOPE", "hex:3x3"):
        with pytest.raises(InputError):
            parse_board(bad, 30, 22)
    with pytest.raises(InputError):
        parse_board("charuco:7x5:DICT_4X4_50", 30, None)


def test_charuco_views():
    b = parse_board("charuco:7x5:DICT_4X4_50", 30, 22)
    board = b.charuco()
    flat = board.generateImage((700, 500), marginSize=20)
    col = ViewCollector(b, min_move_frac=0.0)
    rng = np.random.default_rng(3)
    src = np.float32([[0, 0], [700, 0], [700, 500], [0, 500]])
    for k in range(6):
        dst = src * 0.8 + np.float32(rng.uniform(0, 80, (4, 2))) + 40
        Hm = cv2.getPerspectiveTransform(src, dst)
        img = cv2.warpPerspective(flat, Hm, (800, 600), borderValue=255)
        assert col.add(k, img) == "accepted"
    res = calibrate_views(col)
    assert np.isfinite(res.rms_px) and len(res.frames) == 6  # arbitrary homographies: no exact pinhole fit


def test_portrait_and_landscape_photos_of_one_camera(board_folder, tmp_path, capsys):
    """A phone's portrait shots beside its landscape ones: each portrait photo is turned to the
    camera's (landscape) orientation as `occloc run` turns it, and every view is used."""
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    names = sorted(p.name for p in board_folder.glob("v??.png"))
    for k, name in enumerate(names):
        img = cv2.imread(str(board_folder / name), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(mixed / name), cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE) if k % 2 else img)
    out = tmp_path / "cam.yaml"
    assert occloc(["calibrate", "intrinsics", str(mixed), "--board", f"chess:{COLS}x{ROWS}",
                   "--square-mm", "30", "--out", str(out)]) == 0
    cap = capsys.readouterr()
    line = json.loads(cap.out.strip().splitlines()[-1])
    assert line["frames_seen"] == len(names) and line["views"] >= 16, line
    assert f"{len(names) // 2} photo(s) turned to the camera's landscape orientation (800x600)" in cap.err
    cam = load_camera(str(out))
    assert (cam.width, cam.height) == (W, H)
    for got, want in ((cam.fx, 820.0), (cam.fy, 815.0), (cam.cx, 405.0), (cam.cy, 296.0)):
        assert abs(got / want - 1) < 0.003, (got, want)
    assert line["rms_px"] < 0.3


def test_portrait_photos_only_follow_the_existing_cameras_orientation(board_folder, tmp_path, capsys):
    """Only portrait photos and no camera file: landscape (sensor rows along the long side); with
    a portrait camera file, they stay portrait; a photo of another size is skipped and named."""
    portrait = tmp_path / "portrait"
    portrait.mkdir()
    for name in sorted(p.name for p in board_folder.glob("v??.png"))[:10]:
        img = cv2.imread(str(board_folder / name), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(portrait / name), cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE))
    cv2.imwrite(str(portrait / "z_small.png"), np.zeros((300, 400), np.uint8))
    out = tmp_path / "cam.yaml"
    assert occloc(["calibrate", "intrinsics", str(portrait), "--board", f"chess:{COLS}x{ROWS}",
                   "--square-mm", "30", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "z_small.png: 400x300, not the 800x600 of the first photo" in err
    cam = load_camera(str(out))
    assert (cam.width, cam.height) == (W, H) and abs(cam.cy / 296.0 - 1) < 0.005
    from receiver.io.camera import CameraModel, camera_yaml
    upright = tmp_path / "upright.yaml"
    upright.write_text(camera_yaml(CameraModel(H, W, np.array([[800.0, 0, 299.5], [0, 800.0, 399.5], [0, 0, 1]]),
                                               np.zeros(5), row_readout_us=20.0)))
    out2 = tmp_path / "cam2.yaml"
    assert occloc(["calibrate", "intrinsics", str(portrait), "--board", f"chess:{COLS}x{ROWS}",
                   "--square-mm", "30", "--out", str(out2), "--camera", str(upright)]) == 0
    cam2 = load_camera(str(out2))
    assert (cam2.width, cam2.height) == (H, W)


def test_a_large_view_is_searched_downscaled_and_refined_at_full_resolution(board_folder, monkeypatch):
    """The board search sees at most `max_search_px` pixels (OpenCV's search costs ~0.25 GB per
    megapixel: a 33 MP photo took 7 GB), the corners are refined on the full image: the
    intrinsics stay as accurate as a search at full size."""
    searched = []
    real = cv2.findChessboardCornersSB

    def spy(img, *a, **kw):
        searched.append(img.shape[0] * img.shape[1])
        return real(img, *a, **kw)
    monkeypatch.setattr(cv2, "findChessboardCornersSB", spy)
    limit = W * H // 4
    col = ViewCollector(parse_board(f"chess:{COLS}x{ROWS}", SQ * 1000), max_search_px=limit)
    for k, p in enumerate(sorted(board_folder.glob("v??.png"))):
        col.add(k, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
    assert searched and max(searched) <= limit
    assert col.search_size is not None and col.search_size[0] * col.search_size[1] <= limit
    res = calibrate_views(col)
    K = res.K
    for got, want in ((K[0, 0], 820.0), (K[1, 1], 815.0), (K[0, 2], 405.0), (K[1, 2], 296.0)):
        assert abs(got / want - 1) < 0.003, (got, want)
    assert 0 < res.rms_px < 0.3 and len(res.frames) >= 16


def test_sharpness_of_a_large_view_is_judged_at_the_search_scale(board_folder):
    """A sharp view taken at 3x the resolution has edges three times as many pixels wide: judged
    on the full image it would be 'blurred'; judged where it is searched, it is accepted, and
    its full-resolution corners give the intrinsics of the larger image."""
    col = ViewCollector(parse_board(f"chess:{COLS}x{ROWS}", SQ * 1000), max_search_px=W * H)
    names = sorted(board_folder.glob("v??.png"))[:8]
    got = [col.add(k, cv2.resize(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (3 * W, 3 * H),
                                 interpolation=cv2.INTER_CUBIC)) for k, p in enumerate(names)]
    assert got.count("accepted") == len(names), got
    res = calibrate_views(col)
    K = res.K
    for got_v, want in ((K[0, 0], 3 * 820.0), (K[1, 1], 3 * 815.0), (K[0, 2], 3 * 405.5 - 0.5),
                        (K[1, 2], 3 * 296.5 - 0.5)):
        assert abs(got_v / want - 1) < 0.005, (got_v, want)
