"""Scoring a run against a recording's `truth.jsonl` (the metrics of `occloc eval`).

Both formats are in INTERFACES.md. Per frame, the run's LEDs are matched to the truth LEDs
that are visible, by nearest image centroid within a gate (one-to-one, closest pairs first);
an S2-PSK truth entry offers its two `emitters` (each with its own cx, cy) as match targets,
because the receiver reports the emitters as separate blobs. From the matches:

* ID rate = matched LED-frames whose decoded ID is the truth ID / all matched LED-frames;
  wrong IDs = matched LED-frames with a decoded ID different from the truth ID (an undecoded
  `id: null` is neither right nor wrong).
* distance error = |d - d_true| / d_true (relative, thesis eq. 18 is evaluated this way in its
  lab experiment), overall, by the run's LED pixel area `area_px` and by the LED's
  `distance_estimator` ("unnamed" when the run does not say).
* position error = 3D Euclidean distance (m) between the run's `position` (filtered) or its
  `position.raw` and the truth camera x, y, z (world frame: x, y on the floor, z up).
* latency p50/p99 over the run's `latency_ms`.
* S2-PSK resolvable ID rate (`s2psk_resolvable`): per truth S2-PSK light and frame, the
  light-frame qualifies when in every truth frame of the packet before it (one 30-symbol
  packet: 2.4 s at 200 Hz / 16 clocks, per light from the map's rate_hz / symbol_clocks), up to
  and including this one, the light is listed with both emitters visible (an occluded emitter
  is not), each of at least `min_area_px` (1 px^2) and `min_separation_px` (4 px) apart; it is
  right when a run LED matched to one of its emitters (the matching above) carries its ID.
  Reported as right / qualifying for SL (IDs 0x00-0x7F) and FV (0x80-0xFF) separately, with
  the S2-PSK wrong IDs: a decoded S2-PSK LED matched to a light of another ID, or unmatched
  with an ID that no S2-PSK light of that frame has.

S2-PSK lights: the run reports each emitter as an LED; both are matched to the truth entry's
emitters and compared against the entry's `distance_m` (the distance to the head or taillight
pair the receiver ranges), one sample per matched emitter-frame, grouped as well by the run's
`kind` ("SL" street light, "FV" taillight). A distance without `area_px` (from a pair's
baseline) counts in the totals, the estimator and the kind, not in the area bins.

Vehicle scenes (`evaluate_vehicle`, only when both the run and the truth carry `vehicle`
objects), in the road frame of the truth (x along the road, y to the left):

* HV: 2D error |(x, y) - truth| and lateral error |y - y_true| (m), over the frames where the run
  has the fix, for the filtered `hv`, its `raw` fix, each raw fix grouped by its `method`, and
  each further `hv_<name>` object (by its `method`, else its name); speed and heading errors of
  the filtered `hv` when both sides give them.
* FV: per frame the run's entries are matched to the truth FVs, by ID when the run has decoded
  one (an ID the truth does not have is unmatched), otherwise by nearest bearing within
  `fv_gate_deg` among the visible truth FVs not yet claimed, one-to-one and closest first.
  Distance relative error overall and by truth distance band, bearing error (deg), and per
  truth FV the time from its first visible truth frame to the first run frame giving it a
  distance.

Plots (thesis Figures 31 and 33) live in `receiver.evaluate.plots`, imported only with `--plot`.
"""

from __future__ import annotations

import math

import numpy as np


# Match gate: a detected centroid farther than this from every visible truth LED is unmatched.
# The walk's LEDs are ~200 px across and centroids agree to ~1 px; blobs clipped by the image
# border move their centroid by tens of px, and those are not counted.
DEFAULT_GATE_PX = 15.0
# LED pixel-area bin edges for the distance error (the "by LED size"; eq. 18 degrades
# as eta, the blob area, gets small).
DEFAULT_AREA_BINS_PX = (400.0, 1600.0, 6400.0)
# FV bearing gate: the two FVs of the synthetic scene are >= 5 deg apart while a tracked pair's
# bearing is good to a fraction of a degree.
DEFAULT_FV_GATE_DEG = 2.0
# FV truth-distance bands (m), the thesis' short / medium / long range (Figures 38-39 span 0-200 m).
DEFAULT_FV_BANDS_M = (25.0, 50.0, 100.0)


