"""The lighting server's client: `occloc run --server udp://HOST:PORT` (thesis 4.3).

`RemotePositioner` has the interface of `receiver.locate.indoor.Positioner` (`step(t_s, leds) ->
LocateResult`, `unknown_ids`, `n_fixes`) but solves on a lighting server (`receiver.serve.server`):
ranging stays on the device, done by a local `Positioner`'s `measure`, `_ranges` and
`image_points`; the server gets one v1 datagram per frame (LED IDs, undistorted normalized image
points, ranges) and answers with the filtered position.

Orientation for ranging: the oblique range estimator needs the camera orientation (the previous
fix's, then this frame's own for the reported distances). The server's reply carries its fix's
world-to-camera rotation in the solving frame (`solve_R_cw`, full precision), and the device keeps
the latest one for `max_coast_s` seconds, the rule of `PoseFilter.R_prior`. With every reply
received, the distances and positions equal those of a local `Positioner` with the same options.

What the server does not know: `solver` (always "auto") and the ranging re-solve loop
(`ranging_iterations` 0), and the filter options (the server uses `PoseFilter`'s defaults), so
only the ranging and image-point options of `Positioner` are accepted (`CLIENT_OPTIONS`).
At most `receiver.serve.wire.MAX_LEDS` LEDs (the first, in track order) are sent per frame.

Every wait is bounded: a frame whose reply does not come within `timeout_s` (or whose port is
closed) has no position and is counted in `timeouts`; error replies are counted in `errors`
(`last_error` keeps the reason); replies to older frames are discarded.
"""

from __future__ import annotations

import json
import os
import secrets
import socket
import time
from urllib.parse import urlsplit

import numpy as np

from receiver.core.errors import InputError
from receiver.locate.indoor import Positioner
from receiver.core.records import LocateResult
from receiver.serve.wire import MAX_DEVICE_CHARS, MAX_LEDS, PROTOCOL_VERSION, encode, make_request

DEFAULT_TIMEOUT_S = 0.2
MAX_REPLY_BYTES = 65535
# The local Positioner's options the client may set: ranging and image points only.
CLIENT_OPTIONS = frozenset({"ranging", "pixel_sigma_px", "edge_sigma_px", "model_rel_sigma",
                            "edge_offset_px", "border_margin_px"})


def parse_udp_url(url: str) -> tuple[str, int]:
    """(host, port) of `udp://HOST:PORT` (IPv6 hosts in brackets); InputError otherwise."""
    bad = InputError(f"--server must be udp://HOST:PORT with a port in 1..65535, not {url!r}")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:
        raise bad from None
    if parts.scheme != "udp" or not parts.hostname or not port or parts.path not in ("", "/") \
            or parts.query or parts.fragment or parts.username:
        raise bad
    return parts.hostname, port


def default_device() -> str:
    """A device name unique to this client (a restarted client is a new device to the server)."""
    return f"occloc-{os.getpid()}-{secrets.token_hex(4)}"


def _connect(url: str) -> socket.socket:
    host, port = parse_udp_url(url)
    try:
        family, kind, proto, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        sock = socket.socket(family, kind, proto)
    except OSError as e:
        raise InputError(f"--server {url}: {e.strerror or e}") from None
    try:
        sock.connect(addr)     # only the server's datagrams are received
    except OSError as e:
        sock.close()
        raise InputError(f"--server {url}: {e.strerror or e}") from None
    return sock


def _reply_object(data: bytes) -> dict | None:
    try:
        obj = json.loads(data)
    except ValueError:
        return None
    return obj if isinstance(obj, dict) and obj.get("v") == PROTOCOL_VERSION else None


