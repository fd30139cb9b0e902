"""Device state shared by several `occloc serve` processes in Redis (`--state redis://HOST:PORT/DB`).

Each device's state (its filter or positioner, last seq, the address its name is bound to) is
one Redis value, `occloc:dev:<device>`, written after every batch of datagrams with an expiry of
`forget_s`: Redis's expiry does the thesis 4.4 forgetting, for every server at once. A keyed
device's last seq is `occloc:keyseq:<device>` (no expiry: no replay, ever). Every position is
published on the channel `occloc:fixes` (JSON: `server`, `device`, `t`, `t_device`, `position`,
`ids`), and every server relays the other servers' fixes into its own live view, so any of
them answers the HTTP API and stream for the whole fleet.

A batch costs two round trips (one MGET before, one pipeline of SETs and PUBLISHes after), so a
device may move between servers between any two datagrams (a UDP balancer, SO_REUSEPORT, or a
failover when one dies). The values are pickles (the filter objects as they are, the map and
compiled kernels by reference): Redis is the servers' own back end, to be reachable by them only.
"""

from __future__ import annotations

import copyreg
import importlib
import io
import json
import pickle
import secrets
import threading
import types
from urllib.parse import urlsplit

from receiver.core.errors import InputError

CHANNEL = "occloc:fixes"
DEVICE_KEY = "occloc:dev:"
KEYSEQ_KEY = "occloc:keyseq:"
# The wait for Redis (s): connecting, and each command; a slower Redis is an error.
TIMEOUT_S = 5.0


def check_url(url: str) -> None:
    """InputError unless url is redis://HOST:PORT/DB."""
    try:
        parts = urlsplit(url)
        port = parts.port
        db = parts.path.strip("/")
    except ValueError:
        port, db, parts = None, "", None
    if parts is None or parts.scheme != "redis" or not parts.hostname or not port \
            or not (db == "" or db.isdigit()) or parts.query or parts.fragment:
        raise InputError(f"--state must be redis://HOST:PORT/DB, not {url!r}")


def _server_map():
    """Stands for the server's LED map in a stored value (`_Unpickler.find_class` gives each
    server its own map object): the map is the servers' configuration, not device state."""
    raise pickle.UnpicklingError("the LED map is resolved by the unpickler")


def _module(name: str):
    return importlib.import_module(name)


class _Unpickler(pickle.Unpickler):
    def __init__(self, f, led_map):
        super().__init__(f)
        self.led_map = led_map

    def find_class(self, module, name):
        if module == __name__ and name == "_server_map":
            return lambda: self.led_map
        return super().find_class(module, name)