# One S2-PSK packet at the protocol defaults (PROTOCOL.md 3): 30 symbols of 16 clocks at 200 Hz.
DEFAULT_S2PSK_PACKET_S = 30 * 16 / 200.0
# The physical bound of the resolvable ID rate: both emitters at least this large and this far apart.
S2PSK_MIN_EMITTER_AREA_PX = 1.0
S2PSK_MIN_SEPARATION_PX = 4.0
FV_ID_MIN = 0x80


# ---------------------------------------------------------------- matching and metrics


def match_leds(run_xy: np.ndarray, truth_xy: np.ndarray, *, gate_px: float = DEFAULT_GATE_PX) -> list:
    """One-to-one nearest-centroid matching: for each run point the truth index or None.

    run_xy (N, 2) and truth_xy (M, 2) are image points in px. Pairs are taken closest first,
    so two blobs near one truth LED cannot both claim it.
    """
    out = [None] * len(run_xy)
    if len(run_xy) == 0 or len(truth_xy) == 0:
        return out
    d = np.hypot(run_xy[:, None, 0] - truth_xy[None, :, 0], run_xy[:, None, 1] - truth_xy[None, :, 1])
    used_t = set()
    for flat in np.argsort(d, axis=None, kind="stable"):
        i, j = divmod(int(flat), d.shape[1])
        if d[i, j] > gate_px:
            break
        if out[i] is None and j not in used_t:
            out[i] = j
            used_t.add(j)
    return out


def s2psk_packet_s(led_map) -> dict[int, float]:
    """ID -> one packet's duration (s) of every S2-PSK light of a receiver.io LedMap (30
    symbols of `symbol_clocks` clocks at `rate_hz`, protocol defaults where the map is silent)."""
    out = {}
    for led in led_map.by_mode("s2psk"):
        out[int(led.id)] = 30 * (led.symbol_clocks or 16) / (led.rate_hz or 200.0)
    return out


def s2psk_qualifying(truth: dict[int, dict], frames, *, packet_s=DEFAULT_S2PSK_PACKET_S,
                     min_area_px: float = S2PSK_MIN_EMITTER_AREA_PX,
                     min_separation_px: float = S2PSK_MIN_SEPARATION_PX) -> dict[int, set]:
    """frame -> IDs of the S2-PSK lights that qualify in it (see the module docstring), for the
    truth frames `frames` (sorted ints; a frame missing from `truth` breaks every run).
    `packet_s`: seconds, one number or {id: seconds} (others: the protocol default)."""
    start: dict[int, float] = {}  # id -> t of the first frame of its current run of good frames
    out: dict[int, set] = {}
    prev = None
    for f in frames:
        tr = truth.get(f)
        if tr is None or tr.get("t") is None or (prev is not None and f != prev + 1):
            start = {}
        prev = f
        if tr is None or tr.get("t") is None:
            out[f] = set()
            continue
        t = tr["t"]
        now = {}
        for led_id, ems in tr.get("s2psk", ()):
            (ax, ay, aa, av), (bx, by, ba, bv) = ems
            if av and bv and aa >= min_area_px and ba >= min_area_px \
                    and math.hypot(bx - ax, by - ay) >= min_separation_px:
                now[led_id] = start.get(led_id, t)
        start = now
        ps = packet_s if not isinstance(packet_s, dict) else None
        out[f] = {i for i, t0 in start.items()
                  if t - t0 >= (ps if ps is not None else packet_s.get(i, DEFAULT_S2PSK_PACKET_S)) - 1e-6}
    return out


