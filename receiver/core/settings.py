"""Settings records: every stage's tunables live in one frozen dataclass (`receiver.vision.settings`,
`receiver.decode.settings`, `receiver.locate.settings`), whose field defaults are the only
defaults; a component takes `settings=` and, for convenience, keyword overrides of its fields.
"""

from __future__ import annotations

import dataclasses

# Largest magnitude of any number in a settings file: above it a value in any unit the settings
# use (px, frames, s, Hz, m, counts) is a typo, and overflows C integers or squares to infinity.
MAX_SETTING_MAGNITUDE = 1e9
# Longest image side in pixels (OpenCV's limit for many functions): a length in pixels beyond
# it bridges or searches more than any frame holds.
MAX_IMAGE_SIDE_PX = 1 << 15


def knob(default, lo=None, hi=None, *, above=None):
    """A settings field whose values from a file (`settings_from_json`) must lie in [lo, hi]
    (None: unbounded on that side), or be over `above` (a spread, which 0 makes singular), for
    a field a zero or a huge value breaks."""
    return dataclasses.field(default=default, metadata={"range": (lo, hi), "above": above})



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
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kw = {}
    for key, value in obj.items():
        if key not in fields:
            raise InputError(f"{where}: {cls.__name__} has no setting {key!r}")
        kw[key] = _from_json(hints[key], value, f"{where}.{key}")
        _check_scalar(hints[key], kw[key], fields[key].default, f"{where}.{key}",
                      fields[key].metadata.get("range", (None, None)), fields[key].metadata.get("above"))
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


def _check_scalar(tp, value, default, where: str, bounds=(None, None), above=None) -> None:
    """InputError unless a number, flag or text setting has its field's type (None where the
    field allows it), is finite, at most MAX_SETTING_MAGNITUDE in size, within the field's
    `knob` bounds, and not negative where the default is not (a count, a length, a time or a
    threshold: a negative one has no meaning). Other fields pass."""
    import math
    import types
    import typing

    from receiver.core.errors import InputError

    args = typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,)
    if not args or not all(a in (int, float, bool, str, type(None)) for a in args):
        return
    if value is None:
        if type(None) not in args:
            raise InputError(f"{where}: a value is needed, not null")
        return
    if isinstance(value, bool):
        ok = bool in args
    elif isinstance(value, int):
        ok = int in args or float in args
    elif isinstance(value, float):
        ok = float in args
    else:
        ok = isinstance(value, str) and str in args
    if not ok:
        want = " or ".join(a.__name__ for a in args if a is not type(None))
        raise InputError(f"{where}: expected {want}, not {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise InputError(f"{where}: must be a finite number, not {value!r}")
        if (isinstance(default, (int, float)) and not isinstance(default, bool) and default >= 0
                and value < 0):
            raise InputError(f"{where}: must not be negative, not {value!r}")
        if abs(value) > MAX_SETTING_MAGNITUDE:
            raise InputError(f"{where}: must be at most {MAX_SETTING_MAGNITUDE:g} in size, not {value!r}")
        lo, hi = bounds
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            span = (f"{lo:g}..{hi:g}" if lo is not None and hi is not None
                    else f"at least {lo:g}" if lo is not None else f"at most {hi:g}")
            raise InputError(f"{where}: must be {span}, not {value!r}")
        if above is not None and not value > above:
            raise InputError(f"{where}: must be over {above:g}, not {value!r}")