class SharedState:
    """The Redis side of a LightingServer (`LightingServer(shared=...)`). `url`:
    redis://HOST:PORT/DB. InputError when Redis does not answer."""

    def __init__(self, url: str, led_map, forget_s: float):
        import redis

        check_url(url)
        self.led_map, self.forget_ms = led_map, max(1, int(round(forget_s * 1000)))
        self.server_id = secrets.token_hex(6)
        self.url = url
        self.redis = redis.Redis.from_url(url, socket_timeout=TIMEOUT_S, socket_connect_timeout=TIMEOUT_S)
        try:
            self.redis.ping()
        except redis.RedisError as e:
            raise InputError(f"--state {url}: {e}") from None
        self._events: list[bytes] = []
        self._relay = None
        # Each device's value as this server last wrote it: a value read back unchanged is this
        # server's own device object, which is kept instead of unpickled (`load`).
        self._written: dict[str, bytes] = {}
        # The reductions (in C, per type, no call per object): the compiled kernels by name,
        # the server's map by reference.
        self._dispatch = copyreg.dispatch_table.copy()
        self._dispatch[types.ModuleType] = lambda mod: (_module, (mod.__name__,))
        self._dispatch[type(led_map)] = self._reduce_map

    def _reduce_map(self, obj):
        return (_server_map, ()) if obj is self.led_map else obj.__reduce_ex__(5)

    def dumps(self, dev) -> bytes:
        f = io.BytesIO()
        p = pickle.Pickler(f, protocol=5)
        p.dispatch_table = self._dispatch
        p.dump(dev)
        return f.getvalue()

    def loads(self, data: bytes):
        return _Unpickler(io.BytesIO(data), self.led_map).load()

    def load(self, names, local=None) -> tuple[dict, dict]:
        """({device: its stored state or None}, {device: keyed last seq or None}) in one round trip.
        `local`: this server's device objects by name; one whose stored value is still what
        this server wrote is returned as it is (the same state, not unpickled again)."""
        names = list(names)
        local = local or {}
        values = self.redis.mget([DEVICE_KEY + n for n in names] + [KEYSEQ_KEY + n for n in names])
        devs = {}
        for n, v in zip(names, values):
            if v is None:
                devs[n] = None
            elif n in local and self._written.get(n) == v:
                devs[n] = local[n]
            else:
                self._written.pop(n, None)
                devs[n] = self.loads(v)
        seqs = {n: None if v is None else int(v) for n, v in zip(names, values[len(names):])}
        return devs, seqs

    def publish(self, device: str, event: dict) -> None:
        """Queue a fix event for the next `save`."""
        self._events.append(json.dumps({**event, "server": self.server_id}, separators=(",", ":")).encode())

    def publish_fix(self, device: str, t: float, t_device: float, position, ids) -> None:
        """`publish` of a fix whose `position` is its JSON already (bytes; or a dict, or None):
        the event's bytes are joined, not encoded again (json.dumps' output for the same event)."""
        if not isinstance(position, bytes):
            self.publish(device, {"device": device, "t": t, "t_device": t_device, "position": position,
                                  "ids": list(ids)})
            return
        self._events.append(b"".join((
            b'{"device":', json.dumps(device).encode(), b',"t":', repr(float(t)).encode(), b',"t_device":',
            json.dumps(t_device).encode(), b',"position":', position, b',"ids":[',
            ",".join(str(int(i)) for i in ids).encode(), b'],"server":"', self.server_id.encode(), b'"}')))

    def save(self, devices: dict, key_seqs: dict) -> None:
        """Write the devices' states (expiring after forget_s) and keyed seqs, and publish the
        queued events, in one round trip."""
        pipe = self.redis.pipeline(transaction=False)
        written = {name: self.dumps(dev) for name, dev in devices.items()}
        for name, data in written.items():
            pipe.set(DEVICE_KEY + name, data, px=self.forget_ms)
        for name, seq in key_seqs.items():
            pipe.set(KEYSEQ_KEY + name, seq)
        for e in self._events:
            pipe.publish(CHANNEL, e)
        self._events = []
        try:
            pipe.execute()
        except BaseException:
            for name in written:
                self._written.pop(name, None)
            raise
        self._written.update(written)

    def forget(self, name: str) -> None:
        """This server no longer holds the device (it may still be stored)."""
        self._written.pop(name, None)

    def drop(self, name: str) -> None:
        self._written.pop(name, None)
        self.redis.delete(DEVICE_KEY + name)

    def relay(self, on_event) -> None:
        """Call on_event(event dict) for every other server's fix, from a thread of its own."""
        pubsub = self.redis.pubsub(ignore_subscribe_messages=True)
        pubsub.subscribe(CHANNEL)
        self._relay = pubsub

        def loop():
            import redis
            while self._relay is not None:
                try:
                    msg = pubsub.get_message(timeout=0.5)
                except (redis.RedisError, ValueError, OSError):
                    if self._relay is None:
                        return
                    continue
                if msg is None or msg.get("type") != "message":
                    continue
                try:
                    event = json.loads(msg["data"])
                except ValueError:
                    continue
                if isinstance(event, dict) and event.get("server") != self.server_id:
                    on_event(event)

        threading.Thread(target=loop, name="occloc-relay", daemon=True).start()

    def close(self) -> None:
        pubsub, self._relay = self._relay, None
        if pubsub is not None:
            try:
                pubsub.close()
            except Exception:   # noqa: BLE001 -- closing a dead connection
                pass
        self.redis.close()
