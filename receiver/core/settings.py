"""Settings records: every stage's tunables live in one frozen dataclass (`receiver.vision.settings`,
`receiver.decode.settings`, `receiver.locate.settings`), whose field defaults are the only
defaults; a component takes `settings=` and, for convenience, keyword overrides of its fields.
"""

from __future__ import annotations

import dataclasses


def resolve_settings(settings, cls, overrides: dict):
    """`settings` (or `cls()` when None) with `overrides` applied; an unknown name is a
    TypeError, as a wrong keyword argument would be."""
    s = cls() if settings is None else settings
    if not isinstance(s, cls):
        raise TypeError(f"settings must be a {cls.__name__}, not {type(s).__name__}")
    return dataclasses.replace(s, **overrides) if overrides else s


def settings_json(settings) -> dict:
    """A settings record (nested records included) as plain JSON types."""
    return dataclasses.asdict(settings)
