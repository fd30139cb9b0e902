"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.core.settings import knob


@dataclass(frozen=True)
class OokSettings:
    """What a user may set of `OokDecoder` (receiver.decode.ook), each [default]. The chip rate
    comes from the LED map, the row time and exposure from the camera; the decoder's fixed
    constants are `OokTuning` below, each documented there. docs/ook-exposure.md describes the
    chip reading and the confirmation, with their Monte Carlo.

      exposure_model ["auto"]: how a frame's chips are read. "auto": by the exposure model
        (receiver.decode.exposure: each row averages the chips its exposure spans) when the
        exposure is at least receiver.decode.exposure.MODEL_FROM_CHIPS (0.5) of a chip, else
        by the plain sampler (shorter exposures leave flat chip middles, which it reads); "on":
        always the model; "off": never. Cost: the model fits `OokTuning.model_phases` sub-chip
        offsets per frame.
      decay_per_frame [0.9]: the packet accumulator is multiplied by this each frame before the
        frame is added (about 1 / (1 - decay_per_frame) = 10 frames of memory). Larger: faint
        lights sum more frames, a changed LED takes longer to take over. At most 1 (above it,
        old frames would outweigh new ones).
      switch_frames [3 frames]: consecutive frames a different CRC-valid ID needs to replace
        the decoded one. Larger: a glitch never replaces an ID, a real change shows later.
      confirm_max_chips [20 chips]: a first ID from a packet in which a frame of fewer chips
        was placed by alignment (a wrong shift of n chips ties the right one with probability
        about 27 * 2^(-n/2), and builds a wrong, CRC-valid packet) is reported only once the
        frames after it confirm it (receiver.decode.confirm: `OokTuning`'s verify_min and
        confirm_* fields); 0 = no confirmation. Cost: such IDs come some frames later; seeded
        Monte Carlo (tests/decode/ook_mc.py) in docs/ook-exposure.md.
      soft_min_z [4.0 noise sds]: with the exposure model, a light without an ID whose packet
        the CRC rule rejects is decided by maximum likelihood over all 65,536 packets
        (`receiver.decode.ook.soft_decide`), accepted only when the best ID beats every other by
        this margin, and reported only once the later frames confirm it (as an ID from a
        chained packet); 0 = no soft decision. Lower: earlier IDs from noisy frames, more wrong.
      pieces_max_chips [16 chips]: with the map's IDs at this rate as candidates (map
        addressing, rolling shutter), the frames of a light that show no more than this many
        chips are kept as pieces and placed by their timestamps (receiver.decode.pieces); the ID
        is chosen by maximum likelihood over the candidates. When the exposure model reads the
        chips, every frame short of a whole packet is a piece (`ook.PIECES_MAX_CHIPS`). 0 = off.
        Cost: one correlation table per piece against every candidate (grows with the map's IDs
        at the rate).
      pieces_jitter_us [200 us]: the camera's frame-start jitter: pieces are placed within
        +- this of their timestamps (the frame's other decoded lights narrow it to +- 1 chip,
        `pieces.FrameJitter`). Larger: tolerates a worse camera clock, more shifts searched.
    """

    exposure_model: str = "auto"
    decay_per_frame: float = knob(0.9, 0.0, 1.0)
    switch_frames: int = 3
    confirm_max_chips: int = 20
    soft_min_z: float = 4.0
    pieces_max_chips: float = 16.0
    pieces_jitter_us: float = knob(200.0, 0.0, 1e5)


