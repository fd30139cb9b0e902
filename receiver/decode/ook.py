"""OOK decoding from rolling-shutter row profiles (PROTOCOL.md sections 1-2).

One LED blob gives, per frame, a row profile: the chip stream sampled once per sensor row
(`row_readout_us` apart), each sample the mean over the row's exposure `exposure_us`, times an
unknown gain that varies slowly across the blob, plus an offset and noise. A chip covers
`rows_per_chip = 1e6 / (rate_hz * row_readout_us)` rows (typically 2.5..6).

Stages, each a small function on numpy arrays (all vectorised; no loops over rows):

1. `chip_grid`: refine the chip period and find the chip-boundary phase from the data. The
   squared first difference of the profile is large at chip transitions, which all lie on the
   grid `phase + k * period`; its complex Fourier sum at the nominal chip frequency, taken over
   short segments, drifts linearly in angle when the row time is mis-calibrated. A weighted line
   fit to the unwrapped segment angles gives the true period (so +-several % row-time errors are
   harmless), the whole-profile sum at that period gives the phase. The exposure shifts every
   edge and every chip centre by the same half exposure, so it cancels and need not be known.
2. `soft_chips`: sample each whole chip at its centre (mean of three points over its middle
   half) and normalise locally (running mean and mean absolute deviation over `norm_chips`
   chips; Manchester keeps every such window close to 50 % ON), giving soft chips ~ +-1.
3. `find_sync`: the 6-chip pattern `111000` (sync ON run of 3..4, OFF run of 3..4, PROTOCOL.md
   section 1) with every chip on the right side by `sync_margin`; Manchester data never has
   runs of 3, so it occurs once per 54-chip period.
4. `OokDecoder.step`: soft chips of each frame are added into a 54-chip periodic accumulator,
   aligned by the frame's sync or, without sync, by the best cyclic alignment against what is
   already accumulated (only when unambiguous); unalignable frames wait in a short queue and are
   retried as the accumulator fills. Before anything is anchored, frames are chained in an
   arbitrary cyclic frame and rotated into place once the sync shows in the accumulation.
   With a frame-clock hint (`step(..., clock=, y0=)`, receiver.decode.frameclock: the frame's packet
   timing measured on lights already decoded, which cancels the frame-start jitter common to
   all lights), a frame is also placed by timing alone, at the offset this light showed in its
   own sync-placed frames: small lights whose successive frames barely overlap are then
   assembled without correlation (`_timed_shift`; checked against the chips it overlaps, and
   every timed frame must fit the decoded packet at its own shift before the ID is reported).
5. The packet decision (`_ook.decode_acc`): Manchester soft decision per data bit (difference
   of the pair's two chips), reliability = the weakest pair, then CRC-8. An ID whose CRC fails is never reported. A
   packet that relied on a risky alignment (short overlaps: small blobs) is also checked
   against the last frames as a whole template before its ID is reported (`_verified`).
   A first ID from a packet that chained short frames by alignment (a wrong shift ties the
   right one too often to trust such a chain) is reported only once the frames after its
   proposal, each placed against the proposed packet alone, confirm it
   (receiver.decode.confirm).

With an exposure of half a chip or more, stages 1-2 are replaced by the exposure model
(receiver.decode.exposure: the profile as the chip stream averaged over the exposure, chips by
maximum-likelihood sequence estimation), and a packet that stage 5 rejects may still be decided
by maximum likelihood over all 65,536 packets (`soft_decide`); its margin assumes white noise on
the soft chips, which the exposure model's chips of 20-30 chip frames do not have (3 wrong IDs
among 22 such decisions in `pieces_mc.py 20k-56us-110rows-unmapped --trials 20`), so its ID,
as one from a chained packet, is reported only once the later frames confirm it. The exposure
comes from the camera file or, when it is 0, from the stripes' edge ramps
(`exposure.ExposureLearner`).

A single wrong chip changes at most one Manchester pair, so it is either outvoted in the
accumulator or it yields one wrong bit, which CRC-8 always detects (any CRC whose polynomial has
more than one term detects every single-bit error); a wrong pair also has a small margin.
"""

from __future__ import annotations

import cmath
import math
from collections import deque
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from firmware_tx.framing import OOK_ID_BITS, OOK_PACKET_LEN, SYNC, SYNC_EDGE_TO_DATA
from receiver.decode import confirm, exposure, pieces
from receiver.decode.settings import OOK_TUNING, OokSettings, OokTuning
from receiver.core.settings import resolve_settings
from receiver.core import protocol
from receiver.core.native import require

# the compiled kernels (receiver/decode/_ook.pyx): the one implementation of the accumulator
# updates, alignment, packet decision and timing checks, and of the frame's chips once the period
# is learned (its share of a frame: docs/kernels.md)
_k = require("receiver.decode._ook")


def _specialised(fn, names: dict) -> dict:
    """{dtype chars: the compiled fused-type function's specialisation} ("f" float32, "d"
    float64): called directly they skip the fused dispatch (its signature matching costs
    about what the kernel's own work does on a small blob)."""
    sigs = getattr(fn, "__signatures__", None) or {}
    return {key: sigs[sig] for key, sig in names.items() if sig in sigs}


_CT = {"f": "float", "d": "double"}
# frame_chips by (profile, weights) dtype chars, trim by the weights' dtype char
_FRAME_CHIPS = _specialised(_k.frame_chips, {(x, w): f"{_CT[x]}|{_CT[w]}" for x in "fd" for w in "fd"})
_TRIM = _specialised(_k.trim, {c: _CT[c] for c in "fd"})

_new = object.__new__
PACKET_LEN = OOK_PACKET_LEN  # 54 chips
SYNC_LEN = len(SYNC)  # 6 chips
DATA_START = SYNC_LEN  # first Manchester chip = sync edge (chip 3) + SYNC_EDGE_TO_DATA
assert DATA_START == 3 + SYNC_EDGE_TO_DATA
N_BITS = (PACKET_LEN - SYNC_LEN) // 2  # 24 = 16 ID bits + 8 CRC bits
CRC_BITS = N_BITS - OOK_ID_BITS
# Entries kept of a decoder's (and the frame clock's) timing diagnostics.
DIAGNOSTICS_LEN = 1000
PERIOD_FRAMES = OOK_TUNING.period_frames  # refined periods whose median fixes rows per chip
# A light whose chips the exposure model reads keeps as pieces (receiver.decode.pieces) also its
# frames longer than `pieces_max_chips`, up to this many chips (every frame that does not hold a
# whole packet): placed by the frame times among the map's IDs, they name it as soon as its
# frames cover the packet, while its assembly waits for syncs, alignments and the confirmation
# of chained frames; once it has its ID they measure the frames' jitter for the other lights.
PIECES_MAX_CHIPS = OOK_PACKET_LEN - 1
SOFT_CLIP = 2.0  # soft chips are clipped to +-this: one outlier row must not outvote a packet
_SYNC_T = np.array([1.0 if c else -1.0 for c in SYNC])
_SYNC_CODE = bytes(1 if c else 0xFF for c in SYNC)  # the sync as int8 chip signs (+1 / -1)
_CRC8_TABLE: np.ndarray | None = None


def wrap_chips(x: float) -> float:
    """A packet coordinate difference mapped to [-27, 27) chips."""
    return (x + 0.5 * PACKET_LEN) % PACKET_LEN - 0.5 * PACKET_LEN


