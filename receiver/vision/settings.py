"""Settings of this stage: one frozen dataclass per component, defaults documented."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DetectSettings:
    """Tunables of `detect` (defaults in brackets).

      stripe_gap_px [8]: longest dark stripe (rows, full resolution) bridged inside one LED;
        the pipeline sets it from the chip/tone period. Larger also merges LEDs stacked closer.
      join_x_px [2]: horizontal gaps (columns, full resolution; at least one search pixel)
        bridged, so a stripe broken by a dark spot of the diffuser stays one LED.
      max_detect_px [1.2e6]: frames above this pixel count are searched downsampled.
      k_mad [8], min_contrast [24]: threshold, see `auto_level`.
      fine_noise [False]: the noise sigma of that threshold resolved below one gray level
        (`noise_sigma`: a dark, clipped background of MAD 0); the pipeline sets it, with a
        small `min_contrast`, for S2-PSK maps, whose far emitters peak 20-50 gray over ~0.4.
      refine_frac [0.5]: per-blob edge level between background (0) and peak (1): half
        maximum is the true edge of a blurred sharp-edged light (symmetric PSF), so the hull
        through the outermost lit pixel centres lies half a pixel inside it on average.
      saturated_gray [250], saturated_frac [0.03], min_refine_contrast [6]: a blob whose
        peak reaches `saturated_gray` is clipped (real phone photos: a saturated core in a
        dimmer, still striped glow); its edge level is background + max(saturated_frac *
        (255 - background), min_refine_contrast), which keeps the glow and gives the decoders
        many more stripe rows.
      min_area_px [12]: smaller envelopes are specks. max_area_frac [0.05]: larger than this
        fraction of the frame is a window or a lamp, not a transmitter.
      max_aspect [4], min_fill [0.25]: the stripe-bridged component's bounding box may be at
        most this elongated, and its contour must fill at least this fraction of the box (a
        disc fills 0.79, a 45-degree square 0.5, a thin diagonal bar almost nothing); border
        blobs are exempt, and so are components under shape_min_rows [0] rows tall (full
        resolution; the pipeline sets 3 for S2-PSK maps: far street-light heads seen from below
        are one or two rows tall and several px wide).
      expect_stripes [False]: reject blobs whose row profile is flat (stripe depth below
        `min_stripe_depth` [0.8]) when they span at least `min_stripe_rows` rows (set it to
        about one stripe period; 0 = always checked).
      min_rel_area [0]: drop blobs smaller than this fraction of the frame's largest blob
        (for single photos of a lamp set, where reflections look like small dim lamps;
        0 = off, since a moving camera sees near and far lights together).
      level [None]: fixed global threshold instead of `auto_level`.
      row_pool [2]: 2 = at full resolution, with stripes to bridge (stripe_gap_px >= 4), the
        components are searched on the maximum of every 2 rows: the close and contour pass
        cost half as much. Every gap the full-resolution search bridges is bridged, the boxes
        are the full-resolution search's and the envelopes are taken in full resolution within
        them, so the blobs are the same (a frame where component boxes overlap is searched in
        full resolution), except that the pooled rows may join lights the full-resolution
        search keeps apart: stacked up to 4 rows closer than stripe_gap_px, touching diagonally
        (within join_x_px columns) across a pair of pooled rows, or within a row or two of
        each other at the top or bottom edge (the pooled close reaches the edge from up to 2
        rows farther); and the `min_fill` test uses the pooled component's area (times 2),
        which can decide otherwise within a few % of `min_fill`. 1 = off (full resolution).
        Other values are refused: with 3 rows the pooled close can reach the bottom edge from
        a row less far than the full-resolution one and split what it joins.
    
    """

    stripe_gap_px: int = 8
    join_x_px: int = 2
    max_detect_px: int = 1_200_000
    k_mad: float = 8.0
    min_contrast: float = 24.0
    fine_noise: bool = False
    refine_frac: float = 0.5
    saturated_gray: float = 250.0
    saturated_frac: float = 0.03
    min_refine_contrast: float = 6.0
    min_area_px: float = 12.0
    max_area_frac: float = 0.05
    max_aspect: float = 4.0
    min_fill: float = 0.25
    shape_min_rows: int = 0
    expect_stripes: bool = False
    min_stripe_depth: float = 0.8
    min_stripe_rows: int = 0
    min_rel_area: float = 0.0
    level: float | None = None
    row_pool: int = 2


@dataclass(frozen=True)
class TrackSettings:
    """Tunables of `Tracker` (defaults in brackets).

      gate_px [30]: fixed part of the association gate, px.
      gate_size [1.5]: plus this many blob diameters (sqrt(area)), so big near lights may move
        more per frame than small far ones.
      max_area_ratio [4]: larger area change between frames is another light.
      max_missed [10]: frames a track survives without a blob (an S2-PSK emitter is dark in
        about half the frames, a blob may also leave the view briefly).
      velocity_gain [0.5]: smoothing of the px/frame velocity estimate (1 = last step only).
    
    """

    gate_px: float = 30.0
    gate_size: float = 1.5
    max_area_ratio: float = 4.0
    max_missed: int = 10
    velocity_gain: float = 0.5


@dataclass(frozen=True)
class PairSettings:
    """Tunables of `Pairer` (defaults in brackets).

    (see `pair_score`, units of blob diameters); min_frames [4]: frames of intensity history
    before the on/off check; min_swing [20]: gray levels between an emitter's on and off.
    Following a formed pair: a blob explains an emitter (or the midpoint) within match_size
    [1.5] emitter diameters (at least match_min_px [3] px), at most match_frac [0.75] of the
    baseline, widened by miss_growth_px [1] px per frame without an explained blob (the
    camera's pitch vibration moves far lights by a few px within a second). merged_ratio [1.5],
    max_merged [3]: a blob nearest the midpoint with 1.5 to 3 times one emitter's area is both
    emitters lit (two halves and the blurred gap); one nearest an emitter must be within
    merged_ratio of its area, or down to 1 / max_cut [3] of it (cut by a clock edge during the
    rolling readout). velocity_gain [0.3]: smoothing of the px/frame velocity. max_missed [10]:
    frames without an explained blob before the pair ends (both emitters are dark in about a
    quarter of the frames). give_up_frames [200]: a pair still without an ID after this many
    frames (2.8 packets of 2.4 s at 30 fps) is a wrong pairing and ends (110 ended a lane-
    changing car's right pair with one weak symbol 6 frames before its third pass: hil --mode
    s2psk seed 2 FV 107 -> 155 of 214). unseen_give_up_frames [60]: an undecoded pair of two
    tracks one of whose emitters has had no blob of its own for more than this many frames
    (since it formed) ends too, as a wrong pairing: each emitter of a light is lit alone in
    about a quarter of the frames, so a pair that only ever sees one end is one light and a
    place where none is (or another light's, whose decoded pair claims its blobs). hil --mode
    s2psk seed 3: a 90-118 px pair from head 52 to head 92 formed at frame 16; once 92's own
    pair decoded (frame 71) it lived on head 52's blobs alone, and its end on 52 kept 52's
    tracks from pairing until the end of the run. Right pairs (every decoded two-track pair
    of hil seeds 1-4, vehicle-road seeds 1-3, recordings/vehicle) had gaps of at most 11
    frames before their ID. S2-PSK resolvable SL light-frames / wrong (with beside_hold): 60:
    hil seed 3 844 -> 889 of 891, vehicle-road seed 4 359 / 1 wrong (off: 359 / 1), seeds
    1-3, hil seeds 1/2/4 and recordings/vehicle (output identical) as off. 30: vehicle-road
    seed 1 353 -> 380 but seed 4 359 -> 213 with 11 wrong (a wrong 90 px pair across two cars'
    taillights ended at frame 78: its blobs had held the yaw shift, `shake` "pairs"; head 87's
    pair then slid onto heads 52 / 63 / 97); 45: seed 4 11 wrong; 15: recordings/vehicle SL
    652 -> 638. 0 = off.
    Pairs from one jumping track (`_pair_jumpers`): a jump between single-emitter-sized blobs
    of min_baseline to jump_max_baseline [4] diameters, row_band as above; two consecutive such
    jumps within jump_agree [0.5] diameters of each other once jump_agree_y_px [4] px of their
    vertical difference (the camera's pitch vibration) is forgiven; the pair's baseline is their
    mean. A jump is taken less the measured image shift ("vertical", "2d", "yawpitch") added up
    since the track's previous blob (it may have been dark for frames in between).
    Camera shake: shake ["pairs"]: how the frame's common image shift (the camera's pitch
    and yaw vibration, up to ~10 px per frame on the vehicle-road scene) enters every track's and
    pair's prediction (S2-PSK maps). "pairs" (the default since issue 11): dy as "vertical", dx
    the yaw that best puts this frame's blobs where the formed pairs expect them
    (receiver.vision.motion.pair_dx over `Pairer.dx_offsets`: a blob both lit at its pair's
    midpoint, one emitter's at A or B, by width or area; each blob adds a Gaussian of
    shake_sigma_px [1.5] px around its best place to a shake_step_px [0.25] px grid within
    shake_radius_px; the heads' different baselines settle each one's side; dx 0 when that
    scores within shake_zero_rel [0.15] of the best, so a scene without yaw keeps 0). dx
    error over 2 px in 16 / 4 of the 239 frames of vehicle-road seeds 1 / 2 ("2d": 53 / 59
    with the same pairs, 81 before), 0 of 179 on `synth vehicle --seed 4` (no yaw; "2d": 24).
    "vertical": the mode of the vertical parts of the blobs'
    displacements from the last frames and from the pairs' predicted emitters, within
    shake_radius_px [14] px (receiver.vision.motion.vertical_shift; heads are horizontal, so each
    votes right whichever half is lit); "2d": x and y by `frame_shift` (experimental: the
    horizontal part is ambiguous by the baseline, wrong by > 2 px in a third of the frames of
    vehicle-road); "pitch" (the default): only the pairs' median vertical offset (`pitch_shift`,
    needs shake_min_pairs [3] pairs explaining a blob), the tracks none. Without agreement in a
    frame, "pitch" is used for it. "vertical" was the default (before "pairs") since it is measured together with
    the faint detection and the far-head backlog (README "S2-PSK pairs"); earlier, alone, hil
    --mode s2psk seeds 1-4 SL 513/503/534/540 (pitch: 524/487/512/492), recordings/vehicle SL
    362 (pitch: 391) of 658 resolvable light-frames.
    "yawpitch" (experimental): dy as "vertical", then dx from only the displacements whose
    vertical part agrees with dy, each blob of this frame voting once per cell against the
    blobs of the last frames (receiver.vision.motion.yaw_pitch_shift); on vehicle-road (seed 1,
    faint detection) dx is still off by > 2 px in 61 of 233 frames, and on recordings/vehicle
    (no yaw) its dx p50 error is 1.2 px: not the default. shake_x_wide [False]: the horizontal
    shift ("2d", "yawpitch") moves also pairs formed from two tracks (taillights, near heads),
    not only those from one jumping track (far heads); with the true shift of vehicle-road
    (from its truth, a diagnosis only) True gives FV 0 and False FV 136 of 287 resolvable
    light-frames (cause not found).
    Output: report_coast_frames [3]: a pair's two emitters are reported as LEDs (with the
    pair's ID) every frame, dark or lit, while the pair has explained a blob within this many
    frames (both halves are dark together in runs of 1-3 frames; a pair coasting longer may
    have lost its light, e.g. behind another car) (`Pairer.emitters`).
    backlog_frames [90]: frames of each unpaired track's history (time, seen, area, intensity)
    kept so that a new pair's decoder starts from the tracks' first frames (`Pair.backlog`):
    a pair forms 4-40 frames after its light appears, and without them its ID would come that
    much after the light's first whole packet. 0 = off.
    Far heads by their flux: flux_jumpers [True]: a pair from one jumping track (a far head)
    is also read by its head's whole flux (`Pairer.head_flux`: gray above the background +
    flux_floor [2] summed over a box one baseline plus flux_margin_px [10] either side of its
    midpoint, flux_margin_y_px [2] above and below its envelopes) into a third decoder set
    (receiver.decode.s2psk.flux_xor, both-lit level: twice the median of the last
    flux_recent [12] fluxes over flux_min [4]); no side is needed, so the yaw shake does not
    matter. Measured (README "S2-PSK pairs"): hil --mode s2psk seeds 1-4 SL +2/+10/+5/0, with
    S2PSK_FAINT_DETECT and shake "vertical" vehicle-road seeds 1/2 SL 0/0 -> 91/17.
    drop_twins [True]: an undecoded jumper pair whose midpoint lies within a decoded jumper
    pair's baseline plus match_min_px (horizontally; match_min_px vertically) is the same
    far head followed a baseline aside, and ends (`Pairer._drop_twins`).
    follow_size [True]: a decoded street light's pair takes one emitter's size from every blob
    it explains (half a merged one), not only from its single-emitter blobs: a near head grows
    by several % a frame and its merged blobs left the envelopes behind until its blobs no
    longer fitted them (hil s2psk seed 4 light 110 lost 18 frames at ~20 m; SL light-frames
    seeds 1-4 873/852/876/808 -> 879/868/882/838, recordings/vehicle 635 -> 641 of 658).
    jumper_levels_min_area_px [16]: a new jumper pair whose blob is at least this large (a near
    head) seeds both emitters' levels with its track's on / off levels (`Pairer._pair_jumpers`);
    inf = never (was: its first samples read against one or two values, a wrong sign that
    held hil seed 4 head 40's Manchester margin at 0.21 for its whole view; SL seeds 1-4
    879/868/882/838 -> 884/868/882/854, recordings/vehicle 641 -> 646; all seeding, any
    size: seed 4 879 but seeds 1 and vehicle 6 worse, far heads' first per-emitter reads).
    head_backlog [True]: a new far-head (jumper) pair's backlog is read from every blob of the
    last backlog_frames frames near the head, whichever track had it (`Pairer._head_backlog`:
    the place moved back by the frames' image shifts, following the blobs by head_follow
    [0.2] per frame, going back until head_gap_frames [4] frames in a row without a blob),
    when that is longer than its own track's: far heads' blobs are spread over several short
    tracks. Measured with S2PSK_FAINT_DETECT and shake "vertical": recordings/vehicle SL
    595 -> 635 of 658, hil seeds 1-4 SL 829/824/827/736 -> 873/857/877/818; defaults: no
    change but hil seed 3 SL +1 (the head is found too late by the default detection).
    Reporting: emitter_gate_larger [True]: a decoded emitter without its own blob in this frame
    is left out when another decoded pair's emitter is within match_size diameters of the
    larger emitter of the two lights (else: of its own, perhaps stale, envelope; two cars'
    taillights crossing, hil seed 4 frame 84, had two IDs swapped). jumper_unseen_frames [12]:
    a decoded far-head (jumper) pair's emitter without a blob of its own for more than this
    many frames is not reported (0 = off): such a pair may sit a baseline aside of its head
    (which half a blob was cannot be told) with one emitter on nobody's light, between heads
    (hil seed 1 frame 179: 14 frames; 8 cost 18-30 right light-frames per seed, 12 none).
    Far heads by width (issue 11): width_size [True]: a blob of at most
    width_max_rows [3] rows is one emitter when its width is within width_tol [0.25] (+1 px) of
    the emitters' envelope width, and both lit as one blob when it is one horizontal baseline
    wider (at least width_min_px [2] px), whatever its area, when the pair's envelopes are that
    short too (a row or two of a taller head cut by a clock edge, 17 x 2 px of a 17 x 5 px
    head, read as "merged" and pulled its pair off; `Pairer._width_class`): a far
    head's half is one or two rows tall and its area doubles between frames (vehicle-road seed
    1 head 97 at 47 m: 10 x 1 px then 10 x 2 px; merged 24 x 2 px), so the area tests threw its
    blobs out as "another light's" and the pair lost it at 45-60 m. By width a blob may be
    larger than the area test allows, never smaller (a blob cut by a clock edge, 1-2 rows of
    a 5-row head, must not become the emitter's envelope: its area then shrank the baseline).
    measure_baseline [True]: a jumper pair re-measures its baseline in one frame, free of the
    shake: a merged blob's width less one emitter's (holds for 5-6-row heads of the `vehicle`
    scene too), or both emitters' own blobs; blended by baseline_gain [0.5], measurements off
    by more than baseline_max_ratio [1.5] ignored, grown between measurements by the smoothed
    relative growth per frame (growth_gain [0.2], 0 to max_growth [0.08] per frame, over at
    most growth_span_frames [8]: heads approach; without growth recordings/vehicle SL 650 ->
    599, with shrinking allowed `synth vehicle --seed 4` 843 -> 798) (`Pairer._measure_baseline`;
    the founding jumps' baseline scaled by the area was 20-40 % short on vehicle-road).
    anchor_coast_frames [5]: a decoded
    jumper pair that coasted this many frames may sit a baseline aside (a single half's blob
    cannot tell which half it is; vehicle-road seed 1 head 74 at 126 m, 0.5 px^2 halves, after
    5 dark frames: its second emitter was matched to the head 10 px below): its emitters are
    not reported until a blob both lit, or both halves in one frame, places it (`Pair.anchored`,
    `Pairer.emitters`; 0 = off; vehicle-road 4 / 0 -> 0 / 0 wrong, `synth vehicle --seed 4` SL
    859 -> 857, 3: 817). beside_hold [True]: a decoded jumper pair
    that explained no blob in this frame is not reported when a blob no pair explains (a third
    of one emitter's size up to max_merged of it) lies outside its span, within its baseline
    plus match_min_px of its end emitter, level with it: most likely its own head's half that
    the gate missed, the pair sitting beside its head (`Pair.beside`, `Pairer._mark_beside`).
    vehicle-road seed 3 frame 125: head 17's pair (3 px baseline, its head's 3.9) sat 2 px
    right of it and missed the left half 2.5 px beyond emitter A; emitter B, reported, was
    matched to head 62's emitter (62 coasting, unreported): 1 wrong -> 0. Cost (S2-PSK
    resolvable SL light-frames, before -> after, with unseen_give_up_frames 30): vehicle-road
    seeds 1/2/3 383/560/541 -> 380/560/541, hil --mode s2psk seeds 1-4 894/878/890/883 ->
    894/875/889/880, recordings/vehicle 652 unchanged; vehicle-road seed 4 wrong 2 -> 1. Any unexplained blob beside either emitter (inside the
    span too, any size): recordings/vehicle 642, hil seeds 1-4 883/865/878/869.
    Measured together (`occloc eval` S2-PSK resolvable SL / FV light-frames, 0 wrong everywhere;
    before -> after): vehicle-road seeds 1 / 2 SL 98 / 14 -> 333 / 551 of 644 / 638, FV 136 /
    166 -> 136 / 164 of 287 / 284; recordings/vehicle SL 646 -> 650 of 658, FV 156 / 156, HV
    filtered 2D median 0.05 m; hil --mode s2psk seeds 1-4 SL 884 / 868 / 882 / 854 -> 892 / 876
    / 889 / 857, FV 216 / 214 / 214 / 214 unchanged. Alone: shake "pairs" without the width and
    baseline changes vehicle-road SL 0 / 5 (it needs pairs that keep their heads); width and
    baseline with "vertical" 89 / 16; with the truth's frame shift (a diagnosis only) 496 / 508.
        """

    row_band: float = 1.0
    max_area_ratio: float = 2.5
    min_baseline: float = 1.2
    max_baseline: float = 25.0
    min_frames: int = 4
    min_swing: float = 20.0
    match_frac: float = 0.75
    match_min_px: float = 3.0
    match_size: float = 1.5
    merged_ratio: float = 1.5
    max_merged: float = 3.0
    max_cut: float = 3.0
    miss_growth_px: float = 1.0
    velocity_gain: float = 0.3
    max_missed: int = 10
    give_up_frames: int = 200
    unseen_give_up_frames: int = 60
    jump_max_baseline: float = 4.0
    jump_agree: float = 0.5
    jump_agree_y_px: float = 4.0
    shake_min_pairs: int = 3
    shake: str = "pairs"
    shake_radius_px: float = 14.0
    shake_x_wide: bool = False
    shake_sigma_px: float = 1.5
    shake_step_px: float = 0.25
    shake_zero_rel: float = 0.15
    report_coast_frames: int = 3
    backlog_frames: int = 90
    flux_jumpers: bool = True
    flux_margin_px: float = 10.0
    flux_margin_y_px: float = 2.0
    flux_floor: float = 2.0
    flux_min: float = 4.0
    flux_recent: int = 12
    drop_twins: bool = True
    follow_size: bool = True
    jumper_levels_min_area_px: float = 16.0
    head_backlog: bool = True
    head_follow: float = 0.2
    head_gap_frames: int = 4
    emitter_gate_larger: bool = True
    jumper_unseen_frames: int = 12
    width_size: bool = True
    width_tol: float = 0.25
    width_min_px: float = 2.0
    width_max_rows: int = 3
    measure_baseline: bool = True
    baseline_gain: float = 0.5
    baseline_max_ratio: float = 1.5
    growth_gain: float = 0.2
    growth_span_frames: int = 8
    max_growth: float = 0.08
    anchor_coast_frames: int = 5
    beside_hold: bool = True