@dataclass(frozen=True)
class OokTuning:
    """`OokDecoder`'s internal constants: not settings (a `--settings` file naming one fails),
    fixed by the protocol, the camera model and the Monte Carlo of docs/ook-exposure.md.
    `OokDecoder(tuning=...)` varies them for tests and studies. Chips, rows, frames as named;
    correlations and soft units are dimensionless."""

    # chip grid and period
    min_row_frac: float = 0.25  # rows narrower than this fraction of the widest are trimmed from a blob's ends
    segment_chips: float = 6.0  # period refinement segment: drift per segment under half a chip (~8 % row-time error)
    max_period_error: float = 0.08  # a refined period is clamped within this fraction of the nominal one
    period_frames: int = 5  # refined periods whose median fixes rows per chip (a camera/LED constant)
    min_coherence: float = 0.3  # frames whose transitions do not sit on one chip grid are skipped
    norm_chips: int = 8  # local normalisation window, chips
    # placing a frame in the packet
    sync_margin: float = 0.3  # every sync chip must be right by this (soft units)
    min_margin: float = 0.25  # decode threshold on every Manchester pair and sync chip (soft units)
    align_min: float = 0.7  # a frame without sync is placed by cyclic correlation >= this ...
    align_gap: float = 0.25  # ... beating every other shift by this ...
    align_min_chips: int = 8  # ... over at least this many chips
    parity_gap: float = 2.0  # Manchester pair-grid evidence (pairs) that restricts an alignment to one parity
    pending_frames: int = 8  # unplaceable frames kept and retried as the packet fills
    stale_frames: int = 10  # a full accumulator without a CRC-valid packet this long is cleared
    verify_min: float = 0.9  # least normalised correlation of a frame with a proposed packet that it fits
    verify_frames: int = 16  # frames each of which must fit an alignment-assembled new ID (`verify_min`)
    # frame-clock timing (receiver.decode.frameclock), only with a clock hint
    timing_window: int = 12  # frames of offsets in the offset line fit
    timing_max_gap: int = 6  # frames without an offset that reset the line
    timing_frac: float = 0.25  # a frame whose chip grid is further (chips) from the predicted one is not timed
    timing_conflict: float = 0.35  # a sync-placed frame further (chips) from the line stops timing
    timing_min_overlap: int = 4  # a timed frame overlapping this many surely placed chips ...
    timing_min_corr: float = 0.6  # ... must correlate with them this well, else timing stops
    # exposure model (receiver.decode.exposure)
    blur_rows: float = 1.0  # optical blur sigma across rows, px
    model_phases: int = 8  # sub-chip offsets tried per frame
    model_min_fit: float = 0.3  # frames the model explains less of the level variance of are skipped
    # soft ID decision (`soft_decide`)
    soft_min_snr: float = 1.0  # the best ID's amplitude must be at least this many noise sds
    soft_min_chips: int = 30  # packet positions seen before a soft decision is tried
    soft_sigma_floor: float = 0.05  # least noise sd assumed, soft units
    # confirmation of an ID chained from short frames (receiver.decode.confirm, `confirm_max_chips`)
    confirm_frames: int = 30  # frames after the proposal within which it must be confirmed, else dropped
    confirm_gap: float = 0.15  # a frame is placed at every shift within this of its best fit
    confirm_min_chip: float = 0.5  # a frame's chip agreeing with the packet by this shows its position
    confirm_misfit_right: float = 0.2  # share of a phone's frames misfitting their own packet (4-17 % measured)
    confirm_misfit_wrong: float = 0.4  # share misfitting a wrong assembly (10-45 % of 12-16-chip frames)
    confirm_min_llr: float = 0.75  # log-likelihood ratio right vs wrong assembly to confirm (3 fitting frames)
    confirm_end_chips: int = 1  # chips left out at each frame end (dimmed by the panel's edge)
    confirm_twin_frames: int = 1  # more later frames that must tell the ID from each moved-pair twin
    # pieces placed by time (receiver.decode.pieces, `pieces_max_chips`)
    pieces_frames: int = 30  # pieces kept
    pieces_min_frames: int = 6  # pieces before a decision
    pieces_min_corr: float = 0.85  # least mean correlation of the chosen ID
    # ... and beating every other candidate on the chips where their packets differ: those chips
    # agree with the winner by this on average (7 of 8 agree; a right ID's chips agree there as
    # elsewhere, a wrong best ID fits worst where it differs: docs/ook-exposure.md) ...
    pieces_min_agree: float = 0.75
    # ... with this many noise sds of evidence there (wrong best IDs that agree so reach 2.1)
    pieces_min_z: float = 3.0
    pieces_shift_penalty: float = 0.2  # correlation off per chip of shift from the timestamp
    pieces_timed_penalty: float = 1.0  # ... per chip from the time the frame's other lights measured

    def __post_init__(self):
        if not 0.0 < self.confirm_misfit_right < self.confirm_misfit_wrong <= 0.99:
            raise ValueError("confirm_misfit_right must be over 0 and below confirm_misfit_wrong, at most 0.99 "
                             "(a wrong assembly misfits more of its frames than the right packet does)")