def line_predict(obs, k: float, window: int) -> float:
    """Value at k of a least-squares line through the last `window` (k_i, v_i) of `obs`
    (v continuous, already unwrapped); the last value when they span fewer than 2 frames."""
    if 0 < window <= 64:
        return _k.line_predict(obs, k, window)  # the same numbers (numpy's pairwise sums)
    pts = list(obs)[-window:]
    if len(pts) == 1 or pts[-1][0] - pts[0][0] < 2:
        return pts[-1][1]
    ks = np.array([p[0] for p in pts], dtype=np.float64)
    vs = np.array([p[1] for p in pts], dtype=np.float64)
    # np.add.reduce / n is what ndarray.mean computes for these 1-D float64 arrays (same
    # numbers), without its Python-level wrapper: this runs for every timed light every frame
    km = np.add.reduce(ks) / ks.size
    vm = np.add.reduce(vs) / vs.size
    dk = ks - km
    slope = float(np.add.reduce(dk * (vs - vm)) / np.add.reduce(dk ** 2))
    return float(vm + slope * (k - km))


def crc8_table() -> np.ndarray:
    """CRC-8 (PROTOCOL.md section 5) of every 16-bit ID, uint8 (65536,), built once
    vectorised (same MSB-first register as firmware_tx.crc.crc8)."""
    global _CRC8_TABLE
    if _CRC8_TABLE is None:
        v = np.arange(1 << OOK_ID_BITS, dtype=np.int64)
        reg = np.zeros_like(v)
        for i in range(OOK_ID_BITS - 1, -1, -1):
            fb = ((reg >> 7) & 1) ^ ((v >> i) & 1)
            reg = ((reg << 1) & 0xFF) ^ (fb * 0x07)
        _CRC8_TABLE = reg.astype(np.uint8)
    return _CRC8_TABLE


def rows_per_chip(rate_hz: float, row_readout_us: float) -> float:
    """Nominal chip length in sensor rows (PROTOCOL.md section 2: 1 / (chip_rate * t_row))."""
    return 1e6 / (rate_hz * row_readout_us)


def trim_rows(weights: np.ndarray | None, n: int, min_frac: float) -> tuple[int, int]:
    """[start, stop) of the rows between the first and last row holding at least `min_frac`
    of the widest row's pixels (the blob's thin top and bottom are mostly noise)."""
    if weights is None or n == 0:
        return 0, n
    w = np.asarray(weights)
    ok = (w >= min_frac * np.maximum.reduce(w)).nonzero()[0]  # w.max(), flatnonzero: fewer wrappers
    if ok.size == 0:
        return 0, 0
    return int(ok[0]), n - (w.size - 1 - int(ok[-1]))


def chip_grid(x: np.ndarray, period0_rows: float, *, segment_chips: float = 6.0,
              max_period_error: float = 0.08, phasor: np.ndarray | None = None
              ) -> tuple[float, float, float]:
    """Chip period and boundary phase of a row profile.

    x: float64 (R,) profile. period0_rows: nominal rows per chip.
    Returns (period_rows, phase_rows, coherence): chip boundaries (as seen in the samples)
    lie at rows `phase_rows + k * period_rows`, phase in [0, period); coherence in [0, 1] is
    |sum(e * exp(-i w r))| / sum(e) of the transition energy e (1 = every edge on the grid,
    ~1/sqrt(R) for noise). `phasor`: optional cached exp(-2j pi (r + 0.5) / period0_rows) for
    r = 0.. at least R-2 (saves the dearest line when called every frame).
    """
    d = x[1:] - x[:-1]
    e = d * d
    if phasor is None or phasor.size < e.size:
        # a difference sits between its two rows
        phasor = np.exp(-2j * np.pi / period0_rows * (np.arange(e.size) + 0.5))
    z = e * phasor[:e.size]
    seg = max(2, int(round(segment_chips * period0_rows)))
    nseg = z.size // seg
    period = period0_rows
    zsum = z.sum()
    if nseg >= 3 and segment_chips > 0:
        # A handful of segments: plain Python floats, not a dozen numpy calls on 5 numbers
        # (this runs for every new light in every frame until its period is learned).
        zs = z[:nseg * seg].reshape(nseg, seg).sum(axis=1).tolist()
        w = [abs(v) for v in zs]
        ang = [0.0]  # unwrapped
        for cur, prev in zip(zs[1:], zs[:-1]):
            ang.append(ang[-1] + cmath.phase(cur * prev.conjugate()))
        c = [(k + 0.5) * seg for k in range(nseg)]
        sw = sum(w)
        if sw > 0:
            cm = sum(wk * ck for wk, ck in zip(w, c)) / sw
            am = sum(wk * ak for wk, ak in zip(w, ang)) / sw
            den = sum(wk * (ck - cm) ** 2 for wk, ck in zip(w, c))
            slope = sum(wk * (ck - cm) * (ak - am) for wk, ck, ak in zip(w, c, ang)) / den if den > 0 else 0.0
            # angle(r) = -2 pi r / p0 + 2 pi r (1/p - 1/p0) + const
            f = 1.0 / period0_rows + slope / (2.0 * math.pi)
            if f > 0:
                period = min(max(1.0 / f, period0_rows * (1 - max_period_error)),
                             period0_rows * (1 + max_period_error))
        # sum at the refined period from the segment sums (the residual rotation inside one
        # segment is below 0.5 rad for errors within max_period_error)
        df = 1.0 / period - 1.0 / period0_rows
        zsum = sum(zk * cmath.exp(-2j * math.pi * df * ck) for zk, ck in zip(zs, c)) + complex(
            (z[nseg * seg:] * np.exp(-2j * np.pi * df * (np.arange(nseg * seg, e.size) + 0.5))).sum())
    etot = e.sum()
    coherence = float(abs(zsum) / etot) if etot > 0 else 0.0
    phase = float((-np.arctan2(zsum.imag, zsum.real) * period / (2.0 * np.pi)) % period)
    return period, phase, coherence


def _is_f64(a) -> bool:
    """A 1-D contiguous float64 array (what the accumulator kernels take)?"""
    return type(a) is np.ndarray and a.ndim == 1 and a.dtype.char == "d" and a.flags.c_contiguous


@lru_cache(maxsize=512)
def _arange(n: int) -> np.ndarray:
    return np.arange(n, dtype=np.float64)


@lru_cache(maxsize=64)
def _cyclic_index(n: int) -> np.ndarray:
    """(54, n) packet position of frame chip k under every cyclic shift: (shift + k) % 54.
    Read-only: shared by every decoder (per-frame alignment of every track)."""
    idx = (np.arange(PACKET_LEN)[:, None] + np.arange(n)[None, :]) % PACKET_LEN
    idx.setflags(write=False)
    return idx


@lru_cache(maxsize=64)
def _grid_phasor(period0_rows: float, n: int) -> np.ndarray:
    """exp(-2j pi (r + 0.5) / period0_rows) for r = 0..n-1 (`chip_grid`'s phasor), shared by
    all decoders of one chip rate; read-only."""
    ph = np.exp(-2j * np.pi / period0_rows * (np.arange(n) + 0.5))
    ph.setflags(write=False)
    return ph