def s2psk_resolvable(run: list[dict], truth: dict[int, dict], *, gate_px: float = DEFAULT_GATE_PX,
                     packet_s=DEFAULT_S2PSK_PACKET_S, min_area_px: float = S2PSK_MIN_EMITTER_AREA_PX,
                     min_separation_px: float = S2PSK_MIN_SEPARATION_PX) -> dict:
    """The S2-PSK resolvable ID rate (module docstring) of a run (`load_run` frames) against
    its truth (`load_truth`). Over the truth frames from the run's first to its last (a frame the
    run skipped has no right ID). Returns {"SL": {"right", "qualifying", "rate", "right_any"},
    "FV": ..., "wrong_ids", "packet_s", "min_area_px", "min_separation_px"}; `right_any`: right
    light-frames, qualifying or not."""
    out = {"packet_s": packet_s if not isinstance(packet_s, dict) else
           (sorted(set(packet_s.values())) or [DEFAULT_S2PSK_PACKET_S]),
           "min_area_px": min_area_px, "min_separation_px": min_separation_px, "wrong_ids": 0}
    groups = {k: {"right": 0, "qualifying": 0, "rate": None, "right_any": 0} for k in ("SL", "FV")}
    by_frame = {fr["frame"]: fr for fr in run}
    if not by_frame:
        return {**out, **groups}
    lo, hi = min(by_frame), max(by_frame)
    # Frame numbers are keys: only frames that the truth or the run has count (a frame in
    # neither has nothing to score), so the cost follows the files, not the numbers in them.
    frames = sorted({f for f in truth if lo <= f <= hi} | set(by_frame))
    qual = s2psk_qualifying(truth, frames, packet_s=packet_s, min_area_px=min_area_px,
                            min_separation_px=min_separation_px)
    wrong = 0
    for f in frames:
        tr, fr = truth.get(f), by_frame.get(f)
        right: set = set()
        if tr is not None and fr is not None:
            targets = tr["targets"]
            s2_ids = {i for i, _ in tr.get("s2psk", ())}
            m = match_leds(np.array([(o["cx"], o["cy"]) for o in fr["leds"]]).reshape(-1, 2),
                           np.array([t[:2] for t in targets]).reshape(-1, 2), gate_px=gate_px)
            for o, j in zip(fr["leds"], m):
                if o["id"] is None:
                    continue
                if j is None:
                    wrong += o.get("kind") is not None and o["id"] not in s2_ids
                    continue
                true_id = targets[j][2]
                if o["id"] == true_id:
                    right.add(true_id)
                elif o.get("kind") is not None or true_id in s2_ids:
                    wrong += 1
            for i in right & s2_ids:
                groups["FV" if i >= FV_ID_MIN else "SL"]["right_any"] += 1
        for i in qual.get(f, ()):
            g = groups["FV" if i >= FV_ID_MIN else "SL"]
            g["qualifying"] += 1
            g["right"] += i in right
    for g in groups.values():
        g["rate"] = g["right"] / g["qualifying"] if g["qualifying"] else None
    out["wrong_ids"] = wrong
    return {**out, **groups}


def _stats(values, qs=(50, 95)) -> dict:
    v = np.asarray(values, float)
    out = {"n": int(v.size)}
    for q in qs:
        out[f"p{q}"] = float(np.percentile(v, q)) if v.size else None
    return out


def _bin_label(lo: float, hi: float) -> str:
    if lo == 0:
        return f"<{hi:g}"
    if math.isinf(hi):
        return f">={lo:g}"
    return f"{lo:g}-{hi:g}"