OOK_TUNING = OokTuning()


@dataclass(frozen=True)
class ToneSettings:
    """What a user may set of `ToneDecoder` (receiver.decode.tone), each [default]. A measured
    frequency matches a listed one within half the map's channel spacing (the smallest gap
    between its frequencies, at least 50 Hz); the band searched (FMIN_SHARE / FMAX_SHARE of the
    listed frequencies) and the least spectral peak quality (MIN_QUALITY) are
    receiver.decode.tone's constants.

    decay_per_frame [0.8]: the running frequency mean is multiplied by this each frame before
        the new frame is added, so a blob that changes LED is followed (about
        1 / (1 - decay_per_frame) = 5 frames of memory). Larger: steadier, slower to follow a
        change. At most 1.
    """

    decay_per_frame: float = knob(0.8, 0.0, 1.0)


@dataclass(frozen=True)
class S2pskSettings:
    """What a user may set of `S2pskDecoder` (receiver.decode.s2psk), each [default]. The clock
    and symbol length come from the LED map; the symbol-grid search, the hard rule's margins
    and the soft rule's evidence floors are receiver.decode.s2psk's module constants.

      inverted [False]: read in-phase emitters as symbol 1 (PROTOCOL.md's inverted polarity;
        the thesis polarity by default).
      history_s [None: 2.5 packets, 6 s at the default 200 Hz clock and 16 clocks a symbol]:
        samples older than this are forgotten; at least one packet (30 symbols). Longer: more
        samples per symbol for faint or rarely seen pairs, slower to follow a changed ID; the
        cost of a decode grows with it.
      switch_steps [10 decodes]: consecutive decodes a different valid ID needs to replace the
        decoded one (a decoded pair is decoded every `PolicySettings.redecode_every_frames`
        frames).
      soft_min_z [3.5 noise sds]: a packet the hard rule rejects (every sync symbol and
        Manchester pair must clear the margins, `decode_symbols`) is decided by maximum
        likelihood over every valid packet (`decode_soft`: 256 IDs x 30 shifts,
        docs/s2psk-pairs.md), accepted only when the best ID beats every other by this margin;
        0 = no soft decision (the hard rule alone). Lower: more and earlier IDs from faint
        pairs, more wrong ones (pure-noise packets reach z 2.3; the largest z of a wrong best ID
        with a true ID in heavy noise was 3.35 in a seeded Monte Carlo of 1.4 million packets).
        Cost: one 7680 x 30 matrix product per rejected packet (a second only when the first
        margin passes), about 0.1-0.25 ms each.
    """

    inverted: bool = False
    history_s: float | None = None
    switch_steps: int = 10
    soft_min_z: float = 3.5


@dataclass(frozen=True)
class PolicySettings:
    """What a user may set of the decoding policy (`receiver.decode.policy`), each [default].
    The frame clock's fixed constants are receiver.decode.frameclock's; how many decoded lights
    measure it is receiver.pipeline.CLOCK_REFS; the frames a tone match holds before it is
    reported are receiver.decode.policy.TONE_CONFIRM_FRAMES.

    redecode_every_frames [8 frames]: a track whose ID is known feeds its decoders only every
        this many frames (staggered by track); tracks without an ID are decoded every frame. 8
        re-checks a known ID every 0.27 s at 30 fps, and a changed ID is taken after the
        decoder's `switch_frames` (OOK) or `switch_steps` (S2-PSK) such checks. 1 = every
        frame. Cost: decoded lights' decoding time is divided by it (it keeps the frame budget
        with many lights: 16 lights in 2 ms median); the delay to see a changed ID grows with
        it. S2-PSK pairs alike (`DecodePolicy.pair_due`): their samples are stored every frame,
        decoded every this many frames.
    stripe_check [None: from the map and camera, `ModePlan.expect_stripes`]: True when every
        light must show rolling-shutter stripes: a new track is reported and decoded only once
        its row profile shows stripes (depth at least receiver.vision.detect.MIN_STRIPE_DEPTH)
        or it is shorter than a stripe period, so flat bright regions (lamps, windows) stay
        silent. False: every track is decoded. Cost: one stripe-depth measure per new track.
    """

    redecode_every_frames: int = 8
    stripe_check: bool | None = None
