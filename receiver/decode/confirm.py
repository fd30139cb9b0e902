"""Confirmation of an OOK ID by frames that did not build it (PROTOCOL.md section 1).

A light whose image shows few chips a frame is assembled by chaining its frames: each frame
without a sync is placed at its best cyclic correlation with what is accumulated so far. With n
chips a frame, a wrong shift matches the accumulated chips as well as the right one with
probability about 2^(-n/2) (n/2 Manchester pairs, each matching or not), and each alignment
compares up to 27 shifts of the right pair parity: with 16 chips a frame some wrong shift ties
or wins in about 27 / 256 of the alignments. One wrong placement makes the accumulation wrong
but self-consistent; the frames after it are aligned against it and reinforce it, and the
nearest CRC-valid packet (or the maximum-likelihood one) is then a wrong ID that every frame
which built it fits. No margin on that accumulation tells it apart: its errors are not noise.

An independent test does. The proposed ID's packet is known in full, so each later frame is
placed against that fixed packet alone (its best of 54 cyclic shifts, normalised correlation >=
`min_fit`), not against the accumulation. A wrong assembly is the sent packet with a stretch
taken a pair off; where the stretch begins and ends, the wrong packet puts side by side chips
that are not neighbours in the sent stream (the ends may hide inside runs of a repeated pair,
so that no single position is wrong there). So a frame shows two neighbouring positions
together only where they are neighbours in the stream: the ID is confirmed once every two
neighbouring positions of its packet were shown together by a later frame that fits it, and
few frames fit it nowhere (the frames that straddle a wrong stretch's ends); a frame that fits
at several shifts (a stretch of repeated bits) shows only what they all show, and a weak or
contradicting chip shows nothing.

How many later frames are enough is a sequential likelihood-ratio test on fitting and misfitting
frames: the frames that straddle a wrong stretch's ends fit it nowhere, 10-45 % of the frames of
12-16 chips (`misfit_wrong` of them), while a phone's frames misfit their own packet too, but
less often (`misfit_right`). Each fitting frame adds log((1 - misfit_right) / (1 - misfit_wrong))
to the log-likelihood ratio of "the proposed packet" against "a wrong assembly", each misfit adds
log(misfit_right / misfit_wrong) (negative); the ID is confirmed once that sum reaches `min_llr`
and every join was shown. A light whose later frames all fit confirms as soon as its joins are
shown (3 frames at the defaults), one whose frames misfit waits, and a share of misfits above
log((1 - r) / (1 - w)) / (that + log(w / r)) (29 % at the defaults) never confirms. The fit
leaves out `end_chips` chips at each end of a frame: the panel's edge (blur, bezel, diffuser
falloff) dims the rows at a profile's ends, so an ON chip there reads OFF (the end chips of phone
renders read wrong in 16-23 % of frames, the inner ones in 0.2-1.4 %).

Where the runs of a repeated pair are longer than a frame, the ends of a moved stretch hide in
them: every frame that fits the sent packet fits the wrong one too, and the joins test passes
either way (no frame clock ties the frames' offsets together to tell them apart). The wrong
assemblies to fear are known in advance, though: the packets of the other IDs that are the
proposed packet with a stretch moved by a pair (`twins`, receiver.decode.ook.moved_pair_twins).
Each one must be told apart: later frames that fit the proposed packet better than the twin by
`min_gap` (best normalised correlations) must outnumber those that fit the twin better by
`twin_frames`. A twin no frame can tell apart (its differences only inside runs longer than a
frame) keeps the ID unconfirmed.
Not confirmed within `max_frames` frames, it is dropped.
"""

from __future__ import annotations

import numpy as np

from firmware_tx.framing import OOK_PACKET_LEN as PACKET_LEN, SYNC

SYNC_LEN = len(SYNC)  # the same in every packet: covering it tells no ID from another


class Confirmation:
    """One proposed ID awaiting confirmation by the frames that follow its proposal."""

    def __init__(self, led_id: int, template: np.ndarray, *, min_fit: float, min_gap: float,
                 max_frames: int, min_chip: float, misfit_right: float, misfit_wrong: float, min_llr: float,
                 end_chips: int = 0, twins=(), twin_frames: int = 0):
        self.led_id = led_id
        self.template = np.asarray(template, dtype=np.float64)
        self.min_fit = min_fit
        self.min_gap = min_gap
        self.max_frames = max_frames
        self.min_chip = min_chip
        self.min_llr = min_llr
        self.end_chips = end_chips
        # log-likelihood ratio (right packet : wrong assembly) of a fitting and of a misfitting frame
        self.fit_llr = float(np.log((1.0 - misfit_right) / (1.0 - misfit_wrong)))
        self.misfit_llr = float(np.log(misfit_right / misfit_wrong))
        self.joins = np.zeros(PACKET_LEN, bool)  # [p]: positions p and p + 1 shown by one frame
        self.misfits = 0  # later frames that fit the proposed packet nowhere
        self.frames = 0
        self.twins = [np.asarray(t, dtype=np.float64) for t in twins]
        self.twin_frames = twin_frames
        self.told_apart = np.zeros(len(self.twins), np.int64)  # [k]: frames for the packet - for twin k

    def add(self, soft: np.ndarray) -> None:
        """One later frame's soft chips (~ +-1), less `end_chips` at each end. When it fits the
        proposed packet (best normalised correlation >= min_fit), the positions its chips show:
        at every shift within `min_gap` of the best one, the chips that agree with the packet by
        `min_chip`."""
        self.frames += 1
        x = np.clip(np.asarray(soft, dtype=np.float64), -1.0, 1.0)
        if self.end_chips and x.size > 2 * self.end_chips + SYNC_LEN:
            x = x[self.end_chips:x.size - self.end_chips]
        den = float(np.abs(x).sum())
        if den <= 0:
            return
        pos = (np.arange(PACKET_LEN)[:, None] + np.arange(x.size)[None, :]) % PACKET_LEN  # (shift, chip)
        agree = self.template[pos] * x
        corr = agree.sum(axis=1) / den
        best = float(corr.max())
        for k, t in enumerate(self.twins):
            tbest = float((t[pos] * x).sum(axis=1).max()) / den
            if best >= tbest + self.min_gap:
                self.told_apart[k] += 1
            elif tbest >= best + self.min_gap:
                self.told_apart[k] -= 1
        if best < self.min_fit:
            self.misfits += 1
            return
        shown = np.ones(PACKET_LEN, bool)
        for s in np.flatnonzero(corr >= best - self.min_gap):
            at = np.zeros(PACKET_LEN, bool)
            at[pos[s][agree[s] >= self.min_chip]] = True
            shown &= at
        self.joins |= shown & np.roll(shown, -1)

    @property
    def llr(self) -> float:
        """Log-likelihood ratio of the proposed packet against a wrong assembly from the later
        frames' fits and misfits (module docstring)."""
        return (self.frames - self.misfits) * self.fit_llr + self.misfits * self.misfit_llr

    @property
    def done(self) -> bool:
        """The later frames' log-likelihood ratio reached `min_llr`, and every two neighbouring
        packet positions from the last sync chip on were shown together by one that fits, and
        every twin was told apart by `twin_frames` frames net."""
        return (self.llr >= self.min_llr and bool(self.joins[SYNC_LEN - 1:].all())
                and bool((self.told_apart >= self.twin_frames).all()))

    @property
    def expired(self) -> bool:
        """`max_frames` later frames did not confirm the proposed packet."""
        return self.frames >= self.max_frames and not self.done