def evaluate(run: list[dict], truth: dict[int, dict], *, gate_px: float = DEFAULT_GATE_PX,
             area_bins_px=DEFAULT_AREA_BINS_PX, fv_gate_deg: float = DEFAULT_FV_GATE_DEG,
             fv_bands_m=DEFAULT_FV_BANDS_M, s2psk_packet_s=DEFAULT_S2PSK_PACKET_S) -> tuple[dict, dict]:
    """(metrics, series). `s2psk_packet_s`: see `s2psk_resolvable` (`s2psk_packet_s(led_map)`
    gives the map's). metrics is JSON-ready (None where undefined, `vehicle` None outside
    vehicle scenes); series holds the per-frame arrays the plots need: t_s (N,),
    true/filtered/raw xyz (N, 3) with nan where the run has no position, their 3D errors (N,),
    per distance sample with an area its area_px and rel. error, and `vehicle` (see
    `evaluate_vehicle`, None outside vehicle scenes)."""
    matched = correct = wrong = run_leds = visible = 0
    dist_area, dist_err, dist_est, dist_kind = [], [], [], []
    n = len(run)
    t_s = np.full(n, np.nan)
    true_xyz, filt_xyz, raw_xyz = (np.full((n, 3), np.nan) for _ in range(3))
    latency = []
    for k, fr in enumerate(run):
        tr = truth[fr["frame"]]
        t_s[k] = fr["t"] if fr["t"] is not None else fr["frame"]
        true_xyz[k] = tr["xyz"]
        if fr["filtered"] is not None:
            filt_xyz[k] = fr["filtered"]
        if fr["raw"] is not None:
            raw_xyz[k] = fr["raw"]
        if fr["latency_ms"] is not None:
            latency.append(fr["latency_ms"])
        targets = tr["targets"]
        run_leds += len(fr["leds"])
        visible += len(targets)
        m = match_leds(np.array([(o["cx"], o["cy"]) for o in fr["leds"]]).reshape(-1, 2),
                       np.array([t[:2] for t in targets]).reshape(-1, 2), gate_px=gate_px)
        for o, j in zip(fr["leds"], m):
            if j is None:
                continue
            _, _, true_id, true_d = targets[j]
            matched += 1
            if o["id"] is not None:
                if o["id"] == true_id:
                    correct += 1
                else:
                    wrong += 1
            if o["distance_m"] is not None and true_d:
                dist_area.append(o["area_px"] if o["area_px"] is not None else math.nan)
                dist_err.append(abs(o["distance_m"] - true_d) / true_d)
                dist_est.append(o["estimator"])
                dist_kind.append(o.get("kind"))
    filt_err = np.linalg.norm(filt_xyz - true_xyz, axis=1)
    raw_err = np.linalg.norm(raw_xyz - true_xyz, axis=1)
    dist_area, dist_err = np.array(dist_area, float), np.array(dist_err, float)

    edges = [0.0, *area_bins_px, math.inf]
    bins = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (dist_area >= lo) & (dist_area < hi)
        bins.append({"area_px": _bin_label(lo, hi), **_stats(dist_err[sel])})
    metrics = {
        "frames": n,
        "frames_with_position": int(np.isfinite(filt_err).sum()),
        "gate_px": gate_px,
        "led_frames": run_leds,
        "visible_truth_led_frames": visible,
        "matched_led_frames": matched,
        "unmatched_led_frames": run_leds - matched,
        "ids_correct": correct,
        "wrong_ids": wrong,
        "undecoded": matched - correct - wrong,
        "id_rate": correct / matched if matched else None,
        "distance_rel_error": {**_stats(dist_err), "by_area_px": bins, "by_estimator": {
            name: _stats(dist_err[np.array(dist_est) == name]) for name in sorted(set(dist_est))},
            "by_kind": {name: _stats(dist_err[np.array(dist_kind, object) == name])
                        for name in sorted({k for k in dist_kind if k is not None})}},
        "position_error_m": {"filtered": _stats(filt_err[np.isfinite(filt_err)]),
                             "raw": _stats(raw_err[np.isfinite(raw_err)])},
        "latency_ms": _stats(latency, qs=(50, 99)),
    }
    vehicle, vehicle_series = evaluate_vehicle(run, truth, fv_gate_deg=fv_gate_deg, fv_bands_m=fv_bands_m)
    metrics["vehicle"] = vehicle
    metrics["s2psk_resolvable"] = (s2psk_resolvable(run, truth, gate_px=gate_px, packet_s=s2psk_packet_s)
                                   if any(tr.get("s2psk") for tr in truth.values()) else None)
    has = np.isfinite(dist_area)
    series = {"t_s": t_s, "true_xyz": true_xyz, "filtered_xyz": filt_xyz, "raw_xyz": raw_xyz,
              "filtered_err_m": filt_err, "raw_err_m": raw_err,
              "dist_area_px": dist_area[has], "dist_rel_err": dist_err[has], "vehicle": vehicle_series}
    return metrics, series


# ---------------------------------------------------------------- vehicle scenes


def _wrap_deg(a):
    """Angle difference folded into [-180, 180) degrees."""
    return (np.asarray(a, float) + 180.0) % 360.0 - 180.0


