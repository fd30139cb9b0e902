"""Hardware in the loop: LED driver -> serial protocol -> synthetic camera -> receiver.

`occloc hil` closes the loop through the real serial protocol (INTERFACES.md):

1. By default starts `python -m firmware_tx` on a pseudo-terminal (`--port` drives a real
   board instead).
2. For every light of a synthetic scene, configures the driver with the same command plan
   `occloc tx --mode M --id N --rate R --start --dump K` sends, and reads back the emitted
   stream (`DUMP`): OOK chips or S2-PSK symbols from a packet start.
3. Rebuilds each light's drive waveform from that read-back stream (not from the scene's
   own encoder), renders the scene through the synthetic camera and runs the receiver.
   The driver is then put back as it was found (`STATUS` before: mode, ID and rate of each
   mode the test touched, symbol clock, running or stopped).
4. Reports, per configured ID that came into view, whether and when it came back, and
   every wrong ID. Exit status 0 only when every *resolvable* ID came back and none was wrong.

Resolvable: OOK, every light in view (the walk's panels are hundreds of pixels). S2-PSK needs
one whole 30-symbol packet (2.4 s at 200 Hz / 16 clocks) of frames in which the two emitters
are told apart: both in view with at least `MIN_EMITTER_AREA_PX` and `MIN_SEPARATION_PX`
apart, for `packet frames + 1` frames in a row. The vehicle scene also holds street lights
hundreds of metres away that are in the frustum but one or two pixels large; they are
reported, not required. The S2-PSK default of `S2PSK_DEFAULT_FRAMES` frames holds two
packets (30 frames, the OOK default, is less than half of one); `--scene vehicle-road` (the
realistic road: heads as horizontal panels facing down, pitch and yaw shake, occluding FVs)
renders its whole 240 frames by default.

S2-PSK also reports the LED-frame score of `occloc eval` (receiver.evaluate.metrics
`s2psk_resolvable`): of the light-frames whose whole preceding packet had both emitters >= 1 px
large and >= 4 px apart, the share that carry the right ID, SL and FV separately; the run
passes only when both shares are at least `MIN_RESOLVABLE_RATE` and no ID is wrong.

One driver serves all lights in turn: what is checked is that the stream the driver emits
for each configuration is what the receiver decodes.
"""

from __future__ import annotations

import argparse
import json
import sys

from firmware_tx.framing import OOK_PACKET_LEN, S2PSK_PACKET_LEN
from firmware_tx.schedule import Schedule, s2psk_levels
from receiver.core.errors import InputError

HELP = "hardware-in-the-loop: configure an LED driver over serial, render its stream, decode it"

SCENE_BY_MODE = {"ook": "indoor-walk", "s2psk": "vehicle"}
SCENES_BY_MODE = {"ook": ("indoor-walk",), "s2psk": ("vehicle", "vehicle-road")}
SCENE_FRAMES = {"vehicle-road": 240}
# Required share of the resolvable S2-PSK light-frames that carry the right ID (SL and FV each).
MIN_RESOLVABLE_RATE = 0.95
DUMP_UNITS = {"ook": OOK_PACKET_LEN, "s2psk": S2PSK_PACKET_LEN}
DEFAULT_FRAMES = {"ook": 30, "s2psk": 180}
S2PSK_DEFAULT_FRAMES = DEFAULT_FRAMES["s2psk"]
# An S2-PSK emitter pair is resolvable in a frame when both emitters are at least this large (px)
# and their centres this far apart (px).
MIN_EMITTER_AREA_PX = 4.0
MIN_SEPARATION_PX = 4.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", help="serial port URL of a real driver (default: python -m firmware_tx on a pty)")
    parser.add_argument("--mode", choices=sorted(SCENE_BY_MODE), default="ook",
                        help="ook: indoor walk scene; s2psk: vehicle scene (default ook)")
    parser.add_argument("--scene", default=None,
                        help="synthetic scene (default: indoor-walk for ook, vehicle for s2psk; s2psk "
                             "also takes vehicle-road)")
    parser.add_argument("--frames", type=int, default=None,
                        help="frames to render (default 30 for ook, 180 = two packets for s2psk, "
                             "240 for vehicle-road)")
    parser.add_argument("--seed", type=int, default=1, help="scene and render seed (default 1)")
    parser.add_argument("--timeout", type=float, default=2.0, help="serial reply timeout, seconds")


