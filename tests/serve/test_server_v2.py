"""Datagram v2 (receiver.serve.wire_v2): a `--server` run gives the local run's positions and
ranges on every bundled recording; failures of the server reach the user's stderr while the run
goes on; packed arrays are lossless and every malformed v2 field is refused with a reason."""

from __future__ import annotations

import base64
import json
import socket
from pathlib import Path

import numpy as np
import pytest

from receiver.cli import main as cli
from receiver.cli import run as run_cli
from receiver.io.camera import load_camera
from receiver.io.ledmap import load_map
from receiver.locate.pose import ypr_to_rotation
from receiver.serve.client import RemotePositioner
from receiver.serve.server import BackgroundServer, LightingServer
from receiver.serve.wire import encode
from receiver.serve.wire_v2 import camera_fields, make_request_v2, pack_column, unpack_column
from tests.locate.test_locate import observe

ROOT = Path(__file__).resolve().parents[2]
RECORDINGS = sorted(p.name for p in (ROOT / "recordings").iterdir() if (p / "map.json").is_file())
WALK = ROOT / "recordings" / "indoor-walk"
TOL_M = 1e-4              # m: a server position is within 0.1 mm of the local run's


class _Tee:
    """A `--server` run's positioner that also steps a local `Positioner` on the same frames
    and keeps both results (the video is decoded once for both)."""

    def __init__(self, remote, local):
        self.remote, self.local, self.pairs = remote, local, []

    def step(self, t_s, leds):
        a, b = self.local.step(t_s, leds), self.remote.step(t_s, leds)
        self.pairs.append((a, b))
        return b

    def __getattr__(self, name):
        return getattr(self.remote, name)


@pytest.mark.parametrize("name", RECORDINGS)
def test_server_run_equals_the_local_run(name, tmp_path, monkeypatch, capsys):
    rec = ROOT / "recordings" / name
    tees = []
    make = run_cli.make_positioner

    def tee(camera, led_map, server=None, **kw):
        t = _Tee(make(camera, led_map, server=server, **kw), make(camera, led_map))
        tees.append(t)
        return t

    monkeypatch.setattr(run_cli, "make_positioner", tee)
    # One trusted source replaying frames as fast as the machine runs: no per-source limits (a
    # real phone's rate and CPU share per second of the server's clock depend on the machine).
    server = LightingServer(load_map(str(rec / "map.json")), source_rate=0)
    with BackgroundServer(server) as bg:
        # A generous reply wait: not a speed test.
        assert cli(["run", str(rec), "--server", bg.url, "--server-timeout", "30",
                    "--out", str(tmp_path / "r.jsonl")]) == 0
    assert "server" not in capsys.readouterr().err          # no timeouts, errors or unknown IDs
    (t,) = tees
    assert t.remote.timeouts == 0 and t.remote.errors == 0 and t.remote.protocol == 2
    n_pos = 0
    for a, b in t.pairs:
        assert (a.position is None) == (b.position is None)
        if a.position is not None:
            n_pos += 1
            assert a.position["method"] == b.position["method"]
            for k in "xyz":
                assert abs(a.position[k] - b.position[k]) <= TOL_M, (k, a.position, b.position)
        da = [(o.track, o.distance_m, o.distance_estimator) for o in a.leds]
        db = [(o.track, o.distance_m, o.distance_estimator) for o in b.leds]
        assert [x[::2] for x in da] == [x[::2] for x in db]
        assert all((x[1] is None) == (y[1] is None) and (x[1] is None or abs(x[1] - y[1]) <= TOL_M)
                   for x, y in zip(da, db))
    lines = (tmp_path / "r.jsonl").read_text().splitlines()
    assert len(lines) == len(t.pairs) and sum(json.loads(x)["position"] is not None for x in lines) == n_pos
    if name.startswith("indoor"):
        assert n_pos >= len(t.pairs) // 2           # the indoor recordings do position
    assert server.counters["positions"] == n_pos


def _frame(cam, led_map, extra_id=None):
    C, R = np.array([3.0, 4.0, 1.0]), ypr_to_rotation(5.0, 88.0, 2.0)
    obs = observe(cam, led_map, C, R)
    obs = sorted(obs, key=lambda o: (o.cx - cam.cx) ** 2 + (o.cy - cam.cy) ** 2)[:6]
    if extra_id is not None:
        from dataclasses import replace
        obs.append(replace(obs[0], track=99, id=extra_id, cx=obs[0].cx + 1.0))
    return obs