def match_fvs(run_fv: list[dict], truth_fv: list[dict], *, gate_deg: float = DEFAULT_FV_GATE_DEG) -> list:
    """For each run FV entry (dicts with `id`, `angle_deg`) the index of its truth FV (dicts with
    `id`, `angle_deg`, `visible`) or None, with how it was matched: a list of (index, "id" |
    "bearing") or None.

    A run entry with a decoded ID takes the truth FV of that ID (the first such entry of a frame
    wins; an ID the truth lacks stays unmatched). Entries without an ID are then matched to the
    remaining visible truth FVs by bearing, one-to-one, closest pairs first, within gate_deg.
    """
    out = [None] * len(run_fv)
    used = set()
    by_id = {fv["id"]: j for j, fv in enumerate(truth_fv) if fv["id"] is not None}
    for i, fv in enumerate(run_fv):
        j = by_id.get(fv["id"]) if fv["id"] is not None else None
        if j is not None and j not in used:
            out[i] = (j, "id")
            used.add(j)
    pairs = []
    for i, fv in enumerate(run_fv):
        if fv["id"] is not None or fv["angle_deg"] is None:
            continue
        for j, tf in enumerate(truth_fv):
            if j in used or not tf["visible"] or tf["angle_deg"] is None:
                continue
            d = abs(float(_wrap_deg(fv["angle_deg"] - tf["angle_deg"])))
            if d <= gate_deg:
                pairs.append((d, i, j))
    for _, i, j in sorted(pairs):
        if out[i] is None and j not in used:
            out[i] = (j, "bearing")
            used.add(j)
    return out


def _band_labels(edges_m) -> list[str]:
    edges = [0.0, *edges_m, math.inf]
    return [f">={lo:g}" if math.isinf(hi) else f"{lo:g}-{hi:g}" for lo, hi in zip(edges[:-1], edges[1:])]


def _label_key(label: str):
    """FV labels sorted numerically by ID, the "#index" ones (truth FVs without an ID) last."""
    return (1, label) if label.startswith("#") else (0, int(label))


def _hv_group() -> dict:
    return {"err": [], "lat": []}


def _hv_add(groups: dict, name: str, fix: dict, true_hv: dict, k: int, per_frame: dict | None = None):
    g = groups.setdefault(name, _hv_group())
    dx, dy = fix["x"] - true_hv["x"], fix["y"] - true_hv["y"]
    g["err"].append(math.hypot(dx, dy))
    g["lat"].append(abs(dy))
    if per_frame is not None:
        per_frame.setdefault(name, {})[k] = (fix["x"], fix["y"], math.hypot(dx, dy))


def _hv_summary(g: dict) -> dict:
    return {"frames": len(g["err"]), "error_2d_m": _stats(g["err"]), "lateral_m": _stats(g["lat"])}


