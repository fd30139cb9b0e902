"""Device keys of the lighting server: a datagram of a keyed device carries an HMAC-SHA256 over
its device name, its seq and its bytes, checked before the JSON is read.

Signed datagram: one ASCII header line, then the request's JSON bytes (v1 or v2):
    #mac DEVICE SEQ HEX64\\n{"v": 2, "device": "DEVICE", "seq": SEQ, ...}
  HEX64 = hex(HMAC-SHA256(key, b"#mac DEVICE SEQ " + json)); the JSON's `device` and `seq`
  must be the header's. A keyed device's name has no whitespace.

Keys file (`occloc serve --keys FILE`; the device's own, with its one line, `occloc run
--key-file FILE`): one `DEVICE HEXKEY` per line (key at least MIN_KEY_BYTES bytes, hex), blank
lines and `#` comments ignored. Make a key with `python -c "import secrets; print(secrets.token_hex(32))"`.
"""

from __future__ import annotations

import hashlib
import hmac

from receiver.core.errors import InputError
from receiver.serve.wire import MAX_DEVICE_CHARS, MAX_SEQ, ProtocolError

PREFIX = b"#mac "
MIN_KEY_BYTES = 16
MAX_KEYS_FILE_BYTES = 1 << 24
# The header line is at most this long: "#mac " + 64-character name + 16-digit seq + 64 hex digits.
MAX_HEADER_BYTES = 160


def _head(device: str, seq: int) -> bytes:
    return b"%s%s %d " % (PREFIX, device.encode("ascii"), seq)


def sign(key: bytes, device: str, seq: int, body: bytes) -> bytes:
    """The signed datagram of a request's JSON bytes."""
    head = _head(device, seq)
    return head + hmac.new(key, head + body, hashlib.sha256).hexdigest().encode("ascii") + b"\n" + body


def verify(data: bytes, keys: dict) -> tuple[str, int, bytes]:
    """(device, seq, JSON bytes) of a signed datagram whose MAC is right for the device's key;
    ProtocolError `bad_mac` otherwise (malformed header, a device without a key, a wrong MAC).
    The JSON is not read here."""
    nl = data.find(b"\n", 0, MAX_HEADER_BYTES)
    if nl < 0:
        raise ProtocolError("bad_mac", "no header line")
    parts = data[:nl].split(b" ")
    if len(parts) != 4 or len(parts[3]) != 64:
        raise ProtocolError("bad_mac", "malformed header")
    try:
        device, seq = parts[1].decode("ascii"), int(parts[2])
    except (UnicodeDecodeError, ValueError):
        raise ProtocolError("bad_mac", "malformed header") from None
    if not (0 <= seq <= MAX_SEQ and 1 <= len(device) <= MAX_DEVICE_CHARS and parts[2] == b"%d" % seq):
        raise ProtocolError("bad_mac", "malformed header")
    key = keys.get(device)
    if key is None:
        raise ProtocolError("bad_mac", "no key for this device", device, seq)
    body = data[nl + 1:]
    want = hmac.new(key, data[:nl - 64] + body, hashlib.sha256).hexdigest().encode("ascii")
    if not hmac.compare_digest(want, parts[3]):
        raise ProtocolError("bad_mac", "wrong MAC", device, seq)
    return device, seq, body


def load_keys(path: str) -> dict[str, bytes]:
    """device -> key of a keys file; InputError (one line) on any fault."""
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_KEYS_FILE_BYTES + 1)
    except OSError as e:
        raise InputError(f"{path}: {e.strerror or e}") from None
    if len(raw) > MAX_KEYS_FILE_BYTES:
        raise InputError(f"{path}: larger than {MAX_KEYS_FILE_BYTES} bytes")
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not an ASCII keys file") from None
    keys: dict[str, bytes] = {}
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 2:
            raise InputError(f"{path}:{n}: expected DEVICE HEXKEY")
        device, hexkey = parts
        if len(device) > MAX_DEVICE_CHARS:
            raise InputError(f"{path}:{n}: device names have 1..{MAX_DEVICE_CHARS} characters")
        try:
            key = bytes.fromhex(hexkey)
        except ValueError:
            raise InputError(f"{path}:{n}: the key is not hex") from None
        if len(key) < MIN_KEY_BYTES:
            raise InputError(f"{path}:{n}: keys have at least {MIN_KEY_BYTES} bytes ({2 * MIN_KEY_BYTES} hex digits)")
        if device in keys:
            raise InputError(f"{path}:{n}: {device} is listed twice")
        keys[device] = key
    if not keys:
        raise InputError(f"{path}: no keys")
    return keys


def load_device_key(path: str) -> tuple[str, bytes]:
    """(device, key) of a device's key file (a keys file of one line)."""
    keys = load_keys(path)
    if len(keys) != 1:
        raise InputError(f"{path}: a device's key file holds one DEVICE HEXKEY line")
    return next(iter(keys.items()))
