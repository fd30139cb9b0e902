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


def settings_from_json(cls, obj, where: str = "settings"):
    """The `cls` settings record of `settings_json`'s output (nested records, tuples from JSON
    lists); fields `obj` leaves out keep their defaults. InputError (one line) on a name the
    record does not have or a value of the wrong shape."""
    import typing

    from receiver.core.errors import InputError

    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected an object of {cls.__name__} fields")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    kw = {}
    for key, value in obj.items():
        if key not in names:
            raise InputError(f"{where}: {cls.__name__} has no setting {key!r}")
        kw[key] = _from_json(hints[key], value, f"{where}.{key}")
    try:
        return cls(**kw)
    except (TypeError, ValueError) as e:
        raise InputError(f"{where}: {e}") from None


def _from_json(tp, value, where: str):
    import typing
    records = [a for a in (typing.get_args(tp) or (tp,)) if dataclasses.is_dataclass(a)]
    if records and isinstance(value, dict):
        return settings_from_json(records[0], value, where)
    if isinstance(value, list):
        return tuple(_from_json(None, v, where) for v in value)
    return value
