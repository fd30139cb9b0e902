"""The lighting server's datagrams read ahead of the work, in one queue per source host, taken in
turn (round robin, a datagram of each host with datagrams waiting), so that one source's flood
cannot put its backlog in front of another's datagram: a device behind a flood waits for one
batch of work, not for the flood's queue. A host's own datagrams keep their order.

What one host may hold queued is bounded (bytes), and so is the whole (bytes): a datagram
beyond either is dropped as it is read (`put` says so), which keeps the socket read (and other
hosts' datagrams taken from the kernel's buffer before it overflows) however much one host sends.
"""

from __future__ import annotations

from collections import OrderedDict, deque


class SourceQueues:
    """Datagrams (bytes, address) queued per source host (the address's first item).
    `max_host_bytes` / `max_bytes`: queued bytes of one host / of all at most."""

    def __init__(self, max_host_bytes: int, max_bytes: int):
        self.max_host_bytes, self.max_bytes = max_host_bytes, max_bytes
        self._queues: OrderedDict = OrderedDict()   # host -> [deque of (data, address), bytes]; next host first
        self.count = 0
        self.nbytes = 0

    def put(self, data: bytes, address) -> bool:
        """Queue a datagram; False (not queued) when its host's or the whole bound is reached."""
        host = address[0]
        entry = self._queues.get(host)
        held = 0 if entry is None else entry[1]
        if held + len(data) > self.max_host_bytes or self.nbytes + len(data) > self.max_bytes:
            return False
        if entry is None:
            entry = self._queues[host] = [deque(), 0]
        entry[0].append((data, address))
        entry[1] += len(data)
        self.count += 1
        self.nbytes += len(data)
        return True

    def take(self, max_items: int, max_bytes: int) -> list:
        """Up to `max_items` datagrams, a host's oldest of each host in turn, ending after the one
        that reaches `max_bytes`."""
        out, nbytes = [], 0
        queues = self._queues
        while queues and len(out) < max_items and nbytes < max_bytes:
            host, entry = next(iter(queues.items()))
            item = entry[0].popleft()
            n = len(item[0])
            entry[1] -= n
            out.append(item)
            nbytes += n
            if entry[0]:
                queues.move_to_end(host)
            else:
                del queues[host]
        self.count -= len(out)
        self.nbytes -= nbytes
        return out