def evaluate_vehicle(run: list[dict], truth: dict[int, dict], *, fv_gate_deg: float = DEFAULT_FV_GATE_DEG,
                     fv_bands_m=DEFAULT_FV_BANDS_M) -> tuple[dict | None, dict | None]:
    """(metrics, series) of a vehicle scene, (None, None) unless some run frame has a `vehicle`
    object and some truth frame (of the run's) has one.

    series: `t_s` (N,) over the run's frames (sorted); `hv_true_xy` (N, 2) and `hv` {name: (N, 2)
    x, y} for "filtered", "raw" and "hv_<name>" per further object, with `hv_err_m` {name: (N,)} their 2D
    errors, nan where absent; `fv` {label: {"t_s", "true_m", "run_m"}} per truth FV (label its ID
    or "#index"), (N,) truth distance (nan when not visible) and matched run distance (nan when
    none).
    """
    frames = sorted(run, key=lambda fr: fr["frame"])
    if not any(fr["vehicle"] is not None for fr in frames):
        return None, None
    if not any(truth[fr["frame"]]["vehicle"] is not None for fr in frames):
        return None, None
    n = len(frames)
    t_s = np.array([fr["t"] if fr["t"] is not None else float(fr["frame"]) for fr in frames], float)
    hv_true = np.full((n, 2), np.nan)
    hv_frames = truth_hv_frames = 0
    main = {"filtered": _hv_group(), "raw": _hv_group()}
    by_method, extra = {}, {}
    per_frame, per_extra = {}, {}  # series name -> {row: (x, y, 2D error)}
    speed_err, heading_err = [], []

    fv_err, fv_true_d, fv_bear = [], [], []
    fv_run = fv_matched = fv_by_id = fv_by_bearing = fv_truth_visible = 0
    fv_series = {}
    first_visible, first_distance = {}, {}

    def fv_label(tf, j):
        return str(tf["id"]) if tf["id"] is not None else f"#{j}"

    for k, fr in enumerate(frames):
        tv = truth[fr["frame"]]["vehicle"]
        rv = fr["vehicle"]
        if tv is None:
            continue
        true_hv = tv["hv"]
        if true_hv is not None:
            truth_hv_frames += 1
            hv_true[k] = true_hv["x"], true_hv["y"]
        hv = rv["hv"] if rv is not None else None
        if hv is not None:
            hv_frames += 1
        if true_hv is not None and rv is not None:
            if hv is not None:
                _hv_add(main, "filtered", hv, true_hv, k, per_frame)
                if hv["raw"] is not None:
                    _hv_add(main, "raw", hv["raw"], true_hv, k, per_frame)
                    _hv_add(by_method, hv["raw"]["method"] or "unnamed", hv["raw"], true_hv, k)
                if hv["speed_mps"] is not None and true_hv["speed_mps"] is not None:
                    speed_err.append(abs(hv["speed_mps"] - true_hv["speed_mps"]))
                if hv["heading_deg"] is not None and true_hv["heading_deg"] is not None:
                    heading_err.append(abs(float(_wrap_deg(hv["heading_deg"] - true_hv["heading_deg"]))))
            for name, fix in rv["extra"].items():
                _hv_add(extra, name, fix, true_hv, k, per_extra)
                _hv_add(by_method, fix["method"] or name, fix, true_hv, k)

        truth_fv = tv["fv"]
        for j, tf in enumerate(truth_fv):
            lab = fv_label(tf, j)
            s = fv_series.setdefault(lab, _fv_track(t_s, n))
            if tf["visible"]:
                fv_truth_visible += 1
                s["true_m"][k] = tf["distance_m"] if tf["distance_m"] is not None else np.nan
        run_fv = rv["fv"] if rv is not None else []
        fv_run += len(run_fv)
        for o, m in zip(run_fv, match_fvs(run_fv, truth_fv, gate_deg=fv_gate_deg)):
            if m is None:
                continue
            j, how = m
            tf = truth_fv[j]
            lab = fv_label(tf, j)
            fv_matched += 1
            fv_by_id += how == "id"
            fv_by_bearing += how == "bearing"
            if o["angle_deg"] is not None and tf["angle_deg"] is not None:
                fv_bear.append(abs(float(_wrap_deg(o["angle_deg"] - tf["angle_deg"]))))
            if o.get("ttc_s") is not None:
                fv_series[lab]["ttc_s"][k] = o["ttc_s"]
            if o.get("zone") in FV_ZONES:
                fv_series[lab]["zone"][k] = FV_ZONES.index(o["zone"])
            if o["distance_m"] is not None:
                fv_series[lab]["run_m"][k] = o["distance_m"]
                first_distance.setdefault(lab, fr["frame"])
                if tf["distance_m"]:
                    fv_err.append(abs(o["distance_m"] - tf["distance_m"]) / tf["distance_m"])
                    fv_true_d.append(tf["distance_m"])

    fv_err, fv_true_d = np.array(fv_err, float), np.array(fv_true_d, float)
    edges = [0.0, *fv_bands_m, math.inf]
    bands = [{"band_m": lab, **_stats(fv_err[(fv_true_d >= lo) & (fv_true_d < hi)])}
             for lab, lo, hi in zip(_band_labels(fv_bands_m), edges[:-1], edges[1:])]

    # Time to first distance on the truth's frames between the run's first and last: a run that
    # skipped frames pays for the frames it skipped.
    lo_f, hi_f = frames[0]["frame"], frames[-1]["frame"]
    for f in sorted(f for f in truth if lo_f <= f <= hi_f):
        tv = truth[f]["vehicle"]
        for j, tf in enumerate(tv["fv"] if tv is not None else []):
            if tf["visible"]:
                first_visible.setdefault(fv_label(tf, j), f)
    t_of = {f: tr["t"] for f, tr in truth.items()}
    first = []
    for lab in sorted(set(fv_series) | set(first_visible), key=_label_key):
        fv0, fd = first_visible.get(lab), first_distance.get(lab)
        frames_to = seconds = None
        if fv0 is not None and fd is not None:
            frames_to = fd - fv0
            if t_of.get(fd) is not None and t_of.get(fv0) is not None:
                seconds = t_of[fd] - t_of[fv0]
        first.append({"fv": lab, "first_visible_frame": fv0, "first_distance_frame": fd,
                      "frames": frames_to, "seconds": seconds})

    metrics = {
        "frames_with_hv": hv_frames,
        "truth_frames_with_hv": truth_hv_frames,
        "hv": {name: _hv_summary(g) for name, g in main.items()},
        "hv_by_method": {name: _hv_summary(g) for name, g in sorted(by_method.items())},
        "hv_extra": {name: _hv_summary(g) for name, g in sorted(extra.items())},
        "hv_speed_error_mps": _stats(speed_err),
        "hv_heading_error_deg": _stats(heading_err),
        "fv_gate_deg": fv_gate_deg,
        "fv_run_entries": fv_run,
        "fv_visible_truth_frames": fv_truth_visible,
        "fv_matched": fv_matched,
        "fv_matched_by_id": fv_by_id,
        "fv_matched_by_bearing": fv_by_bearing,
        "fv_unmatched": fv_run - fv_matched,
        "fv_distance_rel_error": {**_stats(fv_err), "by_band_m": bands},
        "fv_bearing_error_deg": _stats(fv_bear),
        "fv_time_to_first_distance": first,
    }
    per_frame.update({f"hv_{name}": rows for name, rows in per_extra.items()})
    hv_xy = {name: np.full((n, 2), np.nan) for name in ("filtered", "raw", *sorted(per_frame))}
    hv_err = {name: np.full(n, np.nan) for name in hv_xy}
    for name, rows in per_frame.items():
        for k, (x, y, e) in rows.items():
            hv_xy[name][k] = x, y
            hv_err[name][k] = e
    series = {"t_s": t_s, "hv_true_xy": hv_true, "hv": hv_xy, "hv_err_m": hv_err, "fv": fv_series}
    return metrics, series