class RemotePositioner:
    """`Positioner` whose solve and Kalman filter run on a lighting server at `url`
    (`udp://HOST:PORT`). `device`: the name the server knows this receiver by (default: unique
    per instance). `timeout_s`: the longest wait for a frame's reply. `ranging_kw`: options of
    the local `Positioner` from `CLIENT_OPTIONS`. Close with `close()` or a `with` block."""

    def __init__(self, camera, led_map, url: str, *, device: str | None = None,
                 timeout_s: float = DEFAULT_TIMEOUT_S, **ranging_kw):
        extra = set(ranging_kw) - CLIENT_OPTIONS
        if extra:
            raise TypeError(f"options not supported with a lighting server: {sorted(extra)}")
        self.device = device if device is not None else default_device()
        if not 1 <= len(self.device) <= MAX_DEVICE_CHARS:
            raise ValueError(f"device names have 1..{MAX_DEVICE_CHARS} characters")
        if not timeout_s > 0:
            raise ValueError("timeout_s must be positive")
        self.local = Positioner(camera, led_map, **ranging_kw)
        self.url, self.timeout_s = url, timeout_s
        self.sock = _connect(url)
        self.seq = 0                    # of the next request
        self.timeouts = 0
        self.errors = 0
        self.last_error: str | None = None
        self._n_fixes = 0

    @property
    def unknown_ids(self) -> set[int]:
        """IDs the local map (or the server's, as replied) does not know."""
        return self.local.unknown_ids

    @property
    def n_fixes(self) -> int:
        """Frames the server had a fix for (`position.raw` not null)."""
        return self._n_fixes

    def step(self, t_s: float, leds) -> LocateResult:
        ranger = self.local.ranger
        items = ranger.usable(leds)[:MAX_LEDS]
        # the server's replied orientations, kept by the rule of a local receiver (R_prior)
        d, sd, names = ranger.ranges(items, self.local.pose.R_prior(t_s))
        request = make_request(self.device, self.seq, t_s, self.local.pose.sigma_uv,
                               [obs.id for obs, _, _ in items], ranger.image_points(items), d, sd)
        self.seq += 1
        reply = self._exchange(request)
        position = None
        if reply is not None:
            position, R = self._accept(reply, t_s)
            if R is not None and self.local.ranging == "oblique":
                d, sd, names = ranger.ranges(items, R)    # this frame's own orientation
        return LocateResult(position=position, leds=ranger.annotate(leds, items, d, names))

    def _accept(self, reply: dict, t_s: float) -> tuple[dict | None, np.ndarray | None]:
        """(position, solving-frame R_cw or None) of a matching reply; keeps its orientation."""
        position = reply.get("position")
        if not isinstance(position, dict):
            position = None
        ids = reply.get("unknown_ids")
        if isinstance(ids, list):
            self.local.unknown_ids.update(i for i in ids if type(i) is int)
        if position is not None and position.get("raw") is not None:
            self._n_fixes += 1
        try:
            R = np.array(reply.get("solve_R_cw"), dtype=np.float64)
        except (TypeError, ValueError):
            R = None
        if R is None or R.shape != (3, 3) or not np.all(np.isfinite(R)):
            return position, None
        self.local.pose.keep_orientation(t_s, R)
        return position, R

    def _exchange(self, request: dict) -> dict | None:
        """Send one request; its reply, or None after `timeout_s` or an error reply."""
        seq = request["seq"]
        deadline = time.monotonic() + self.timeout_s
        try:
            self.sock.send(encode(request))
        except OSError:
            self.timeouts += 1          # e.g. the refusal of an earlier datagram, reported late
            return None
        while (remaining := deadline - time.monotonic()) > 0:
            self.sock.settimeout(remaining)
            try:
                reply = _reply_object(self.sock.recv(MAX_REPLY_BYTES))
            except OSError:             # timeout, or nothing listens on the port
                break
            if reply is None or reply.get("device") != self.device or reply.get("seq") != seq:
                continue                # a late reply to an earlier frame, or garbage
            if "error" in reply:
                self.errors += 1
                self.last_error = str(reply["error"])
                return None
            return reply
        self.timeouts += 1
        return None

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> "RemotePositioner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
