"""The lighting server's live view for the HTTP API: each device's latest position and counts
(`snapshot`), and the feed of fixes to live streams (`subscribe`). Written by the UDP thread
(`LightingServer.on_fix` / `on_forget`, and the Redis relay), read by the HTTP thread."""

from __future__ import annotations

import asyncio
import threading
import time

# Fixes waiting for one slow stream reader at most; beyond it its oldest are dropped (a live map
# wants the newest positions, not a backlog).
SUBSCRIBER_QUEUE = 1000


def _offer(q: asyncio.Queue, item) -> None:
    if q.full():
        q.get_nowait()
    q.put_nowait(item)


class LiveView:
    """Latest fix per device and the subscribers of new ones. `clock`: monotonic seconds (for
    `age_s`); `wall`: Unix seconds (each fix's `t`)."""

    def __init__(self, clock=time.monotonic, wall=time.time, forget_s: float | None = None):
        self.clock, self.wall, self.forget_s = clock, wall, forget_s
        self._lock = threading.Lock()
        self._devices: dict[str, dict] = {}
        self._subscribers: list[tuple[asyncio.AbstractEventLoop, asyncio.Queue]] = []

    def fix(self, device: str, t_device: float | None, position: dict | None, ids=(), relayed: bool = False) -> dict:
        """Record one accepted datagram's reply (position None: no fix this frame) and hand
        the fix to every subscriber. Returns the event sent."""
        now, wall = self.clock(), self.wall()
        with self._lock:
            d = self._devices.get(device)
            if d is None:
                d = self._devices[device] = {"device": device, "position": None, "t": None, "seen": now,
                                             "datagrams": 0, "positions": 0}
            d["datagrams"] += 1
            d["seen"] = now
            if position is not None:
                d["positions"] += 1
                d["position"], d["t"] = position, wall
            subs = list(self._subscribers)
        event = {"device": device, "t": wall, "t_device": t_device, "position": position, "ids": list(ids)}
        for loop, q in subs:
            try:
                loop.call_soon_threadsafe(_offer, q, event)
            except RuntimeError:      # its loop has closed
                self.unsubscribe(q)
        return event

    def forget(self, device: str) -> None:
        with self._lock:
            self._devices.pop(device, None)

    def snapshot(self) -> list[dict]:
        """Every live device: `device`, `position` (the latest, as `occloc run` writes it, or
        null), `t` (Unix s of that fix), `age_s` (s since its last datagram), `datagrams`
        (accepted), `positions` (of them with a position)."""
        now = self.clock()
        with self._lock:
            if self.forget_s is not None:
                for name in [n for n, d in self._devices.items() if now - d["seen"] > self.forget_s]:
                    del self._devices[name]
            rows = [dict(d) for d in self._devices.values()]
        for r in rows:
            r["age_s"] = round(max(0.0, now - r.pop("seen")), 3)
        return sorted(rows, key=lambda r: r["device"])

    def subscribe(self) -> asyncio.Queue:
        """A queue of new fixes for the running event loop's stream."""
        q: asyncio.Queue = asyncio.Queue(SUBSCRIBER_QUEUE)
        with self._lock:
            self._subscribers.append((asyncio.get_running_loop(), q))
        return q

    def unsubscribe(self, q: asyncio.Queue) -> None:
        with self._lock:
            self._subscribers = [(lp, x) for lp, x in self._subscribers if x is not q]