def tx_commands(port: str, mode: str, led_id: int, rate_hz: int, symclk: int | None) -> list[str]:
    """The command lines `occloc tx` sends for this configuration (same parser, same plan)."""
    from receiver.cli import tx as txhost

    parser = argparse.ArgumentParser()
    txhost.add_arguments(parser)
    argv = ["--port", port, "--mode", mode, "--id", str(led_id), "--rate", str(rate_hz)]
    if symclk is not None:
        argv += ["--symclk", str(symclk)]
    argv += ["--start", "--dump", str(DUMP_UNITS[mode])]
    return txhost.plan_commands(parser.parse_args(argv))


def parse_dump(reply: str, n: int) -> bytearray:
    """Stream units of an `OK DUMP <n> <bits>` reply."""
    parts = reply.split()
    if len(parts) != 4 or parts[:2] != ["OK", "DUMP"] or parts[2] != str(n) or len(parts[3]) != n \
            or set(parts[3]) - {"0", "1"}:
        raise InputError(f"driver sent a malformed DUMP reply: {reply[:60]!r}")
    return bytearray(int(c) for c in parts[3])


def schedule_from_dump(mode: str, units: bytearray, rate_hz: int, symclk: int) -> Schedule:
    """Drive schedule rebuilt from what the driver reported it emits (PROTOCOL.md 2-3)."""
    if mode == "ook":
        return Schedule("ook", rate_hz, bytearray(units), 1, units, 1)
    return Schedule("s2psk", 2 * rate_hz, s2psk_levels(units, symclk), 2, units, 2 * symclk)


def configure_lights(client, port: str, scene, mode: str) -> dict[int, bytearray]:
    """Configure the driver for each light of `mode`, read its stream back and swap the
    light's drive for one built from the read-back stream. Returns id -> dumped units."""
    from tools.synth.waveform import LedDrive

    dumps = {}
    for light in scene.lights:
        if light.mode != mode:
            continue
        # The scene's own configuration of this light (vehicles are not in the map).
        own = light.emitters[0].drive.schedule
        rate = own.tick_hz if mode == "ook" else own.tick_hz // 2
        symclk = own.ticks_per_unit // 2 if mode == "s2psk" else None
        reply = ""
        for line in tx_commands(port, mode, light.id, rate, symclk):
            reply = client.command(line)
        units = parse_dump(reply, DUMP_UNITS[mode])
        sched = schedule_from_dump(mode, units, rate, symclk or 16)
        for pin, emitter in enumerate(light.emitters):
            old = emitter.drive
            emitter.drive = LedDrive(sched, pin=pin, phase_s=old.phase_s,
                                     clock_ppm=(old.clock_scale - 1.0) * 1e6)
        dumps[light.id] = units
    client.command("STOP")
    return dumps


def parse_status(reply: str) -> dict:
    """{'mode', 'id', 'rate', 'symclk', 'running'} of an `OK STATUS mode=M id=N ...` reply."""
    parts = reply.split()
    try:
        if parts[:2] != ["OK", "STATUS"]:
            raise ValueError
        kv = dict(p.split("=", 1) for p in parts[2:])
        return {"mode": kv["mode"], "id": int(kv["id"]), "rate": int(kv["rate"]), "symclk": int(kv["symclk"]),
                "running": kv["running"] == "1"}
    except (ValueError, KeyError):
        raise InputError(f"driver sent a malformed STATUS reply: {reply[:60]!r}") from None


