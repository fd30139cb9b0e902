"""Rendered frames stored by a hash of everything that makes them: the scene builder and its
keywords, the scene and noise seeds, the frame count, and the source of the renderer and of the
builder (so an edit of `tools/synth` or of the experiment's scene builder never reuses a stale
render; editing another builder keeps the others' renders).

A render is one .npz: `frames` (N, H, W) uint8 and `truth` (the renderer's truth lines as one JSON
text). Files are written to a temporary sibling and renamed, so parallel workers never read half
a file.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field

import numpy as np

_SOURCE_DIRS = ("tools/synth",)
_source_digest: str | None = None


def default_cache_dir() -> str:
    """~/.cache/occloc/experiments (XDG_CACHE_HOME respected)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "occloc", "experiments")


def source_digest() -> str:
    """sha1 over the renderer's source files (tools/synth/*.py)."""
    global _source_digest
    if _source_digest is None:
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        h = hashlib.sha1()
        paths = []
        for d in _SOURCE_DIRS:
            folder = os.path.join(root, d)
            paths += [os.path.join(folder, n) for n in sorted(os.listdir(folder)) if n.endswith(".py")]
        for p in sorted(paths):
            with open(p, "rb") as f:
                h.update(os.path.relpath(p, root).encode() + b"\0" + f.read())
        _source_digest = h.hexdigest()
    return _source_digest


@dataclass(frozen=True)
class SceneSpec:
    """One render: `builder` is a tools.synth scene name or a builder of
    `tools.experiments.scenes.BUILDERS`; `kwargs` its keyword overrides (sorted (key, value)
    pairs, values JSON-able); `scene_seed` fixes the scene's random choices, `noise_seed` the
    sensor noise; `n_frames` frames from frame 0."""

    builder: str
    kwargs: tuple = ()
    scene_seed: int = 0
    noise_seed: int = 0
    n_frames: int = 30

    @staticmethod
    def of(builder: str, *, scene_seed: int = 0, noise_seed: int = 0, n_frames: int = 30, **kwargs) -> "SceneSpec":
        return SceneSpec(builder, tuple(sorted(kwargs.items())), int(scene_seed), int(noise_seed), int(n_frames))

    def key(self) -> str:
        from tools.experiments.scenes import builder_source
        text = json.dumps([self.builder, [list(kv) for kv in self.kwargs], self.scene_seed, self.noise_seed,
                           self.n_frames, source_digest(), builder_source(self.builder)], sort_keys=True,
                          default=list)
        return hashlib.sha1(text.encode()).hexdigest()[:20]

    def scene(self):
        from tools.experiments.scenes import build_scene
        return build_scene(self.builder, self.scene_seed, self.n_frames, dict(self.kwargs))


@dataclass
class Cache:
    """Renders on disk under `folder` (None: no caching). `hits`, `misses`: counts of this process."""

    folder: str | None
    hits: int = 0
    misses: int = 0
    _mem: dict = field(default_factory=dict)

    def render(self, spec: SceneSpec):
        """(scene, frames (N, H, W) uint8, truth list of dicts) of `spec`."""
        from tools.synth import render_frames

        scene = spec.scene()
        path = None if self.folder is None else os.path.join(self.folder, spec.key() + ".npz")
        if path is not None and os.path.exists(path):
            try:
                with np.load(path) as z:
                    frames, truth = z["frames"], json.loads(str(z["truth"]))
                self.hits += 1
                return scene, frames, truth
            except (OSError, ValueError, KeyError, EOFError):
                pass  # a damaged file is rendered again
        self.misses += 1
        imgs, truth = [], []
        for img, t in render_frames(scene, seed=spec.noise_seed):
            imgs.append(img)
            truth.append(t)
        frames = np.stack(imgs) if imgs else np.zeros((0, scene.camera.height, scene.camera.width), np.uint8)
        if path is not None:
            os.makedirs(self.folder, exist_ok=True)
            tmp = f"{path}.{os.getpid()}.tmp.npz"
            np.savez_compressed(tmp, frames=frames, truth=np.array(json.dumps(truth)))
            os.replace(tmp, path)
        return scene, frames, truth