def json_safe(obj):
    """obj with every non-finite float replaced by None (JSON has no NaN) and numpy scalars
    made plain Python numbers."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


# ---------------------------------------------------------------- output


def _fmt(v, scale=1.0, unit="", nd=2) -> str:
    return "-" if v is None else f"{v * scale:.{nd}f}{unit}"


# The run's forward-vehicle zones, least to most urgent (receiver.locate.vehicle.ZONES).
FV_ZONES = ("safe", "min", "critical")


def _fv_track(t_s, n: int) -> dict:
    """One forward vehicle's series: true and run distance (m), the run's time to collision (s)
    and zone (index into FV_ZONES), nan where absent."""
    return {"t_s": t_s, "true_m": np.full(n, np.nan), "run_m": np.full(n, np.nan),
            "ttc_s": np.full(n, np.nan), "zone": np.full(n, np.nan)}


def format_table(m: dict) -> str:
    """The metrics as a readable plain-text table: the rows of the recording's kind (a vehicle
    recording has no indoor position rows unless the run gave positions)."""
    indoor = m.get("vehicle") is None or m["frames_with_position"] > 0
    rows = [
        ("frames", f"{m['frames']} ({m['frames_with_position']} with a position)" if indoor else f"{m['frames']}"),
        ("LED-frames", f"{m['led_frames']} detected, {m['visible_truth_led_frames']} visible in truth, "
                       f"{m['matched_led_frames']} matched (gate {m['gate_px']:g} px)"),
        ("ID rate", f"{_fmt(m['id_rate'], 100, ' %')} ({m['ids_correct']}/{m['matched_led_frames']})"),
        ("wrong IDs", f"{m['wrong_ids']} (undecoded {m['undecoded']})"),
    ]
    de = m["distance_rel_error"]
    rows.append(("distance error", f"median {_fmt(de['p50'], 100, ' %', 3)}  p95 {_fmt(de['p95'], 100, ' %', 3)}"
                                   f"  (n={de['n']})"))
    for b in de["by_area_px"]:
        rows.append((f"  area {b['area_px']} px", f"median {_fmt(b['p50'], 100, ' %', 3)}  "
                                                  f"p95 {_fmt(b['p95'], 100, ' %', 3)}  (n={b['n']})"))
    for name, b in de["by_estimator"].items():
        rows.append((f"  estimator {name}", f"median {_fmt(b['p50'], 100, ' %', 3)}  "
                                  f"p95 {_fmt(b['p95'], 100, ' %', 3)}  (n={b['n']})"))
    for name, b in de.get("by_kind", {}).items():
        rows.append((f"  kind {name}", f"median {_fmt(b['p50'], 100, ' %', 3)}  "
                                       f"p95 {_fmt(b['p95'], 100, ' %', 3)}  (n={b['n']})"))
    for kind in ("filtered", "raw") if indoor else ():
        pe = m["position_error_m"][kind]
        rows.append((f"position {kind}", f"median {_fmt(pe['p50'], 100, ' cm')}  p95 {_fmt(pe['p95'], 100, ' cm')}"
                                         f"  (n={pe['n']})"))
    la = m["latency_ms"]
    rows.append(("latency", f"p50 {_fmt(la['p50'], unit=' ms')}  p99 {_fmt(la['p99'], unit=' ms')}  (n={la['n']})"))
    sr = m.get("s2psk_resolvable")
    if sr is not None:
        # "S2-PSK resolvable ID rate": right / qualifying light-frames (s2psk_resolvable)
        text = "; ".join(f"{kind} {_fmt(sr[kind]['rate'], 100, ' %')} ({sr[kind]['right']}/{sr[kind]['qualifying']}, "
                         f"{sr[kind]['right_any']} right in all)" for kind in ("SL", "FV"))
        rows.append(("S2-PSK resolvable", f"ID rate {text}; wrong {sr['wrong_ids']}"))
    if m.get("vehicle") is not None:
        rows += _vehicle_rows(m["vehicle"])
    width = max(len(r[0]) for r in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _pct(st: dict, nd=3) -> str:
    return f"median {_fmt(st['p50'], 100, ' %', nd)}  p95 {_fmt(st['p95'], 100, ' %', nd)}  (n={st['n']})"


def _hv_row(g: dict) -> str:
    e, lat = g["error_2d_m"], g["lateral_m"]
    return (f"2D median {_fmt(e['p50'], unit=' m')}  p95 {_fmt(e['p95'], unit=' m')}  "
            f"lateral median {_fmt(lat['p50'], unit=' m')}  p95 {_fmt(lat['p95'], unit=' m')}  (n={g['frames']})")


def _vehicle_rows(v: dict) -> list[tuple[str, str]]:
    rows = [("HV frames", f"{v['frames_with_hv']} with a fix, {v['truth_frames_with_hv']} in truth")]
    for name, g in v["hv"].items():
        rows.append((f"HV {name}", _hv_row(g)))
    for name, g in v["hv_by_method"].items():
        rows.append((f"  method {name}", _hv_row(g)))
    for name, g in v["hv_extra"].items():
        rows.append((f"HV hv_{name}", _hv_row(g)))
    for key, label, unit in (("hv_speed_error_mps", "HV speed error", " m/s"),
                             ("hv_heading_error_deg", "HV heading error", " deg")):
        st = v[key]
        if st["n"]:
            rows.append((label, f"median {_fmt(st['p50'], unit=unit)}  p95 {_fmt(st['p95'], unit=unit)}  (n={st['n']})"))
    rows.append(("FV entries", f"{v['fv_run_entries']} in run, {v['fv_visible_truth_frames']} visible in truth, "
                               f"{v['fv_matched']} matched ({v['fv_matched_by_id']} by ID, "
                               f"{v['fv_matched_by_bearing']} by bearing within {v['fv_gate_deg']:g} deg)"))
    de = v["fv_distance_rel_error"]
    rows.append(("FV distance error", _pct(de)))
    for b in de["by_band_m"]:
        rows.append((f"  truth {b['band_m']} m", _pct(b)))
    be = v["fv_bearing_error_deg"]
    rows.append(("FV bearing error", f"median {_fmt(be['p50'], unit=' deg', nd=3)}  "
                                     f"p95 {_fmt(be['p95'], unit=' deg', nd=3)}  (n={be['n']})"))
    for f in v["fv_time_to_first_distance"]:
        if f["first_visible_frame"] is None:
            text = "never visible"
        elif f["frames"] is None:
            text = f"visible from frame {f['first_visible_frame']}, no distance"
        else:
            text = (f"{f['frames']} frames ({_fmt(f['seconds'], unit=' s')}) after first visible "
                    f"(frame {f['first_visible_frame']} -> {f['first_distance_frame']})")
        rows.append((f"FV {f['fv']} first distance", text))
    return rows