def driver_state(client, mode: str) -> list[dict]:
    """The driver's state as found: its current mode's STATUS, then (when the test's `mode` is
    another) that mode's ID and rate, which the test overwrites too (the driver keeps one ID and
    rate per mode). `restore_driver` puts them back."""
    found = parse_status(client.command("STATUS"))
    states = [found]
    label = mode.upper()
    if found["mode"] != label:
        client.command(f"MODE {label}")
        states.insert(0, parse_status(client.command("STATUS")))
        client.command(f"MODE {found['mode']}")
    return states


def restore_driver(client, states: list[dict]) -> None:
    """Each saved mode's ID and rate, the found mode last (with its symbol clock), and the
    waveform running or stopped as it was."""
    for st in states:
        client.command(f"MODE {st['mode']}")
        client.command(f"ID {st['id']}")
        client.command(f"RATE {st['rate']}")
    found = states[-1]
    client.command(f"SYMCLK {found['symclk']}")
    client.command("START" if found["running"] else "STOP")


def run_loop(client, port: str, mode: str = "ook", frames: int = 30, seed: int = 1,
             progress=None, scene_name: str | None = None) -> dict:
    """Configure, render and decode; returns the report (see module docstring)."""
    from receiver.evaluate.metrics import s2psk_packet_s, s2psk_resolvable
    from receiver.io.output import frame_record
    from receiver.io.truth import run_frame, truth_frame
    from receiver.pipeline import Receiver
    from receiver.core.records import Frame
    from tools.synth import make_scene, render_frames

    scene_name = scene_name or SCENE_BY_MODE[mode]
    if scene_name not in SCENES_BY_MODE[mode]:
        raise InputError(f"--scene {scene_name} has no {mode} lights (choose from "
                         f"{', '.join(SCENES_BY_MODE[mode])})")
    scene = make_scene(scene_name, seed=seed, n_frames=frames)
    truth_frames: dict[int, dict] = {}
    run_frames: list[dict] = []
    saved = driver_state(client, mode)
    try:
        dumps = configure_lights(client, port, scene, mode)
    finally:
        restore_driver(client, saved)   # the driver is left as it was found
    rx = Receiver(scene.camera, scene.led_map)
    first_seen: dict[int, int] = {}
    first_decoded: dict[int, int] = {}
    wrong: list[dict] = []
    run: dict[int, int] = {}   # current run of resolved frames per ID
    runs: dict[int, int] = {}  # longest such run
    for img, truth in render_frames(scene, seed=seed):
        k = truth["frame"]
        for led in truth["leds"]:
            if led.get("visible") and led["id"] in dumps:
                first_seen.setdefault(led["id"], k)
            ok = led["id"] in dumps and resolved_in_frame(led, mode)
            run[led["id"]] = run.get(led["id"], 0) + 1 if ok else 0
            runs[led["id"]] = max(runs.get(led["id"], 0), run[led["id"]])
        result = rx.process(Frame(k, truth["t"], img))
        if mode == "s2psk":
            truth_frames[k] = truth_frame(truth)[1]
            run_frames.append(run_frame(frame_record(result)))
        for obs in result.leds:
            if obs.id is None:
                continue
            if obs.id in dumps and obs.id in first_seen:
                first_decoded.setdefault(obs.id, k)
            elif obs.id not in dumps:
                wrong.append({"frame": k, "id": obs.id})
        if progress:
            progress(k + 1, frames)
    ids = sorted(first_seen)
    need = packet_frames(scene) + 1 if mode == "s2psk" else 1
    per_id = [{"id": i, "stream": "".join(map(str, dumps[i])), "first_in_view": first_seen[i],
               "decoded_at": first_decoded.get(i), "resolvable": runs.get(i, 0) >= need} for i in ids]
    back = sum(1 for r in per_id if r["decoded_at"] is not None)
    resolvable = [r for r in per_id if r["resolvable"]]
    back_res = sum(1 for r in resolvable if r["decoded_at"] is not None)
    ok = back_res == len(resolvable) and not wrong and len(resolvable) > 0
    led_frames = None
    if mode == "s2psk":
        led_frames = s2psk_resolvable(run_frames, truth_frames, packet_s=s2psk_packet_s(scene.led_map) or 2.4)
        ok = ok and led_frames["wrong_ids"] == 0 and all(
            led_frames[k]["rate"] is None or led_frames[k]["rate"] >= MIN_RESOLVABLE_RATE for k in ("SL", "FV"))
    return {"mode": mode, "scene": scene_name, "frames": frames, "configured": len(dumps), "in_view": len(ids),
            "came_back": back, "resolvable": len(resolvable), "came_back_resolvable": back_res,
            "wrong_ids": wrong, "ids": per_id, "resolvable_led_frames": led_frames, "ok": ok}


