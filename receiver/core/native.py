"""Optional compiled kernels (Cython, built by `pip install -e .` from receiver/**/_*.pyx).

A stage imports its kernel module with `load("receiver.vision._edges")` and calls it when the
result is not None; otherwise it runs its pure numpy path, which stays the tested reference the
kernel must equal. `OCCLOC_PURE=1` in the environment forces the pure path everywhere (for A/B
measurements and the equality tests); `OCCLOC_PURE=_pairing,_wire` (module names, without their
package) forces it for those kernels only, to measure what one kernel saves
(`tools/kernel_shares.py`); `status()` says which kernels are in use.

A kernel that is the one implementation of its computation (no numpy twin) is imported with
`require(name)` instead: always used, whatever OCCLOC_PURE says, and an ImportError naming the
build command when it is not built (receiver.vision._pixels, _track, _envelope,
receiver.decode._ook, _pieces, receiver.locate._ranging, _vehicle_pose; the locate stage imports _outline, _pnp, _kalman and
_position directly, for the same reason).

Why Cython (pinned in pyproject.toml's build requirements, modules listed there under
`tool.setuptools.ext-modules`): the remaining cost of a frame is interpreter and numpy dispatch
on small per-LED arrays (thousands of calls per frame), which numpy and OpenCV cannot remove.
numba would compile such loops too, but its import (~0.4 s) and first-call compilation would
break the start-up budget (`occloc --help` <= 0.2 s, a photo command <= 0.6 s). Kernels take
typed memoryviews (no numpy C headers needed at build time).
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType

_LOADED: dict[str, ModuleType | None] = {}

# Kernels that are the one implementation of their computation (no numpy path): OCCLOC_PURE
# does not switch them off, and `tools/kernel_shares` cannot measure them.
ONE_IMPLEMENTATION = ("_pixels", "_ranging", "_track", "_envelope", "_ook", "_pieces", "_vehicle_pose", "_outline", "_pnp", "_kalman", "_position")


def pure_forced() -> bool:
    """True when OCCLOC_PURE=1 asks for the pure numpy paths."""
    return os.environ.get("OCCLOC_PURE", "") == "1"


def _named_pure() -> set[str]:
    """The kernels OCCLOC_PURE names (`_pairing,_wire`); empty for "1" or unset."""
    value = os.environ.get("OCCLOC_PURE", "")
    return set() if value in ("", "1") else {n.strip() for n in value.split(",") if n.strip()}


def load(name: str) -> ModuleType | None:
    """The compiled module `name`, or None (not built, or OCCLOC_PURE forces its pure path)."""
    if pure_forced() or name.rsplit(".", 1)[-1] in _named_pure():
        return None
    if name not in _LOADED:
        try:
            _LOADED[name] = importlib.import_module(name)
        except ImportError:
            _LOADED[name] = None
    return _LOADED[name]


def require(name: str) -> ModuleType:
    """The compiled module `name`, which has no pure path (OCCLOC_PURE does not apply)."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise ImportError(f"the compiled kernel {name} is not built (pip install -e . builds it; "
                          f"tools/dev does it all): {exc}") from None


def kernel_sources() -> list[str]:
    """Module names of every kernel source (receiver/**/_*.pyx) in this checkout."""
    root = Path(__file__).resolve().parents[2]
    return [".".join(p.relative_to(root).with_suffix("").parts)
            for p in sorted((root / "receiver").rglob("_*.pyx"))]


def status() -> str:
    """'native (k of n kernels)', 'pure (OCCLOC_PURE=1, except ...)' or 'pure (no kernels)'."""
    names = kernel_sources()
    if pure_forced():
        return f"pure (OCCLOC_PURE=1, except the one-implementation kernels {', '.join(ONE_IMPLEMENTATION)})"
    if not names:
        return "pure (no kernels)"
    built = sum(load(n) is not None for n in names)
    return f"native ({built} of {len(names)} kernels)"
