"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass

from receiver.core.settings import knob


@dataclass(frozen=True)
class OokSettings:
    """Tunables of `OokDecoder` (defaults in brackets).

      rate_hz [20000]: chip rate from the LED map; row_readout_us [15]: sensor row time t_row;
      exposure_us [0]: row exposure (camera.yaml); 0 = unknown: learned from the stripes'
        edge ramps (`receiver.decode.exposure.ExposureLearner`, shared per rate).
      min_row_frac [0.25]: rows with fewer pixels than this fraction of the widest row are
        trimmed from the blob's top and bottom.
      segment_chips [6]: segment length for the period refinement (drift per segment must stay
        under half a chip: 6 chips tolerate ~8 % row-time error); max_period_error [0.08].
      verify_frames [16], verify_min [0.9]: a CRC-valid packet assembled by cyclic alignment
        could be a wrong assembly (a 2-chip slip) that happens to pass CRC-8 (1 in 256); unless
        every data chip was placed where it surely belongs (by its frame's sync, or by an
        alignment that could compare every shift), a new ID is reported only when each of the
        last `verify_frames` frames fits its full packet somewhere with normalised correlation
        >= verify_min (`best_cyclic_match`).
      confirm_max_chips [20], confirm_frames [30]: a first ID from a
        packet for which a frame of fewer than confirm_max_chips chips read by the exposure
        model was placed by alignment (some wrong shift of its n chips ties the right one
        with probability about 27 * 2^(-n/2), and one wrong placement builds a wrong,
        self-consistent packet; the maximum-likelihood decision names an ID for it) is
        reported only when the frames after its proposal confirm it within confirm_frames,
        else it is dropped with its accumulation (receiver.decode.confirm). Each frame, less
        confirm_end_chips [1] chips at each end (dimmed by the panel's edge), is placed against
        the proposed packet alone, at every shift within confirm_gap [0.15] of its best fit
        when that is >= verify_min; its chips agreeing with the packet by confirm_min_chip
        [0.5] show their positions; every two neighbouring positions from the sync's last chip
        on must be shown together by one frame, and the frames' log-likelihood ratio of the
        proposed packet against a wrong assembly must reach confirm_min_llr [0.75]: a fitting
        frame adds log((1 - r) / (1 - w)), a frame fitting nowhere log(r / w), with r =
        confirm_misfit_right [0.2] the share of a phone's frames that misfit their own packet
        (without the end chips: 4-17 % on phone renders) and w = confirm_misfit_wrong [0.4] the share
        that misfit a wrong assembly (the frames straddling its moved stretch's ends, 10-45 %
        of 12-16-chip frames): 3 fitting frames confirm, more than 29 % misfits never do.
        confirm_twin_frames [1]: each other ID whose packet is the proposed one with a stretch
        moved by a pair (receiver.decode.ook.moved_pair_twins) must be told apart by this many
        more later frames fitting the proposed packet better (by confirm_gap) than fitting the
        twin better: inside runs of a repeated pair longer than a frame, the stretch's ends show in
        no frame, and a wrong assembly fits every frame.
        Seeded Monte Carlo (tests/decode/ook_mc.py, docs/ook-exposure.md).
      period_frames [5]: the refined chip period (rows) of this many frames is fixed by
        their median (it is a camera/LED constant); later frames only measure the phase.
      period_learner [None]: a `PeriodLearner` shared with the other decoders of this rate
        and camera (its own `period_frames` counts their refinements together); None: this
        decoder learns alone.
      min_coherence [0.3]: frames whose transitions do not sit on a chip grid are skipped.
      norm_chips [8]: local normalisation window, chips.
      sync_margin [0.3]: every sync chip must be right by this (soft units).
      align_min [0.7], align_gap [0.25], align_min_chips [8]: a frame without sync is placed
        by its best cyclic correlation with the accumulated packet only when that correlation
        is >= align_min, beats every other shift by align_gap and overlaps >= align_min_chips.
      pending_frames [8]: unplaceable frames kept and retried as the packet fills.
      decay [0.9]: accumulator memory per frame (< 1 lets a changed LED take over).
      min_margin [0.25]: decode threshold on every Manchester pair and sync chip.
      switch_frames [3]: consecutive frames a different CRC-valid ID needs to replace the
        decoded one.
      parity_gap [2.0]: Manchester pair-grid evidence (pairs) needed to restrict a cyclic
        alignment to shifts of the right parity (`pair_parity`).
      stale_frames [10]: a full accumulator that yields no CRC-valid packet for this many
        frames is cleared (a wrong alignment must not lock the decoder up forever).
      align_when_decoded [False]: once an ID is decoded, frames without a sync are skipped
        (saves the cyclic alignment, the step's dearest part; ID changes still show in the
        frames with sync).
      Frame-clock timing (only with a `clock` hint): timing_window [12] frames of offsets in
        the offset line fit; timing_max_gap [6] frames without an offset reset it;
        timing_frac [0.25]: a frame whose chip grid is further (chips) from the predicted one
        is not placed by timing; timing_conflict [0.35]: a sync-placed frame further from the
        offset line disables timing (for good when the line rests on a sync);
        timing_min_overlap [4], timing_min_corr [0.6]: a timed frame overlapping that many
        surely placed chips must correlate with them this well, else timing is disabled;
        trust_timed [True]: timed placements count as sure once a sync frame has confirmed
        the offsets (their frames are then checked at their own shift, `_timed_frames_fit`).
      Exposure model (receiver.decode.exposure): exposure_model ["auto"]: "auto" reads the
        chips by the exposure model when the exposure is at least model_min_chips [0.5] of a
        chip (shorter exposures leave flat chip middles, which the plain sampler reads),
        "on" always, "off" never; blur_rows [1.0]: optical blur sigma across rows (px) in the
        model; model_phases [8]: sub-chip offsets tried per frame; model_min_fit [0.3]:
        frames the model explains less than this fraction of the level variance of are
        skipped (no chip stream behind them).
      Soft ID decision (with the exposure model, for a light without an ID, when the rule
        above rejects its packet): maximum likelihood over all 65,536 packets at the anchored
        positions (`receiver.decode.ook.soft_decide`; unseen positions are erasures), once
        soft_min_chips [30] positions are seen; accepted when the best ID beats every other by
        soft_min_z [4.0] noise sds with amplitude >= soft_min_snr [1.0] noise sds (noise sd
        floored at soft_sigma_floor [0.05] soft units), and only when every position seen was
        placed by a trusted placement (else the `verify_frames` check). 0 = off.
      Pieces placed by time (receiver.decode.pieces; with the map's IDs at this rate as
        candidates, map addressing): frames of a light (once it has an ID, they measure the
        frames' jitter for the others) that show no more than
        pieces_max_chips [16] chips (0 = off) are kept (the last pieces_frames [30]), placed
        by their timestamps and image rows within +-pieces_jitter_us [200] (the camera's
        frame-start jitter; pieces_shift_penalty [0.2] correlation off per chip of shift), or,
        when the other lights of the frame measured its jitter (`pieces.FrameJitter`), at
        that time within +-1 chip and pieces_timed_penalty [1.0] off per chip,
        and the ID and packet phase chosen by maximum likelihood over the candidates, from
        pieces_min_frames [6] pieces, when the mean correlation is >= pieces_min_corr [0.85],
        beats every other ID by pieces_min_gap [0.3] and the pieces cover the packet.
        Seeded Monte Carlo (a small version is tests/decode/test_ook_pieces.py): pieces
        of 5-13 chips, 100 us rms jitter, 20-360 candidates, half of the lights not among
        them, 25 decisions a light: in 25,000 decisions the largest gap of a wrong best ID
        with mean correlation >= 0.8 was 0.230 (in 10,000 with >= 0.85: 0.191); a light in
        the map passes 0.85 / 0.3 in 15 % of its decisions (it needs one).
        Group Monte Carlo with the jitter measured by the lights of each frame
        (`python tests/decode/pieces_mc.py --trials 20`: 5 lights a trial, 40 % outside a map
        of 60-300 IDs, 100-200 us rms jitter, +-50 ppm crystals, 5-10 kHz, 70-120 rows): 0
        wrong IDs among 700 lights (200 of them in scenes with no light in the map); 68-99 %
        of the mapped lights decoded, after a median of 14-35 frames.
    """

    min_row_frac: float = 0.25
    segment_chips: float = 6.0
    max_period_error: float = 0.08
    min_coherence: float = 0.3
    norm_chips: int = knob(8, 1)
    sync_margin: float = 0.3
    align_min: float = 0.7
    align_gap: float = 0.25
    align_min_chips: int = 8
    pending_frames: int = 8
    decay: float = 0.9
    min_margin: float = 0.25
    switch_frames: int = 3
    parity_gap: float = 2.0
    stale_frames: int = 10
    align_when_decoded: bool = False
    period_frames: int = 5
    verify_frames: int = 16
    verify_min: float = 0.9
    confirm_max_chips: int = 20
    confirm_frames: int = 30
    confirm_gap: float = 0.15
    confirm_min_chip: float = 0.5
    confirm_misfit_right: float = knob(0.2, None, 0.99, above=0.0)
    confirm_misfit_wrong: float = knob(0.4, None, 0.99, above=0.0)
    confirm_min_llr: float = 0.75
    confirm_end_chips: int = 1
    confirm_twin_frames: int = 1
    timing_window: int = 12
    timing_max_gap: int = 6
    timing_frac: float = 0.25
    timing_conflict: float = 0.35
    timing_min_overlap: int = 4
    timing_min_corr: float = 0.6
    trust_timed: bool = True
    exposure_model: str = "auto"
    soft_min_z: float = 4.0
    soft_min_snr: float = 1.0
    soft_min_chips: int = 30
    soft_sigma_floor: float = 0.05
    pieces_max_chips: float = 16.0
    pieces_jitter_us: float = knob(200.0, 0.0, 1e5)
    pieces_frames: int = knob(30, 1, 1000)
    pieces_min_frames: int = knob(6, 1, 1000)
    pieces_min_corr: float = 0.85
    pieces_min_gap: float = 0.3
    pieces_shift_penalty: float = 0.2
    pieces_timed_penalty: float = knob(1.0, 0.0)
    model_min_chips: float = 0.5
    blur_rows: float = 1.0
    model_phases: int = 8
    model_min_fit: float = 0.3

    def __post_init__(self):
        if self.confirm_misfit_right >= self.confirm_misfit_wrong:
            raise ValueError("confirm_misfit_right must be below confirm_misfit_wrong (a wrong assembly "
                             "misfits more of its frames than the right packet does)")