def packet_frames(scene) -> int:
    """Frames one S2-PSK packet lasts in `scene` (the slowest pair of its map)."""
    import math
    longest = max((S2PSK_PACKET_LEN * (led.symbol_clocks or 16) / (led.rate_hz or 200.0)
                   for led in scene.led_map.by_mode("s2psk")), default=0.0)
    return math.ceil(longest * scene.camera.fps)


def resolved_in_frame(led: dict, mode: str) -> bool:
    """Can the receiver tell this truth LED apart in this frame (see module docstring)?"""
    if not led.get("visible"):
        return False
    em = led.get("emitters")
    if mode != "s2psk" or not em:
        return True
    if len(em) != 2 or not all(e.get("visible") and e.get("area_px", 0.0) >= MIN_EMITTER_AREA_PX for e in em):
        return False
    return ((em[0]["cx"] - em[1]["cx"]) ** 2 + (em[0]["cy"] - em[1]["cy"]) ** 2) ** 0.5 >= MIN_SEPARATION_PX


def main(args: argparse.Namespace) -> int:
    from receiver.io.txlink import TxClient, VirtualDriver, wait_for_driver

    scene = getattr(args, "scene", None) or SCENE_BY_MODE[args.mode]
    if scene not in SCENES_BY_MODE[args.mode]:
        raise InputError(f"--scene {scene} has no {args.mode} lights (choose from "
                         f"{', '.join(SCENES_BY_MODE[args.mode])})")
    if args.frames is None:
        args.frames = SCENE_FRAMES.get(scene, DEFAULT_FRAMES[args.mode])
    if args.frames <= 0:
        raise InputError("--frames must be positive")
    if not 0 <= args.seed < 2 ** 32:  # numpy seeds are non-negative; checked before any driver starts
        raise InputError(f"--seed must be within 0..{2 ** 32 - 1}, not {args.seed}")
    if not (args.timeout > 0 and args.timeout <= 3600):
        raise InputError(f"--timeout must be within 0..3600 s, not {args.timeout}")

    tty = sys.stderr.isatty()

    def progress(done, total):
        if tty:
            print(f"\rhil: frame {done}/{total}", end="" if done < total else "\n", file=sys.stderr)
        elif done % 10 == 0 or done == total:
            print(f"hil: frame {done}/{total}", file=sys.stderr)

    driver = None if args.port else VirtualDriver()
    port = args.port or driver.port
    try:
        with TxClient(port, timeout_s=args.timeout) as client:
            pong = wait_for_driver(client)
            print(f"hil: driver on {port}: {pong}", file=sys.stderr)
            report = run_loop(client, port, args.mode, args.frames, args.seed, progress, scene_name=scene)
    finally:
        if driver is not None:
            driver.close()
    print(json.dumps(report))
    print(f"hil: {report['came_back_resolvable']}/{report['resolvable']} resolvable IDs came back "
          f"({report['came_back']}/{report['in_view']} of all in view), "
          f"{len(report['wrong_ids'])} wrong IDs -> {'PASS' if report['ok'] else 'FAIL'}", file=sys.stderr)
    lf = report.get("resolvable_led_frames")
    if lf is not None:
        print("hil: resolvable light-frames with the right ID: " + ", ".join(
            f"{k} {lf[k]['right']}/{lf[k]['qualifying']}" for k in ("SL", "FV"))
            + f"; {lf['wrong_ids']} wrong (need >= {100 * MIN_RESOLVABLE_RATE:g} % each)", file=sys.stderr)
    return 0 if report["ok"] else 1
