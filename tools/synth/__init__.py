"""Synthetic rolling-shutter camera: renders firmware_tx's real drive waveforms into video.

Usage in tests and notebooks::

    from tools.synth import make_scene, render_frames
    scene = make_scene("indoor-static", seed=1, n_frames=5, read_noise_dn=0.0)
    for img, truth in render_frames(scene, seed=7):   # img: (H, W) uint8 gray
        print(truth["frame"], truth["t"], [(d["id"], d["cx"], d["cy"]) for d in truth["leds"]])

`scene.camera` is a `receiver.io.CameraModel`, `scene.led_map` a `receiver.io.LedMap`.
`tools.synth.recording.write_recording(scene, out_dir, seed=...)` writes a recording folder
(INTERFACES.md). Geometry conventions: `tools.synth.camera`; rendering and truth: `tools.synth.render`.
"""

from tools.synth.render import FrameRenderer, render_frames  # noqa: F401
from tools.synth.scenes import SCENES, make_scene  # noqa: F401