def test_unknown_ids_and_a_silent_server_are_reported_while_the_run_goes_on():
    cam, walk_map = load_camera(str(WALK / "camera.yaml")), load_map(str(WALK / "map.json"))
    lines = []
    with BackgroundServer(LightingServer(walk_map, source_rate=0)) as bg, \
            RemotePositioner(cam, walk_map, bg.url, timeout_s=30.0, report=lines.append) as rp:
        for k in range(3):
            res = rp.step(k / 30.0, _frame(cam, walk_map, extra_id=4242))
            assert res.position is not None
    assert rp.unknown_ids == {4242}
    assert lines == [f"occloc: server {bg.url}: LED IDs not in the server's map: 4242"]   # once
    lines.clear()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        url = "udp://127.0.0.1:%d" % silent.getsockname()[1]
        with RemotePositioner(cam, walk_map, url, timeout_s=0.05, report=lines.append) as rp:
            for k in range(3):
                assert rp.step(k / 30.0, _frame(cam, walk_map)).position is None
            assert rp.timeouts == 3
    assert len(lines) == 1 and "no reply within 0.05 s" in lines[0]


def test_packed_columns_are_lossless():
    rng = np.random.default_rng(3)
    for a in (rng.normal(500, 300, 50), np.arange(20) * 0.5, np.zeros(0), np.array([1e-300, -2.5])):
        s = pack_column(a)
        assert s[:3] == ("f4:" if np.array_equal(a.astype(np.float32), a) else "f8:")
        assert np.array_equal(unpack_column(s, "x"), a)
    assert pack_column(np.arange(4) * 0.5).startswith("f4:")


def _v2_request(**change):
    cam, walk_map = load_camera(str(WALK / "camera.yaml")), load_map(str(WALK / "map.json"))
    req = make_request_v2("dev", 0, 0.0, camera_fields(cam), _frame(cam, walk_map))
    for k, v in change.items():
        if k.startswith("obs0_"):
            req["obs"][0][k[5:]] = v
        elif k.startswith("cam_"):
            req["camera"][k[4:]] = v
        else:
            req[k] = v
    return encode(req)


def _b64(a, kind="<f8"):
    return ("f8:" if kind == "<f8" else "f4:") + base64.b64encode(np.asarray(a, kind).tobytes()).decode()


@pytest.mark.parametrize("change, reason", [
    ({"obs0_contour": ["f8:@@@", "f4:"]}, "bad_value"),
    ({"obs0_contour": ["f2:AAAA", "f4:"]}, "bad_value"),
    ({"obs0_contour": [_b64([1.0, 2.0]), _b64([1.0])]}, "bad_value"),
    ({"obs0_contour": [_b64([np.nan]), _b64([1.0])]}, "bad_value"),
    ({"obs0_contour": [_b64([1e9]), _b64([1.0])]}, "bad_value"),
    ({"obs0_contour": [_b64(np.ones(5000), "<f4"), _b64(np.ones(5000), "<f4")]}, "bad_value"),
    ({"obs0_contour": "f8:"}, "bad_type"),
    ({"obs0_edge": [_b64([1.0]), _b64([1.0]), _b64([-1.0])]}, "bad_value"),
    ({"obs0_area_px": 0.0}, "bad_value"),
    ({"obs0_border": 1}, "bad_type"),
    ({"obs0_mode": "s2psk"}, "bad_value"),
    ({"obs0_id": -1}, "bad_value"),
    ({"cam_K": [1.0, 2.0]}, "bad_type"),
    ({"cam_K": [-1000.0, 1000.0, 640.0, 360.0]}, "bad_value"),
    ({"cam_width": 0}, "bad_value"),
    ({"camera": None}, "bad_type"),
    ({"obs": {}}, "bad_type"),
    ({"obs": [{}] * 65}, "too_many_leds"),
])
def test_malformed_v2_requests_are_refused_with_a_reason(change, reason):
    walk_map = load_map(str(WALK / "map.json"))
    server = LightingServer(walk_map)
    reply = server.handle(_v2_request(**change), ("127.0.0.1", 5))
    assert reply["error"] == reason and reply.get("device") == "dev", reply
    assert server.counters[reason] == 1 and not server.devices
    ok = server.handle(_v2_request(), ("127.0.0.1", 5))
    assert ok["v"] == 2 and ok["position"] is not None and len(ok["ranges"]) == 6


