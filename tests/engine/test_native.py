"""The compiled kernels (receiver/core/native.py): every kernel source is declared in
pyproject.toml, and is built and importable in an installed checkout (a failed build would
otherwise fall back to the pure path silently and every benchmark would measure the wrong code)."""

import re
from pathlib import Path

import pytest

from receiver.core import native

ROOT = Path(__file__).resolve().parents[2]


def _declared() -> dict[str, list[str]]:
    """name -> sources of each [[tool.setuptools.ext-modules]] table (tomllib is 3.11+ only)."""
    text = (ROOT / "pyproject.toml").read_text()
    out = {}
    for block in text.split("[[tool.setuptools.ext-modules]]")[1:]:
        block = block.split("\n[", 1)[0]
        assert len(re.findall(r"^name\s*=", block, re.M)) == 1, f"malformed ext-modules table: {block!r}"
        name = re.search(r'^name\s*=\s*"([^"]+)"', block, re.M)
        sources = re.search(r'^sources\s*=\s*\[([^\]]*)\]', block, re.M)
        assert name and sources, f"malformed ext-modules table: {block!r}"
        out[name.group(1)] = re.findall(r'"([^"]+)"', sources.group(1))
    return out


def test_every_kernel_source_is_declared():
    declared = _declared()
    for name in native.kernel_sources():
        path = name.replace(".", "/") + ".pyx"
        assert declared.get(name) == [path], f"{path} missing from tool.setuptools.ext-modules"
    assert set(declared) == set(native.kernel_sources())


def test_every_kernel_is_built(monkeypatch):
    monkeypatch.delenv("OCCLOC_PURE", raising=False)
    missing = [n for n in native.kernel_sources() if native.load(n) is None]
    assert not missing, f"not built: {missing} (run tools/dev, which reinstalls on a .pyx change)"


def test_pure_forced(monkeypatch):
    monkeypatch.setenv("OCCLOC_PURE", "1")
    assert native.pure_forced()
    assert all(native.load(n) is None for n in native.kernel_sources())
    assert native.status().startswith("pure (OCCLOC_PURE=1, except the one-implementation kernels _pixels, _ranging, _track")


def test_pure_forced_for_named_kernels_only(monkeypatch):
    monkeypatch.setenv("OCCLOC_PURE", "_kalman, _wire")
    assert not native.pure_forced()
    assert native.load("receiver.locate._kalman") is None
    assert native.load("receiver.serve._wire") is None
    assert native.load("receiver.locate._position") is not None


def test_require_ignores_occloc_pure_and_names_the_build_when_missing(monkeypatch):
    monkeypatch.setenv("OCCLOC_PURE", "1")
    kernel = native.require("receiver.locate._vehicle_pose")
    assert kernel.__file__.endswith((".so", ".pyd"))
    with pytest.raises(ImportError, match=r"receiver\.locate\._absent is not built \(pip install -e \."):
        native.require("receiver.locate._absent")


def test_one_implementation_kernels_are_kernels_of_this_checkout():
    names = {n.rsplit(".", 1)[-1] for n in native.kernel_sources()}
    assert set(native.ONE_IMPLEMENTATION) <= names