@dataclass(frozen=True)
class ToneSettings:
    """Tunables of `ToneDecoder` (defaults in brackets).

    spacing_hz [None = smallest gap in the table, >= 50 Hz]; min_quality [30]: frames whose
    spectral peak is weaker than this are ignored (pure noise profiles of 30-300 rows reach
    up to ~25; there is no CRC in tone mode, so this gate is what keeps a non-LED blob out);
    memory [0.8]: per-frame forgetting of the running mean (a blob that changes LED is followed);
    fmin_hz / fmax_hz: see `stripe_frequency_hz` (fmin defaults to half the lowest listed
    frequency, fmax to 1.5 times the highest, so harmonics and envelope stay out of the search).
    """

    spacing_hz: float | None = None
    min_quality: float = 30.0
    memory: float = 0.8
    fmin_hz: float | None = None
    fmax_hz: float | None = None


@dataclass(frozen=True)
class S2pskSettings:
    """Tunables of `S2pskDecoder` (defaults in brackets).

      clk_hz [200]: emitter clock; symbol_clocks [16]: clock periods per symbol (both from the
        LED map); inverted [False]: read in-phase as 1 (the other published polarity).
      history_s [None = 2.5 packets]: samples older than this are forgotten (a packet is
        30 symbols = 2.4 s at the defaults).
      n_phases [16]: symbol-boundary phases tried over one symbol; phase_every [8]: the full
        phase search runs every this many steps, the steps between reuse the found phase.
      guard [0.12]: fraction of a symbol at each end whose samples are not used (timestamp
        jitter and exposure straddling a symbol change).
      sync_margin [0.25], min_margin [0.3]: see `decode_symbols`. sync_margin was 0.3: a
        lane-changing car (hil --mode s2psk seed 2, FV 228) followed right for 108 frames, every
        folded symbol's sign right, had one sync symbol at 0.29 with two samples (FV 155 -> 214
        of 214 resolvable light-frames); random folded packets (N(0, sd) clipped, 10^5 each,
        sd 0.3 / 0.6 / 1.0) decode as often at 0.25 as at 0.3 (0 / 0 / 2e-5: the Manchester
        margin and CRC-4 reject them).
      min_samples [1]: samples each packet position needs before a decode is attempted.
      switch_steps [10]: consecutive steps a different valid ID needs to replace the decoded one.
      decoder ["soft"]: "hard" = the margins above only (`decode_symbols`, the reference);
        "soft" = a packet the hard rule rejects is also tried by maximum likelihood over every
        valid packet (`decode_soft`, receiver.decode.s2psk.soft_stats: 256 IDs x 30 shifts,
        weighted by each position's sample count, noise fitted per packet; codebook distance
        >= 4 symbols between different IDs at any shifts, 6 aligned). Accepted when the margin
        over every other ID is >= soft_min_z [3.5] noise sds, the fitted amplitude >=
        soft_min_snr [1.0] noise sds and no position contradicts the packet by more than
        soft_max_contradiction [2.0] noise sds (a strongly wrong symbol is rejected, as by the
        hard rule); soft_sigma_floor [0.05]: least noise sd (soft units) assumed;
        soft_position_dof [0 = off]: weigh each position by its own samples' spread
        (`soft_stats` position_dof; 2.0 took recordings/vehicle SL 650 -> 653 and hil seed 1
        888 -> 891 but vehicle-road seed 1 138 -> 115 with 2 wrong light-frames and hil seed 1
        1 wrong, at soft_min_z 3.0: far heads decoded earlier whose pairs then missed a 10 px
        yaw jump and sat on the next head, pairing.py; off until pairs follow yaw).
        Measured (Monte Carlo, folded packets of 1-3 samples per position, N(0, sd) clipped to
        [-1, 1]; seeded small version in tests/decode/test_s2psk_soft.py): pure noise, 10^6 packets
        per sd 0.3 / 0.6 / 1.0: hard rule 0 / 0 / 1 accepted, soft rule 0 / 0 / 0 (largest z
        2.03 / 1.96 / 2.26; snr 99.99th percentile 0.86-0.93). A true ID plus noise, 2 x 10^5
        packets each at (sd, amplitude) (0.3, 0.3), (0.3, 0.5), (0.6, 0.3), (0.6, 0.5),
        (1.0, 0.3), (1.0, 0.5), (1.0, 1.0): the hard rule accepts 0 / 0 / 0 / 0 / 0 / 1 / 2
        wrong; the soft rule's largest z for a wrong best hypothesis is 3.35 (sd 1.0, amplitude
        1.0, one of 8211 wrong bests; counts above z 2 / 2.5 / 3 / 3.5: 7 / 2 / 1 / 0), so at
        soft_min_z 3.0 hard-or-soft accepted 3 wrong there against the hard rule's 2, at 3.5
        the same 2 (and the same as hard everywhere else). Right IDs, hard -> hard or soft at
        3.5: amplitude 0.5 in sd 0.3 0.106 -> 0.564, amplitude 1.0 in sd 1.0 0.039 -> 0.061.
        Pipeline, hard -> soft 3.5 (S2-PSK resolvable light-frames, 0 wrong everywhere):
        vehicle-road seeds 1 / 2 SL 98 / 14 -> 130 / 19 of 644 / 638, FV 136 / 166 unchanged;
        recordings/vehicle SL 646 -> 648 of 658, FV 156 / 156, HV filtered 2D median 0.06 ->
        0.05 m, p95 0.23 -> 0.17 m; hil --mode s2psk seeds 1-4 SL 884 / 868 / 882 / 854 ->
        886 / 868 / 838 / 872 (seed 3: SL 92 decoded at frame 71, not 105, and head 52 then
        never got a pair: pairing dynamics, not a decode; without that one soft decode seed 3
        reads 882 again), FV unchanged; resolvable IDs first decoded earlier (at 3.0: e.g. hil
        seed 1 ID 15 frame 99 -> 71, seed 4 ID 102 130 -> 86), none later. soft_min_z 3.0
        was 138 / 19, 650, 888 / 868 / 838 / 872, but `occloc hil --mode s2psk --scene
        vehicle-road --seed 3` 3 wrong light-frames: SL 62 decoded at z 3.39 by its far-head
        pair sitting a baseline aside of the head (pairing), reported over lights 17 / 122
        (0 wrong at 3.5 and by the hard rule). Cost: the soft rule runs only on packets the
        hard rule rejects (one 7680 x 30 matrix product, a second only when the first margin
        passes; ~0.1-0.25 ms per attempt on this machine); vehicle-road seed 1, 240 frames:
        4.03 / 3.83 s CPU hard vs 3.93 / 4.10 s soft.
    """

    inverted: bool = False
    history_s: float | None = None
    n_phases: int = 16
    guard: float = 0.12
    sync_margin: float = 0.25
    min_margin: float = 0.3
    min_samples: int = 1
    switch_steps: int = 10
    phase_every: int = 8
    decoder: str = "soft"
    soft_min_z: float = 3.5
    soft_min_snr: float = 1.0
    soft_max_contradiction: float = 2.0
    soft_sigma_floor: float = 0.05
    soft_position_dof: float = 0.0


