"""Where the lighting server keeps what it serves (thesis 4.2.1: the server "stores the
information for future purpose"): every accepted fix in SQLite (`occloc serve --db FILE`), the
live view of each device for the HTTP API, and the feed of new fixes for live streams.

`FixStore`: fixes are queued by the UDP thread (`add`, never blocking on the disk) and written
in batches, one transaction each, by a writer thread; `close()` writes what is queued (SIGTERM
loses no fix). The database is in WAL mode (readers never wait for the writer); fixes older than
`retention_s` are deleted as new ones arrive (at most once a minute). A keyed device's last
accepted seq is stored too, so a restarted server refuses replays (`seqs`).

Table `fixes`: device, t (server wall clock, Unix s), t_device (the frame time the device sent,
s), x, y, z (map m), position (the `occloc run` position object, JSON: covariance and all),
ids (JSON list of the LED IDs the device sent).
"""

from __future__ import annotations

import json
import queue
import sqlite3
import threading
import time

from receiver.core.errors import InputError

DEFAULT_RETENTION_S = 7 * 24 * 3600.0
# Fixes written per transaction at most; the writer takes what is queued, never waits to fill.
WRITE_BATCH = 2000
# Fixes queued at most (about 10 s at 10,000/s); beyond it new fixes are dropped and counted.
MAX_QUEUED = 100_000
PRUNE_EVERY_S = 60.0
# Fixes one track request returns at most (the oldest first: page on with `since`).
MAX_TRACK_ROWS = 10_000

_SCHEMA = """
CREATE TABLE IF NOT EXISTS fixes (device TEXT NOT NULL, t REAL NOT NULL, t_device REAL,
    x REAL, y REAL, z REAL, position TEXT NOT NULL, ids TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS fixes_device_t ON fixes (device, t);
CREATE INDEX IF NOT EXISTS fixes_t ON fixes (t);
CREATE TABLE IF NOT EXISTS seqs (device TEXT PRIMARY KEY, seq INTEGER NOT NULL);
"""


class FixStore:
    """SQLite at `path` (created if missing). `retention_s`: fixes older than this are deleted."""

    def __init__(self, path: str, retention_s: float = DEFAULT_RETENTION_S, clock=time.time):
        self.path, self.retention_s, self.clock = path, retention_s, clock
        try:
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
        except sqlite3.Error as e:
            raise InputError(f"--db {path}: {e}") from None
        self._lock = threading.Lock()      # one connection, used by the writer and the readers
        self._queue: queue.Queue = queue.Queue(MAX_QUEUED)
        self.dropped = 0
        self.written = 0
        self._pruned = 0.0
        self._writer = threading.Thread(target=self._write_loop, name="occloc-store", daemon=True)
        self._writer.start()

    def seqs(self) -> dict[str, int]:
        """device -> last accepted seq, as stored."""
        with self._lock:
            return dict(self._db.execute("SELECT device, seq FROM seqs").fetchall())

    def add(self, device: str, t_device: float | None, position: dict, ids, seq: int | None = None) -> None:
        """Queue one fix (`seq`: a keyed device's seq to keep); never blocks."""
        try:
            self._queue.put_nowait((device, self.clock(), t_device, position, list(ids), seq))
        except queue.Full:
            self.dropped += 1

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            batch = [item]
            stop = False
            while len(batch) < WRITE_BATCH:
                try:
                    nxt = self._queue.get_nowait()
                except queue.Empty:
                    break
                if nxt is None:
                    stop = True
                    break
                batch.append(nxt)
            self._write(batch)
            if stop:
                return

    def _write(self, batch) -> None:
        rows = [(d, t, td, p.get("x"), p.get("y"), p.get("z"), json.dumps(p, separators=(",", ":")),
                 json.dumps(ids)) for d, t, td, p, ids, _ in batch]
        seqs = {d: s for d, _, _, _, _, s in batch if s is not None}
        with self._lock:
            try:
                self._db.execute("BEGIN")
                self._db.executemany("INSERT INTO fixes VALUES (?, ?, ?, ?, ?, ?, ?, ?)", rows)
                self._db.executemany("INSERT INTO seqs VALUES (?, ?) ON CONFLICT(device) DO UPDATE "
                                     "SET seq = max(seq, excluded.seq)", list(seqs.items()))
                now = self.clock()
                if now - self._pruned > PRUNE_EVERY_S:
                    self._db.execute("DELETE FROM fixes WHERE t < ?", (now - self.retention_s,))
                    self._pruned = now
                self._db.execute("COMMIT")
                self.written += len(rows)
            except sqlite3.Error:
                self._db.execute("ROLLBACK") if self._db.in_transaction else None
                self.dropped += len(rows)

    def track(self, device: str, since: float | None = None, until: float | None = None,
              limit: int = MAX_TRACK_ROWS) -> list[dict]:
        """The stored fixes of a device with since <= t <= until (server Unix s), oldest first."""
        q = "SELECT t, t_device, position, ids FROM fixes WHERE device = ? AND t >= ? AND t <= ? ORDER BY t LIMIT ?"
        with self._lock:
            rows = self._db.execute(q, (device, -1e300 if since is None else since,
                                        1e300 if until is None else until, limit)).fetchall()
        return [{"t": t, "t_device": td, "position": json.loads(p), "ids": json.loads(i)} for t, td, p, i in rows]

    def close(self) -> None:
        """Write everything queued, then close the database."""
        if self._writer.is_alive():
            self._queue.put(None)
            self._writer.join()
        with self._lock:
            self._db.close()