@lru_cache(maxsize=512)
def _window_start(n: int, win: int) -> np.ndarray:
    """Start of a `win`-long window around each of n items, shifted inwards at the ends."""
    return np.clip(np.arange(n) - win // 2, 0, n - win)


def _clip1(x: np.ndarray) -> np.ndarray:
    """x clipped to [-1, 1]: the two ufuncs, without np.clip's wrapper (a few us a call, and
    the decoder clips several small arrays per frame)."""
    return np.minimum(np.maximum(x, -1.0), 1.0)


def soft_chips(x: np.ndarray, w: np.ndarray | None, period: float, phase: float, *,
               exposure_rows: float = 0.0, norm_chips: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Soft values (~ +1 ON, ~ -1 OFF) and weights of the whole chips in a profile.

    Chip k spans samples [phase + (k-1) p, phase + k p) with phase in [0, p); its centre is
    sampled at three points over the middle of the part not blurred by the exposure (linear
    interpolation between rows). Weights: the row weights at the chip centre relative to the
    widest row (rows with fewer pixels are noisier). Normalisation: running mean and mean
    absolute deviation over `norm_chips` chips.
    Returns (soft (n,), weight (n,)), chip 0 being the first whole chip from the top.
    """
    n_rows = x.size
    n = int((n_rows - 1 - phase) // period)
    if n <= 0:
        return np.zeros(0), np.zeros(0)
    centres = _arange(n) * period + (phase + 0.5 * period)
    h = 0.25 * max(period - exposure_rows, 0.0)
    rows = _arange(n_rows)
    vals = np.interp(np.concatenate((centres - h, centres, centres + h)), rows, x)
    v = (vals[:n] + vals[n:2 * n] + vals[2 * n:]) * (1.0 / 3.0)
    if w is None:
        cw = np.ones(n)
    else:
        cw = np.interp(centres, rows, w)
        cw *= 1.0 / max(np.maximum.reduce(cw), 1e-9)
    win = min(norm_chips, n)
    lo = _window_start(n, win)
    cs = np.zeros(n + 1)
    # window sums: cs[j + win] - cs[j] for every start j, then picked per chip
    np.add.accumulate(v, out=cs[1:])
    d = v - (cs[win:] - cs[:n + 1 - win])[lo] * (1.0 / win)
    np.add.accumulate(np.abs(d), out=cs[1:])
    soft = d / np.maximum((cs[win:] - cs[:n + 1 - win])[lo] * (1.0 / win), 1e-9)
    np.minimum(soft, SOFT_CLIP, out=soft)
    np.maximum(soft, -SOFT_CLIP, out=soft)
    return soft, cw


def find_sync(soft: np.ndarray, *, sync_margin: float = OOK_TUNING.sync_margin) -> tuple[int | None, float]:
    """Index of the first chip of `111000` in the frame's soft chips, or None.

    Every one of the 6 chips must be on the right side by at least `sync_margin`. When the
    frame shows the sync more than once the occurrences must be a whole packet apart.
    Returns (index, margin of the weakest sync chip).
    """
    if _is_f64(soft):
        return _k.find_sync(soft, sync_margin)
    if soft.size < SYNC_LEN:
        return None, 0.0
    # chip signs (+1 / -1, 0 inside the margin) as bytes: the pattern is then a substring
    # search, a third of the cost of six shifted comparisons on these short arrays
    code = ((soft > sync_margin).view(np.int8) - (soft < -sync_margin).view(np.int8)).tobytes()
    hits = []
    k = code.find(_SYNC_CODE)
    while k >= 0:
        hits.append(k)
        k = code.find(_SYNC_CODE, k + 1)
    if not hits:
        return None, 0.0
    if any((k - hits[0]) % PACKET_LEN for k in hits):
        return None, 0.0  # inconsistent syncs: grid or noise trouble, do not trust the frame
    score = [float((soft[k:k + SYNC_LEN] * _SYNC_T).min()) for k in hits]
    best = int(np.argmax(score))
    return int(hits[best]), score[best]


def packet_template(led_id: int) -> np.ndarray:
    """The 54-chip packet of an ID as +-1 floats (sync first)."""
    value = (led_id << CRC_BITS) | int(crc8_table()[led_id])
    bits = (value >> np.arange(N_BITS - 1, -1, -1)) & 1
    data = np.stack([bits, 1 - bits], axis=1).ravel() * 2.0 - 1.0  # Manchester: 1 -> 1 0
    return np.concatenate((_SYNC_T, data))


@lru_cache(maxsize=256)
def moved_pair_twins(led_id: int) -> tuple:
    """The other IDs whose packets are this ID's packet with one Manchester pair taken out at
    one place and one put in at another (a stretch of the data moved by a pair): what a chained
    assembly gives when one stretch of its frames was placed two chips off
    (receiver.decode.confirm). Sorted; mostly empty or one or two IDs (each candidate passes
    the CRC-8 with probability 1/256)."""
    table = crc8_table()
    value = (led_id << CRC_BITS) | int(table[led_id])
    bits = [(value >> (N_BITS - 1 - i)) & 1 for i in range(N_BITS)]
    out = set()
    for a in range(N_BITS):
        rest = bits[:a] + bits[a + 1:]
        for b in range(N_BITS):
            for v in (0, 1):
                t = int("".join(map(str, rest[:b] + [v] + rest[b:])), 2)
                tid = t >> CRC_BITS
                if tid != led_id and int(table[tid]) == t & ((1 << CRC_BITS) - 1):
                    out.add(tid)
    return tuple(sorted(out))


@lru_cache(maxsize=16)
def _templates(ids: tuple) -> np.ndarray:
    """(K, 54) +-1 packets of the IDs (shared by the decoders of one map and rate)."""
    bits = _bit_signs(np.array(ids, dtype=np.int64))  # (K, 24) +-1; Manchester: bit b -> (b, -b)
    t = np.concatenate((np.broadcast_to(_SYNC_T, (len(ids), SYNC_LEN)),
                        np.stack((bits, -bits), axis=2).reshape(len(ids), 2 * N_BITS)), axis=1)
    t.setflags(write=False)
    return t


def candidate_tables(candidates) -> pieces.Candidates:
    """`pieces.Candidates` of candidate IDs (an array of them, or such tables already made)."""
    if isinstance(candidates, pieces.Candidates):
        return candidates
    ids = np.asarray(candidates, dtype=np.int64)
    return pieces.Candidates(ids, _templates(tuple(ids.tolist())) if ids.size else np.zeros((0, PACKET_LEN)))


def best_cyclic_match(soft: np.ndarray, template: np.ndarray) -> float:
    """Best normalised correlation sum(s * t) / sum(|s|) of a frame's soft chips with a
    fully known +-1 periodic packet over all cyclic shifts (1 = the frame fits somewhere)."""
    # the kernel reads exactly PACKET_LEN template chips (a template of another length: numpy)
    if _is_f64(soft) and _is_f64(template) and template.shape == (PACKET_LEN,):
        r = _k.best_two(template, soft)
        return r[1] if r is not None else 0.0
    s = _clip1(soft)
    idx = _cyclic_index(s.size)
    den = np.abs(s).sum()
    return float((template[idx] @ s).max() / den) if den > 0 else 0.0


# Packets whose margins `soft_decide` computes at once (nearest scores first).
_NEAR_CHUNK = 256
# (256, 8) +-1: the bits of every byte, most significant first.
_BYTE_SIGNS = (((np.arange(256)[:, None] >> np.arange(7, -1, -1)) & 1) * 2.0 - 1.0)


def _bit_signs(ids: np.ndarray) -> np.ndarray:
    """(len(ids), 24) +-1 data bits (ID then CRC-8, MSB first) of the given IDs' packets."""
    value = (ids.astype(np.int64) << CRC_BITS) | crc8_table()[ids].astype(np.int64)
    return ((value[:, None] >> np.arange(N_BITS - 1, -1, -1)) & 1) * 2.0 - 1.0


def soft_decide(sums: np.ndarray, weights: np.ndarray, squares: np.ndarray, *,
                sigma_floor: float = 0.05, z_cap: float = 8.0) -> tuple[int, float, float]:
    """Maximum-likelihood ID of an anchored packet accumulation over all 65,536 packets.

    sums, weights, squares: (54,) per packet position the weighted sum of the soft chips, the
    sum of their weights and the weighted sum of their squares (0 where nothing was seen).
    Model (as `receiver.decode.s2psk.soft_stats`): a soft chip at position p is x = a c_p + n,
    c_p = +-1 the hypothesis' chip, n white of variance sigma^2; the log-likelihood is then
    const + a sum_p c_p S_p / sigma^2, largest for the largest correlation sum_p c_p S_p. a and sigma^2 are fitted under the best packet
    (sigma floored by `sigma_floor`). Between the best packet c1 and another c, the score
    difference 2 sum_{p: c1 != c} c1_p S_p has sd 2 sigma sqrt(W), W = the weight of the
    positions where they differ (unseen positions weigh 0: a packet that differs only there
    has z = 0). Returns (best ID, z, snr = a / sigma): z is the smallest such margin over
    every other ID in noise sds when it is below `z_cap`, else z_cap (larger margins are not
    computed; below the cap, the first packet found under it may stand for the smallest)."""
    w = np.asarray(weights, dtype=np.float64)
    S = np.asarray(sums, dtype=np.float64)
    n = float(w.sum())
    if n <= 0:
        return 0, 0.0, 0.0
    # Every packet shares the sync and sends bit d as the chip pair (d, -d): its correlation is
    # the sync's plus sum_i d_i u_i, u_i the pair's difference; with the ID's two bytes and the
    # CRC byte apart, all 65,536 of them are sums of three 256-entry tables.
    u = S[DATA_START::2] - S[DATA_START + 1::2]
    hi, lo, cr = (_BYTE_SIGNS @ u[8 * j:8 * j + 8] for j in range(3))
    scores = (hi[:, None] + lo[None, :]).ravel() + cr[crc8_table()] + float(S[:SYNC_LEN] @ _SYNC_T)
    i1 = int(np.argmax(scores))
    score1 = float(scores[i1])
    amp = score1 / n
    rss = max(float(np.sum(squares)) - score1 * amp, 0.0)
    var = max(rss / max(n - 1.0, 1.0), sigma_floor ** 2)
    # W <= n, so a packet whose score is below score1 - 2 sqrt(n var) z_cap has z >= z_cap:
    # W (the weight of the chip pairs whose bits differ from c1's) is only needed for the others
    gap = score1 - scores
    near = np.flatnonzero(gap < 2.0 * math.sqrt(n * var) * z_cap)
    near = near[near != i1]
    pair_w = w[DATA_START::2] + w[DATA_START + 1::2]
    c1 = _bit_signs(np.array([i1]))
    zmin = z_cap
    # nearest scores first, in chunks: a packet below the cap settles a rejection
    if near.size > _NEAR_CHUNK:
        first = np.argpartition(gap[near], _NEAR_CHUNK)[:_NEAR_CHUNK]
        near = np.concatenate((near[first], np.delete(near, first)))
    for k in range(0, near.size, _NEAR_CHUNK):
        part = near[k:k + _NEAR_CHUNK]
        W = (_bit_signs(part) != c1) @ pair_w
        z = gap[part] / (2.0 * np.sqrt(np.maximum(W, 1e-12) * var))
        z[W <= 1e-9] = 0.0  # differs only where nothing was seen: not told apart
        zmin = min(zmin, float(z.min()))
        if zmin < z_cap:
            break
    return i1, zmin, amp / math.sqrt(var)


@dataclass(frozen=True)
class OokState:
    """Decoder state after a frame. `led_id`: CRC-valid ID or None (once decoded it stays
    unless another CRC-valid ID is decoded in `switch_frames` consecutive frames);
    `frames`: frames fed; `chips_known`: packet positions seen (of 54); `confidence`: weakest
    Manchester pair reliability of the current accumulated packet (0..~1)."""

    led_id: int | None
    frames: int
    chips_known: int
    confidence: float


class PeriodLearner:
    """Rows per chip of one chip rate on one camera, fixed by the median of the first
    `period_frames` refined periods handed in (`add`). Rows per chip is a camera/LED constant,
    so the decoders of all lights of a rate can share one learner (receiver.pipeline does):
    then only the lights of the first frame(s) pay the period refinement, not every new light
    for its first `period_frames` frames. A decoder made without one learns alone."""

    def __init__(self, period_frames: int = PERIOD_FRAMES):
        self.period_frames = period_frames
        self.periods: list[float] = []
        self.period: float | None = None

    def add(self, period: float) -> None:
        if self.period is not None:
            return
        self.periods.append(period)
        if len(self.periods) >= self.period_frames:
            self.period = float(np.median(self.periods))


class OokDecoder:
    """Per-blob OOK packet assembler (one per tracked blob; call `step` every frame).

    Tunables: `OokSettings` (receiver.decode.settings), given as `settings=` or as keyword
    overrides of its fields; `tuning`: the internal constants (`OokTuning`, for tests and
    studies).
    """

    def __init__(self, rate_hz: float = protocol.OOK_RATE_HZ, row_readout_us: float = 15.0, exposure_us: float = 0.0, *,
                 period_learner: PeriodLearner | None = None, settings: OokSettings | None = None,
                 exposure_learner: exposure.ExposureLearner | None = None,
                 candidates: np.ndarray | pieces.Candidates | None = None, frame_jitter: pieces.FrameJitter | None = None,
                 tuning: OokTuning = OOK_TUNING, **overrides):
        s = self.settings = resolve_settings(settings, OokSettings, overrides)
        k = self.tuning = tuning
        if rate_hz <= 0 or row_readout_us <= 0:
            raise ValueError("rate_hz and row_readout_us must be positive")
        self.period0_rows = rows_per_chip(rate_hz, row_readout_us)
        self._phasor = np.zeros(0, dtype=np.complex128)
        self._learner = period_learner if period_learner is not None else PeriodLearner(k.period_frames)
        self._period: float | None = None  # learned rows per chip
        self.last_start_row: float | None = None  # frame chip 0's first row (frame_chips)
        self._model_mode, self._model_min_chips = s.exposure_model, exposure.MODEL_FROM_CHIPS
        # exposure_us <= 0: unknown, learned from the stripes' edges (shared per rate and camera)
        self.exposure_learner = (None if exposure_us > 0 else exposure_learner if exposure_learner is not None
                                 else exposure.ExposureLearner())
        self._set_exposure(max(exposure_us, 0.0) / row_readout_us)
        self.blur_rows = k.blur_rows
        self.model_phases = k.model_phases
        self.model_min_fit = k.model_min_fit
        self.model_fit: float | None = None  # the latest frame's fit (1 - residual / variance)
        self.min_row_frac = k.min_row_frac
        self.segment_chips = k.segment_chips
        self.max_period_error = k.max_period_error
        self.min_coherence = k.min_coherence
        self.norm_chips = k.norm_chips
        self.sync_margin = k.sync_margin
        self.align_min = k.align_min
        self.align_gap = k.align_gap
        self.align_min_chips = k.align_min_chips
        self.decay = s.decay_per_frame
        self.min_margin = k.min_margin
        self.switch_frames = s.switch_frames
        self.parity_gap = k.parity_gap
        self.stale_frames = k.stale_frames
        self._stale = 0
        # the four accumulators are the rows of one array (one buffer for the kernels); every
        # update of them is in place, so these views stay theirs
        self._acc4 = np.zeros((4, PACKET_LEN))
        self.acc = self._acc4[0]  # sum of weighted soft chips per packet position
        self.acc_w = self._acc4[1]  # sum of weights
        # weight placed where it surely belongs: by the frame's own sync, or by an alignment
        # for which every cyclic shift overlapped enough known chips to be judged
        self.trust_w = self._acc4[2]
        self._last_align_complete = False
        self.pending: deque = deque(maxlen=k.pending_frames)
        self.recent: deque = deque(maxlen=k.verify_frames)  # soft chips of the latest frames
        self.verify_min = k.verify_min
        self.anchored = False  # accumulator positions are packet positions (sync at 0)
        self.frames = 0
        self.led_id: int | None = None
        self.confidence = 0.0
        self._cand: int | None = None
        self._cand_n = 0
        # frame-clock timing (receiver.decode.frameclock): offsets o = shift - (clock coordinate of
        # frame chip 0) of placed frames, in accumulator coordinates
        self.timing_window = k.timing_window
        self.timing_max_gap = k.timing_max_gap
        self.timing_frac = k.timing_frac
        self.timing_conflict = k.timing_conflict
        self.timing_min_overlap = k.timing_min_overlap
        self.timing_min_corr = k.timing_min_corr
        self.timing_ok = True  # False for good after a timing disagreement
        self._tobs: deque = deque(maxlen=k.timing_window)  # (k, o)
        self._t_epoch: int | None = None
        self._t_confirmed = False  # the offsets are tied to packet coordinates by a sync frame
        self._t_strong = False  # some offset came from a sync-placed frame
        self._tc: float | None = None  # this frame: clock coordinate of frame chip 0
        self._tk = 0
        self.timed_w = self._acc4[3]  # weight of timed placements not yet confirmed
        self.acc_sq = np.zeros(PACKET_LEN)  # sum of weighted squared soft chips (exposure model only)
        self.soft_min_z = s.soft_min_z
        self.soft_min_snr = k.soft_min_snr
        self.soft_min_chips = k.soft_min_chips
        self.soft_sigma_floor = k.soft_sigma_floor
        self.soft_z = 0.0  # the latest soft decision's margin (noise sds)
        # pieces placed by the frame times (receiver.decode.pieces), for lights showing few
        # chips a frame; only with candidate IDs (the map's at this rate)
        self.rate_hz = rate_hz
        self.pieces_max_chips = s.pieces_max_chips
        self.pieces = None
        self.pieces_took = 0  # short pieces the ID was pieced together from (0: not by pieces)
        if candidates is not None and len(candidates) and s.pieces_max_chips > 0:
            self.pieces = pieces.PieceAssembler(
                candidate_tables(candidates), jitter_chips=pieces.jitter_chips(s.pieces_jitter_us, rate_hz),
                history=k.pieces_frames, min_frames=k.pieces_min_frames, min_corr=k.pieces_min_corr,
                min_agree=k.pieces_min_agree, min_z=k.pieces_min_z, shift_penalty=k.pieces_shift_penalty, jitter=frame_jitter,
                timed_penalty=k.pieces_timed_penalty)
        self.timing_stats = {"timed": 0, "frac": 0, "conflict": 0, "overlap_conflict": 0,
                             "weak_reset": 0, "verify_conflict": 0}
        # Diagnostics of the latest frames, chips (bounded: a decoder lives as long as its
        # track): |sync-placed offset - prediction| and |timed prediction - frame's chip grid|.
        self.timing_resid: deque = deque(maxlen=DIAGNOSTICS_LEN)
        self.timing_frac_resid: deque = deque(maxlen=DIAGNOSTICS_LEN)
        self._tpl: tuple[int, np.ndarray] | None = None
        self.timed_frames: deque = deque(maxlen=k.verify_frames)  # (soft, shift) of timed placements
        # a first ID from a packet chained by alignments of short frames waits for the frames
        # after its proposal to confirm it (receiver.decode.confirm)
        self.confirm_max_chips = s.confirm_max_chips
        self.confirm_frames = k.confirm_frames
        self.confirm_gap = k.confirm_gap
        self.confirm_min_chip = k.confirm_min_chip
        self.confirm_misfit_right = k.confirm_misfit_right
        self.confirm_misfit_wrong = k.confirm_misfit_wrong
        self.confirm_min_llr = k.confirm_min_llr
        self.confirm_end_chips = k.confirm_end_chips
        self.confirm_twin_frames = k.confirm_twin_frames
        self._chained = False  # the accumulation holds a short frame placed by alignment
        self._confirm: confirm.Confirmation | None = None

    def _set_exposure(self, exposure_rows: float) -> None:
        """Use this exposure (rows): the exposure model (receiver.decode.exposure) reads the
        chips where the exposure averages them, from `exposure.MODEL_FROM_CHIPS` of a chip up."""
        self.exposure_rows = exposure_rows
        self.exposure_model = self._model_mode == "on" or (
            self._model_mode == "auto" and exposure_rows >= self._model_min_chips * self.period0_rows)

    def _learn_exposure(self, profile, weights) -> None:
        lr = self.exposure_learner
        if lr.exposure_rows is None:
            x = np.asarray(profile, dtype=np.float64)
            a, b = trim_rows(weights, x.size, 0.5)
            lr.add(x[a:b], self.rows_per_chip)
        if lr.exposure_rows is not None:
            self._set_exposure(lr.exposure_rows)
            self.exposure_learner = None  # learned: this decoder is set

    def frame_chips(self, profile, weights=None) -> tuple[np.ndarray, np.ndarray]:
        """Soft chips and weights of one frame's row profile (stages 1-2); empty when the
        profile is too short or shows no chip grid."""
        self.last_start_row = None
        if self.exposure_learner is not None:
            self._learn_exposure(profile, weights)
        if self.exposure_model:
            return self._model_chips(profile, weights)
        if self._period is not None or self._learner.period is not None:
            fast = self._frame_chips_native(profile, weights)
            if fast is not None:
                return fast
        x = np.asarray(profile, dtype=np.float64)
        a, b = trim_rows(weights, x.size, self.min_row_frac)
        x = x[a:b]
        if x.size < 4 * self.period0_rows:
            return np.zeros(0), np.zeros(0)
        w = None if weights is None else np.asarray(weights, dtype=np.float64)[a:b]
        if self._period is None and self._learner.period is not None:
            self._period = self._learner.period
            self._phasor = np.zeros(0, dtype=np.complex128)
        learned = self._period is not None
        p0 = self._period if learned else self.period0_rows
        if self._phasor.size < x.size:
            self._phasor = _grid_phasor(p0, 2 * x.size)
        period, phase, coh = chip_grid(x, p0, segment_chips=0.0 if learned else self.segment_chips,
                                       max_period_error=self.max_period_error,
                                       phasor=self._phasor)
        if coh < self.min_coherence:
            return np.zeros(0), np.zeros(0)
        # where frame chip 0 starts (rows from the profile's first row) and the chip length:
        # the frame's timing, for the frame clock (receiver.decode.frameclock)
        self.last_start_row = a + phase
        if not learned and x.size >= 3 * self.segment_chips * p0:
            # rows per chip is fixed by the camera and the LED: learn it once, then skip the
            # refinement (half the cost of a step)
            self._learner.add(period)
            if self._learner.period is not None:
                self._period = self._learner.period
                self._phasor = np.zeros(0, dtype=np.complex128)
        return soft_chips(x, w, period, phase, exposure_rows=self.exposure_rows,
                          norm_chips=self.norm_chips)

    def _model_chips(self, profile, weights) -> tuple[np.ndarray, np.ndarray]:
        """`frame_chips` by the exposure model (receiver.decode.exposure): the whole chips of
        the frame as max-log likelihood ratios scaled to ~ +-1, their weights the rows' relative
        pixel counts; empty when the profile is short or the model does not fit it."""
        x = np.asarray(profile, dtype=np.float64)
        a, b = trim_rows(weights, x.size, self.min_row_frac)
        x = x[a:b]
        p = self.rows_per_chip
        if x.size < 4 * p:
            return np.zeros(0), np.zeros(0)
        w = np.ones(x.size) if weights is None else np.asarray(weights, dtype=np.float64)[a:b]
        w = w / max(float(w.max()), 1e-9)
        e = self.exposure_rows / p
        blur = self.blur_rows / p
        z = exposure.linearise(x, p, e, blur, self.norm_chips)
        r = exposure.mlse_chips(z, w, p, e, blur, self.model_phases)
        if r is None:
            return np.zeros(0), np.zeros(0)
        llr, k0, tau0, resid = r
        zm = float(np.average(z, weights=w))
        var = float(np.average((z - zm) ** 2, weights=w))
        self.model_fit = 1.0 - resid / var if var > 0 else 0.0
        if self.model_fit < self.model_min_fit:
            return np.zeros(0), np.zeros(0)
        # chip k's start shows in the samples where the middle of a row's exposure crosses it
        k = k0 + np.arange(llr.size)
        start = (k - 0.5 * e - tau0) * p
        whole = (start >= 0) & (start + p <= x.size - 1)
        if not whole.any():
            return np.zeros(0), np.zeros(0)
        llr, start = llr[whole], start[whole]
        scale = float(np.median(np.abs(llr)))
        if scale <= 0:
            return np.zeros(0), np.zeros(0)
        soft = np.clip(llr / scale, -SOFT_CLIP, SOFT_CLIP)
        cw = np.interp(start + 0.5 * p, _arange(x.size), w)
        self.last_start_row = a + float(start[0])
        return soft, cw

    def _frame_chips_native(self, profile, weights) -> tuple[np.ndarray, np.ndarray] | None:
        """`frame_chips` once the period is learned, by the compiled kernel (the same numbers);
        None for inputs it does not take (not a contiguous float32/float64 array)."""
        # 1-D contiguous float32/float64 arrays only (checked inline: once per decoded light a frame)
        if not (type(profile) is np.ndarray and profile.ndim == 1 and profile.dtype.char in "fd"
                and profile.flags.c_contiguous):
            return None
        if weights is not None and not (type(weights) is np.ndarray and weights.ndim == 1
                                        and weights.dtype.char in "fd" and weights.flags.c_contiguous
                                        and weights.size == profile.size):
            return None
        if weights is None:
            a, b = 0, profile.size
            frame_chips = _k.frame_chips
        else:
            wc = weights.dtype.char
            a, b = _TRIM.get(wc, _k.trim)(weights, self.min_row_frac)
            frame_chips = _FRAME_CHIPS.get((profile.dtype.char, wc), _k.frame_chips)
        if b - a < 4 * self.period0_rows:
            return np.zeros(0), np.zeros(0)
        if self._period is None:
            self._period = self._learner.period
            self._phasor = np.zeros(0, dtype=np.complex128)
        if self._phasor.size < b - a:
            self._phasor = _grid_phasor(self._period, 2 * (b - a))
        phase, _, soft, cw = frame_chips(profile, weights, a, b, self._phasor, self._period,
                                         self.exposure_rows, self.norm_chips, self.min_coherence)
        if soft is None:
            return np.zeros(0), np.zeros(0)
        self.last_start_row = a + phase
        return soft, cw

    def _align(self, soft: np.ndarray) -> int | None:
        """Cyclic shift placing frame chip k at packet position (k + shift) % 54, from the
        correlation with the accumulated packet; None when weak or ambiguous. Sets
        `_last_align_complete` when every shift overlapped >= align_min_chips known chips
        (then the true shift was among those compared, and the choice can be trusted)."""
        shift, self._last_align_complete = _k.align(
            self.acc, self.acc_w, soft, self.anchored, self.align_min_chips, self.parity_gap,
            self.align_min, self.align_gap)
        return shift

    def _mean_packet(self, known: np.ndarray) -> np.ndarray:
        """Mean accumulated soft chip per packet position, 0 where nothing is known
        (`known` = acc_w > 0)."""
        return np.divide(self.acc, self.acc_w, out=np.zeros(PACKET_LEN), where=known)

    def _add(self, soft: np.ndarray, cw: np.ndarray, shift: int, trusted: bool = False,
             timed: bool = False) -> None:
        if self.exposure_model:  # the squares, for the soft decision's noise fit
            self.acc_sq += np.bincount(_cyclic_index(soft.size)[shift % PACKET_LEN], cw * soft * soft, PACKET_LEN)
        _k.add4(self._acc4, 2 if trusted else 3 if timed else -1, soft, cw, shift)

    def step(self, profile, weights=None, t_s=None, *, clock=None, y0: int | None = None, near: tuple = ()) -> OokState:
        """Feed one frame's row profile (float (R,), rows top to bottom, one per sensor row)
        and its per-row pixel counts `weights` (R,) or None. `t_s`: the frame's timestamp (s),
        used with `y0` to place short pieces by time (receiver.decode.pieces) when the decoder
        has candidate IDs.
        Optional timing hint: `clock` (receiver.decode.frameclock.ClockTick of this frame) and `y0`
        (image row of the profile's first row); with them, frames are also placed by timing
        (`_timed_shift`). `near`: the map IDs the tracked pose puts where this light is
        (receiver.locate.map_prior), for the pieces' choice (`PieceAssembler.decide`)."""
        self.frames += 1
        self.acc_sq *= self.decay
        _k.decay4(self._acc4, self.decay)
        soft, cw = self.frame_chips(profile, weights)
        self._tc = None
        if clock is not None and y0 is not None and self.last_start_row is not None and self.timing_ok:
            if clock.epoch != self._t_epoch:
                self._timing_reset()
                self._t_epoch = clock.epoch
            self._tk = clock.k
            self._tc = clock.value + (y0 + self.last_start_row) / self.rows_per_chip
        if (self.pieces is not None and (self.led_id is None or self.pieces.frame_jitter is not None)
                and t_s is not None and y0 is not None and self.last_start_row is not None and soft.size >= 2):
            self._add_piece(soft, cw, t_s, y0, near)
        added = None
        if self._confirm is not None and soft.size >= SYNC_LEN:
            self._confirm_step(soft)
        if soft.size >= SYNC_LEN:
            self.recent.append(soft)
            added = self._place(soft, cw)
            if added is None:
                self.pending.append((soft, cw, self._tc, self._tk))
            elif added and self.pending:  # (nothing to retry in an empty queue)
                self._retry_pending()
        if added:
            self._decode()
        elif self._stale:  # nothing new to decode, but a failing packet keeps ageing
            self._age_stale()
        known = _k.known_count(self.acc_w) if self.anchored else 0
        # OokState(...) by records.frozen_record's construction (every field, in order)
        st = _new(OokState)
        st.__dict__.update(led_id=self.led_id, frames=self.frames, chips_known=known, confidence=self.confidence)
        return st

    def _place(self, soft: np.ndarray, cw: np.ndarray) -> bool | None:
        """Add one frame's chips to the accumulator: True when added, None when it cannot be
        placed yet, False when deliberately skipped.

        Until a sync has been seen the accumulator is kept in an arbitrary cyclic frame
        ("unanchored"): frames are chained by correlation, and the whole accumulator is
        rotated to packet coordinates as soon as the sync shows in it. So two frames that
        each show only part of the sync can still be combined.
        """
        s, _ = find_sync(soft, sync_margin=self.sync_margin)
        if not _k.any_nonzero(self.acc_w):  # (weights are never negative)
            if s is None:
                self._add(soft, cw, 0)
                self.anchored = False
            else:
                self._add(soft, cw, (-s) % PACKET_LEN, trusted=True)
                self.anchored = True
            self._t_observe((-s) % PACKET_LEN if s is not None else 0, sync=s is not None)
            return True
        if s is not None and self.anchored:
            self._add(soft, cw, (-s) % PACKET_LEN, trusted=True)
            if self._tc is not None:  # (_t_observe does nothing without this frame's clock)
                self._t_observe((-s) % PACKET_LEN, sync=True)
            return True
        if s is None and self.led_id is not None:
            self.pending.clear()  # decoded: frames without sync add little, cost alignments
            return False
        shift = self._timed_shift(soft)
        if shift is not None:
            self._add_timed(soft, cw, shift)
            if not self.anchored:
                q = s + shift if s is not None else self._cyclic_sync()
                if q is not None:
                    self._rotate(q)
                    shift = (shift - q) % PACKET_LEN
            self._t_observe(shift, sync=s is not None, timed=True)
            return True
        shift = self._align(soft)
        if shift is None:
            if s is None:
                return None
            # an unanchored guess that the sync frame cannot be fitted to: the sync wins
            self.pending.append((*self._unanchored_chips(), None, None))
            self._clear()
            self._add(soft, cw, (-s) % PACKET_LEN, trusted=True)
            self.anchored = True
            self._t_observe((-s) % PACKET_LEN, sync=True)
            return True
        self._add(soft, cw, shift, trusted=self.anchored and self._last_align_complete)
        self._chain(soft)
        if not self.anchored:
            q = s + shift if s is not None else self._cyclic_sync()
            if q is not None:
                self._rotate(q)
                shift = (shift - q) % PACKET_LEN
        self._t_observe(shift, sync=False)
        return True

    def _add_piece(self, soft: np.ndarray, cw: np.ndarray, t_s: float, y0: int, near: tuple = ()) -> None:
        """Keep a piece with its packet time (receiver.decode.pieces) and try the ML choice of
        the light's ID (once it is known, the piece only measures its frame's jitter for the
        other lights): a short one (no more than `pieces_max_chips` chips), or, when the
        exposure model reads the chips, any frame short of a whole packet (`PIECES_MAX_CHIPS`)."""
        if soft.size > (PIECES_MAX_CHIPS if self.exposure_model else self.pieces_max_chips):
            return  # a long piece: the assembly above places it by its own chips
        q = self.rate_hz * float(t_s) + (y0 + self.last_start_row) / self.rows_per_chip
        if self.led_id is None and self.pieces.frame_jitter is not None:
            self.pieces.frame_jitter.want()
        self.pieces.add(soft, cw, q, float(t_s))
        led_id = self.pieces.decide(fixed=self.led_id, near=near)
        if led_id is not None:
            self.led_id = led_id
            self.pieces_took = self.pieces.added

    def _add_timed(self, soft: np.ndarray, cw: np.ndarray, shift: int) -> None:
        """Add a frame placed by the frame clock: trusted once the offsets are tied to packet
        coordinates by a sync frame, else kept apart (`timed_w`) until one confirms them."""
        self.timing_stats["timed"] += 1
        sure = self.anchored and self._t_confirmed
        self._add(soft, cw, shift, trusted=sure, timed=not sure)
        self.timed_frames.append((soft, shift))

    def _rotate(self, q: int) -> None:
        """Rotate the unanchored accumulator so that its sync (at q) lands on position 0."""
        self._acc4[:] = np.roll(self._acc4, -q, axis=1)  # in place: acc .. timed_w stay its rows
        self.acc_sq[:] = np.roll(self.acc_sq, -q)
        self._tobs = deque(((k, o - q) for k, o in self._tobs), maxlen=self._tobs.maxlen)
        self.timed_frames = deque(((x, (sh - q) % PACKET_LEN) for x, sh in self.timed_frames),
                                  maxlen=self.timed_frames.maxlen)
        self.anchored = True

    # -- frame-clock timing -------------------------------------------------------------

    @property
    def rows_per_chip(self) -> float:
        """Learned rows per chip (nominal until learned)."""
        return self._period if self._period is not None else self.period0_rows

    def _timing_reset(self) -> None:
        self._tobs.clear()
        self._t_confirmed = False
        self._t_strong = False
        self.timed_w[:] = 0.0  # unconfirmed timed chips stay in the accumulator, untrusted

    def _t_predict(self, k: int | None = None) -> float | None:
        """Offset o of frame k (default: this frame) from the line through the recent
        offsets, or None."""
        if not self._tobs:
            return None
        if self._tk - self._tobs[-1][0] > self.timing_max_gap:
            self._timing_reset()
            return None
        return line_predict(self._tobs, self._tk if k is None else k, self.timing_window)

    def _t_observe(self, shift: int, *, sync: bool = False, timed: bool = False) -> None:
        """Record where this frame was placed (accumulator coordinates) against the clock.

        Offsets come from sync-placed frames (strong), timed frames (which only refine the
        fraction of a chip: tracking the slow drift) and, while there are none, from the
        first frame or a correlation alignment (weak: these can be off by whole chips).
        A sync-placed frame that the offset line does not predict (by > timing_conflict
        chips) disables timing for good when the line rests on a sync, and replaces a weak
        line. A sync-placed frame that agrees ties the offsets to packet coordinates: the
        timed chips so far become trusted."""
        if self._tc is None or not self.timing_ok:
            return
        o = wrap_chips(shift - self._tc)
        pred = self._t_predict()
        if pred is not None:
            d = wrap_chips(o - pred)
            if not (sync or timed):
                return  # a correlation alignment adds nothing to a line
            if sync and abs(d) > self.timing_conflict:
                if self._t_strong:
                    self._disable_timing("conflict")
                    return
                self.timing_stats["weak_reset"] += 1
                self._timing_reset()
            else:
                if sync:
                    self.timing_resid.append(abs(d))
                o = pred + d
        self._tobs.append((self._tk, o))
        self._t_strong = self._t_strong or sync
        if sync and self.anchored and not self._t_confirmed:
            self._t_confirmed = True
            self.trust_w += self.timed_w
            self.timed_w[:] = 0.0

    def _disable_timing(self, why: str) -> None:
        self.timing_stats[why] += 1
        self.timing_ok = False
        self._timing_reset()

    def _timed_shift(self, soft: np.ndarray, tc: float | None = None, k: int | None = None) -> int | None:
        """The frame's shift predicted by the clock, or None: no clock or offset, the frame's
        chip grid more than `timing_frac` chips off the prediction, or the frame disagrees
        with the accumulated chips it overlaps (which disables timing). `tc`, `k`: the clock
        coordinate of the frame's chip 0 and its frame index (default: this frame)."""
        if tc is None:
            tc, k = self._tc, None
        if tc is None or not self.timing_ok:
            return None
        pred = self._t_predict(k)
        if pred is None:
            return None
        v = tc + pred
        r = round(v)
        if abs(v - r) > self.timing_frac:
            self.timing_stats["frac"] += 1
            return None
        self.timing_frac_resid.append(abs(v - r))
        shift = int(r) % PACKET_LEN
        # judged against the chips that were placed mostly where they surely belong (sync,
        # complete alignment, confirmed timing): a short-overlap alignment may be the wrong one
        n_ov, c = _k.overlap_corr(self.acc, self.acc_w, self.trust_w, self.timed_w, soft, shift)
        if n_ov >= self.timing_min_overlap and c is not None and c < self.timing_min_corr:
            self._disable_timing("overlap_conflict")
            return None
        return shift

    def row0_coordinate(self, profile, weights, y0: int, *, min_chips: int = 16,
                        min_corr: float = 0.9, min_gap: float = 0.3) -> float | None:
        """Reference measurement for the frame clock: packet coordinate (chips, mod 54) of
        sensor row 0 in this frame, `shift - (y0 + start row of chip 0) / rows per chip`,
        from a unique strong match of the frame's chips with the decoded (CRC-valid) packet;
        None when not decoded, too few chips, or the match is weak or ambiguous. Does not
        touch the accumulator."""
        if self.led_id is None:
            return None
        soft, _ = self.frame_chips(profile, weights)
        if soft.size < min_chips:
            return None
        if self._tpl is None or self._tpl[0] != self.led_id:
            self._tpl = (self.led_id, packet_template(self.led_id))
        r = _k.best_two(self._tpl[1], soft)
        if r is None or r[1] < min_corr or r[1] - r[2] < min_gap:
            return None
        return float((r[0] - (y0 + self.last_start_row) / self.rows_per_chip) % PACKET_LEN)

    def _unanchored_chips(self) -> tuple[np.ndarray, np.ndarray]:
        """The unanchored accumulator as one pseudo-frame (known run of chips) for retrying."""
        known = self.acc_w > 0
        start = int(np.argmin(known)) if not known.all() else 0
        order = (np.arange(PACKET_LEN) + start) % PACKET_LEN
        order = order[known[order]]
        return self.acc[order] / self.acc_w[order], np.minimum(self.acc_w[order], 1.0)

    def _cyclic_sync(self) -> int | None:
        """Sync position in the (unanchored) accumulated packet, or None."""
        m = self._mean_packet(self.acc_w > 0)
        ext = np.concatenate((m, m[:SYNC_LEN - 1]))
        s, _ = find_sync(ext, sync_margin=self.sync_margin)
        return None if s is None else s % PACKET_LEN

    def _retry_pending(self) -> None:
        if self.timing_ok and self._t_strong:
            # placed by timing from now on: the pending frames with a clock value too, those
            # without are dropped (a short-overlap alignment is the risky placement)
            for soft, cw, tc, k in list(self.pending):
                shift = self._timed_shift(soft, tc, k) if tc is not None else None
                if shift is not None:
                    self._add_timed(soft, cw, shift)
            self.pending.clear()
            return
        placed = True
        while placed and self.pending:
            placed = False
            for i, (soft, cw, _, _) in enumerate(self.pending):
                shift = self._align(soft)
                if shift is not None:
                    del self.pending[i]
                    self._place_at(soft, cw, shift)
                    placed = True
                    break

    def _place_at(self, soft: np.ndarray, cw: np.ndarray, shift: int) -> None:
        self._add(soft, cw, shift, trusted=self.anchored and self._last_align_complete)
        self._chain(soft)
        if not self.anchored:
            q = self._cyclic_sync()
            if q is not None:
                self._rotate(q)

    def _age_stale(self) -> None:
        self._stale += 1
        if self._stale >= self.stale_frames:
            self._clear()
            self._stale = 0

    def _soft_due(self) -> bool:
        """Try the maximum-likelihood ID decision? Only for a light without an ID whose chips
        the exposure model reads, with the packet anchored and `soft_min_chips` positions seen."""
        return (self.soft_min_z > 0 and self.exposure_model and self.led_id is None and self.anchored
                and int(np.count_nonzero(self.acc_w)) >= self.soft_min_chips)

    def _soft_decode(self) -> int | None:
        """The ID of `soft_decide` on the accumulated packet when it passes `soft_min_z` and
        `soft_min_snr`, else None."""
        led_id, z, snr = soft_decide(self.acc, self.acc_w, self.acc_sq, sigma_floor=self.soft_sigma_floor,
                                     z_cap=self.soft_min_z)
        self.soft_z = z
        return led_id if z >= self.soft_min_z and snr >= self.soft_min_snr else None

    def _clear(self) -> None:
        self.acc_sq[:] = 0.0
        self.acc[:] = 0.0
        self.acc_w[:] = 0.0
        self.trust_w[:] = 0.0
        self.anchored = False
        self._chained = False
        self._timing_reset()
        self.timed_frames.clear()

    def _verified(self, led_id: int, soft: bool = False) -> bool:
        """A packet whose every data chip was placed by trusted placements (the frame's own
        sync, or a complete alignment, see `_align`) is accepted as it is (a `soft` decision:
        every chip seen so far). One that needed other alignments must fit all of the last
        `verify_frames` frames (there must be that many): a 2-chip slip in the assembly is then
        exposed by the frames straddling it."""
        sure = self.trust_w[self.acc_w > 0] if soft else self.trust_w[SYNC_LEN:]
        if (sure > 0).all():
            return self._timed_frames_fit(led_id)
        if len(self.recent) < self.recent.maxlen:
            return False
        t = packet_template(led_id)
        return all(best_cyclic_match(s, t) >= self.verify_min for s in self.recent)

    def _chain(self, soft: np.ndarray) -> None:
        """A frame was placed by alignment: a short one read by the exposure model makes the
        packet's first ID need confirmation (its maximum-likelihood decision names an ID for
        any chained packet, not only a CRC-valid one)."""
        self._chained = self._chained or (self.exposure_model and soft.size < self.confirm_max_chips)

    def _propose(self, led_id: int) -> None:
        """A first ID from a packet chained by alignments of short frames, or from the soft
        decision (`_soft_decode`): confirmed by the frames that follow (`_confirm_step`) before
        it is reported; a new proposal replaces one under confirmation."""
        if self._confirm is None or self._confirm.led_id != led_id:
            self._confirm = confirm.Confirmation(
                led_id, packet_template(led_id), min_fit=self.verify_min, min_gap=self.confirm_gap,
                max_frames=self.confirm_frames, min_chip=self.confirm_min_chip,
                misfit_right=self.confirm_misfit_right, misfit_wrong=self.confirm_misfit_wrong,
                min_llr=self.confirm_min_llr, end_chips=self.confirm_end_chips,
                twins=[packet_template(t) for t in moved_pair_twins(led_id)],
                twin_frames=self.confirm_twin_frames)

    def _confirm_step(self, soft: np.ndarray) -> None:
        """This frame's part in confirming the proposed ID: reported once confirmed; an ID
        not confirmed in time is dropped with the accumulation that proposed it (a wrong
        chain would keep proposing it)."""
        c = self._confirm
        c.add(soft)
        if c.done:
            self._confirm = None
            if self.led_id is None:
                self.led_id = c.led_id
                self._stale = 0
        elif c.expired:
            self._confirm = None
            self._clear()

    def _timed_frames_fit(self, led_id: int) -> bool:
        """Every recent frame placed by timing fits the packet exactly where it was put
        (normalised correlation >= verify_min at its own shift, not at its best one): a
        wrong clock value (a whole-chip slip) is exposed by the frame it misplaced. A misfit
        drops timing for good."""
        if not self.timed_frames:
            return True
        t = packet_template(led_id)
        for soft, shift in self.timed_frames:
            c = _k.corr_at(t, soft, shift)
            misfit = c is not None and c < self.verify_min
            if misfit:
                if self.timing_ok:
                    self._disable_timing("verify_conflict")
                self.timed_frames.clear()
                self.trust_w[:] = 0.0  # nothing placed so far is sure any more
                return False
        return True

    def _decode(self) -> None:
        complete = False
        led_id, conf = None, 0.0
        table = _CRC8_TABLE if _CRC8_TABLE is not None else crc8_table()
        r = _k.decode_acc(self.acc, self.acc_w, self.min_margin, table) if self.anchored else None
        if r is not None:
            (led_id, conf), complete = r, True
        soft = False
        if led_id is None and self._soft_due():
            led_id, soft = self._soft_decode(), True
            complete = complete or led_id is not None
        if not complete:
            self.confidence = 0.0
            return
        self.confidence = conf
        if led_id is not None:
            self._stale = 0
        else:
            self._age_stale()
        if led_id is None or led_id == self.led_id:
            self._cand, self._cand_n = None, 0
            return
        if not self._verified(led_id, soft=soft):
            return
        if self.led_id is None:
            if self._chained or soft:
                self._propose(led_id)
            else:
                self.led_id = led_id
            return
        self._cand_n = self._cand_n + 1 if led_id == self._cand else 1
        self._cand = led_id
        if self._cand_n >= self.switch_frames:
            self.led_id, self._cand, self._cand_n = led_id, None, 0