@dataclass(frozen=True)
class FrameClockSettings:
    """Tunables of `FrameClock` (defaults in brackets).

    window [12]: frames of a reference's offset history in its line fit.
    max_gap [6]: a reference unseen for more frames than this loses its offset.
    max_resid [0.2]: chips a reference may disagree with the consensus.
    """

    window: int = 12
    max_gap: int = 6
    max_resid: float = 0.2


@dataclass(frozen=True)
class PolicySettings:
    """Tunables of the decoding policy (`receiver.decode.policy`; defaults in brackets).

    redecode_every [8]: a track whose ID is known feeds its decoders only every this many
        frames (staggered by track), to keep the frame budget with many lights (16 lights in
        2 ms median); tracks without an ID are decoded every frame. 8 frames re-check a known
        ID every 0.27 s at 30 fps (a changed ID is taken after the decoder's `switch_frames`
        consecutive CRC-valid checks). 1 = always; cost grows with it. S2-PSK pairs alike
        (`DecodePolicy.pair_due`): a decoded pair's samples are stored every frame and decoded
        every this many frames, so a changed ID takes `switch_steps` such checks.
    stripe_check [None = from the map and camera, `ModePlan.expect_stripes`]: when every light
        must show rolling-shutter stripes, a new track is reported and decoded only once its
        row profile shows stripes (depth >= `min_stripe_depth` [0.8]) or it is shorter than a
        stripe period; flat bright regions (lamps, windows) stay silent. (A single photo has no
        tracks: there detection drops flat blobs itself, at `detect.MIN_STRIPE_DEPTH`, the same 0.8.)
    tone_confirm_frames [None: 1 for a tone-only map or photos, else 3]: consecutive frames a
        tone match must hold before it is reported; with OOK lights in the map, an OOK stripe
        pattern can show a spectral line near a listed tone for a frame or two.
    frame_clock [True], clock_refs [3]: while some track has no ID, the `clock_refs` tallest
        decoded OOK tracks of each chip rate are measured every frame (their frame's packet
        position against their known packet, `OokDecoder.row0_coordinate`) to give the
        frame's clock (receiver.decode.frameclock); undecoded OOK decoders get it as a timing
        hint, so small lights whose frames barely overlap are still assembled. Rolling shutter
        only. Costs one row profile and packet match per reference per frame, only while a
        light lacks its ID.
    """

    redecode_every: int = 8
    stripe_check: bool | None = None
    min_stripe_depth: float = 0.8
    tone_confirm_frames: int | None = None
    frame_clock: bool = True
    clock_refs: int = 3