def _same_request(a, b):
    assert (a.device, a.seq, a.t, a.camera_key) == (b.device, b.seq, b.t, b.camera_key)
    assert all(np.array_equal(getattr(a.camera, f), getattr(b.camera, f))
               for f in ("K", "dist", "width", "height", "pixel_size_um", "focal_length_mm"))
    assert len(a.leds) == len(b.leds)
    for x, y in zip(a.leds, b.leds):
        assert (x.track, x.cx, x.cy, x.area_px, x.border, x.id, x.mode) == \
            (y.track, y.cx, y.cy, y.area_px, y.border, y.id, y.mode)
        pairs = [(x.contour, y.contour)]
        assert (x.edge_px is None) == (y.edge_px is None)
        if x.edge_px is not None:
            pairs += list(zip(x.edge_px, y.edge_px))
        for p, q in pairs:
            assert p.dtype == q.dtype == np.float64 and p.shape == q.shape and p.flags.c_contiguous
            assert np.array_equal(p, q)


def _edged_frame(rng, cam, frame):
    """A v2 request object of camera `cam` whose observations (`frame`) carry random stripe edge
    points (float32-exact and full float64 columns both)."""
    from dataclasses import replace
    obs = []
    for o in frame:
        n = int(rng.integers(0, 40))
        pts = np.column_stack([rng.uniform(0, cam.width, n), rng.uniform(0, cam.height, n)])
        if rng.random() < 0.5:
            pts = np.round(pts * 4) / 4                 # float32-exact: packed as f4
        obs.append(replace(o, edge_px=(pts, rng.uniform(0.05, 0.5, n))))
    return json.loads(encode(make_request_v2("dev", 3, 0.1, camera_fields(cam), obs)))


def test_fast_v2_check_takes_only_what_the_full_check_takes():
    """The common-form check (`_parse_v2_fast`) gives the full check's request on well-formed
    requests, and on seeded mutations either the full check's request or None (never a request
    the full check refuses)."""
    from receiver.serve.wire import ProtocolError
    from receiver.serve.wire_v2 import _parse_v2_checked, _parse_v2_fast
    rng = np.random.default_rng(11)
    odd = [None, True, 0, -1, 1, 2.5, -0.0, 1e300, 1e-12, 2 ** 31, 2 ** 53 + 1, "x", "ook", [], {},
           ["f4:", "f4:"], ["f8:AAAAAAAA+H8=", "f8:AAAAAAAA8D8="], ["f4:AACAPw==", "f4:AACAPw=="],
           ["f4:AACAPw==", "f4:AACAPw==", "f4:AAAAAA=="], ["f4:AACAPw==", "f4:AACAPw==", "f4:AACAfw=="],
           ["f4:AACAPw=", "f4:AACAPw=="], ["f4:AACA Pw==", "f4:AACAPw=="], ["f8:AACAPw==", "f8:AACAPw=="]]
    cam, walk_map = load_camera(str(WALK / "camera.yaml")), load_map(str(WALK / "map.json"))
    frame = _frame(cam, walk_map)
    taken = refused = 0
    for n in range(300):
        obj = _edged_frame(rng, cam, frame)
        if n:
            pick = obj["obs"][int(rng.integers(0, len(obj["obs"])))]
            where = obj if n % 5 == 0 else obj["camera"] if n % 5 == 1 else pick
            keys = list(where) + ["extra"]
            where[keys[int(rng.integers(0, len(keys)))]] = odd[int(rng.integers(0, len(odd)))]
            obs = obj["obs"]
            if n % 7 == 0 and isinstance(obs, list) and len(obs) > 1 and isinstance(obs[-1], dict) \
                    and isinstance(obs[0], dict):
                obs[-1]["id"] = obs[0].get("id")                      # a repeated LED id
        fast = _parse_v2_fast(obj)
        try:
            full = _parse_v2_checked(obj)
        except ProtocolError:
            assert fast is None, (n, obj)
            refused += 1
            continue
        if fast is not None:
            _same_request(fast, full)
            taken += 1
    assert taken > 30 and refused > 30, (taken, refused)
