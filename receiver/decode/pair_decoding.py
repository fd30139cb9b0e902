"""The S2-PSK decoding state of a receiver's emitter pairs (receiver.vision.pairing.Pair), kept
per pair by its `uid`: the pair's own decoders and the decoder sets that stand in until it has
an ID. `PairDecoding.step` feeds one pair's frame and names the pair when one of them decodes."""

from __future__ import annotations

import math

from receiver.decode.policy import DecodePolicy
from receiver.decode.s2psk import flux_xor, pair_xor


class PairDecoding:
    """Every live pair's S2-PSK decoder sets (`DecodePolicy.new_pair_decoders`), by Pair.uid:

    * `main`: the pair's own decoders, fed from the frame it formed on;
    * `early`: fed its backlog (the frames before it formed) too, until an ID or until they hold
      no sample from before the pair formed (`early_until`, then dropped): the founding tracks
      may have followed other blobs before, and a wrong history must not hold the pair's own
      samples back; whichever set decodes first wins;
    * `confirm`: fed from the frame the pair lost `Pair.confirmed` on (placed on blobs that may
      be another light's): until they decode, only what its emitters send from then on names it;
    * `flux`: a far head's whole flux (`Pairer.reads_flux`: no side needed, so the camera's yaw
      shake does not matter), fed until the pair's first ID."""

    def __init__(self, policy: DecodePolicy):
        self.policy = policy
        self.main: dict[int, dict] = {}
        self.early: dict[int, dict] = {}
        self.early_until: dict[int, float] = {}
        self.confirm: dict[int, dict] = {}
        self.flux: dict[int, dict] = {}

    def step(self, p, t_s: float, frame_index: int, a: float, b: float, flux: tuple | None = None) -> None:
        """Feed pair `p` this frame's emitter intensities a, b (and, for a far head read by its
        flux, `flux` = (its flux, the flux's ON level)); an accepted ID becomes the pair's
        (`led_id`, `kind`; `confirmed` when the confirm decoders found it)."""
        policy = self.policy
        decs = self.main.get(p.uid)
        if decs is None:
            decs = self.main[p.uid] = policy.new_pair_decoders()
            if p.backlog:
                early = self.early[p.uid] = policy.new_pair_decoders()
                self.early_until[p.uid] = t_s + max(getattr(d, "history_s", math.inf) for d in early.values())
                for t_b, *ab in p.backlog:
                    policy.step_pair(early, t_b, pair_xor(*ab))
                p.backlog = []
        (a_on, a_off), (b_on, b_off) = p.levels_a.on_off(), p.levels_b.on_off()
        x = pair_xor(a, b, a_on, b_on, a_off, b_off)
        due = policy.pair_due(p.led_id, frame_index, p.uid)
        found, _ = policy.step_pair(decs, t_s, x, due)
        if flux is not None:
            fdecs = self.flux.get(p.uid)
            if fdecs is None:
                fdecs = self.flux[p.uid] = policy.new_pair_decoders()
            ffound, _ = policy.step_pair(fdecs, t_s, flux_xor(*flux), due)
            if found is None and ffound is not None and p.led_id is None:
                found = ffound
        early = self.early.get(p.uid)
        if early is not None and t_s > self.early_until[p.uid]:
            del self.early[p.uid]
            early = None
        if early is not None:
            if found is None:
                found, _ = policy.step_pair(early, t_s, x)
                if found is not None:  # from now on the decoders that found the ID
                    self.main[p.uid] = early
            if found is not None:
                del self.early[p.uid]
        if not p.confirmed:
            conf = self.confirm.get(p.uid)
            if conf is None:
                conf = self.confirm[p.uid] = policy.new_pair_decoders()
            cfound, _ = policy.step_pair(conf, t_s, x)
            if cfound is not None:
                found, p.confirmed = cfound, True
                self.main[p.uid] = conf
                del self.confirm[p.uid]
                self.early.pop(p.uid, None)
            else:
                found = None
        if found is not None:
            p.led_id, p.kind = found.led_id, getattr(found, "kind", None)
            self.flux.pop(p.uid, None)  # fed only until the pair's first ID

    def keep(self, uids: set) -> None:
        """Forget the pairs whose uid is not in `uids` (no longer live)."""
        for uid in [u for u in self.main if u not in uids]:
            del self.main[uid]
            self.early.pop(uid, None)
            self.early_until.pop(uid, None)
            self.flux.pop(uid, None)
            self.confirm.pop(uid, None)
