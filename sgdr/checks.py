"""Checks of config values, declared next to each config schema and run before any work.

Every config section's module (`sgdr/*/config.py`) has a `CHECKS` table, {field: Check}, with
one entry per field that is not a bool; `sgdr.config.validate(cfg)` applies all of them (and
the cross-field rules of `sgdr.config.RULES`) in well under a second, so a bad value fails
before the first stage, naming its key, instead of minutes later inside a stage.
`tests/test_config_checks.py` fails when a field has no check.

A check is a predicate with the rule it enforces written out (the error message says both
the value and the rule):

    CHECKS = {"n_anchors": at_least(2), "contact": choice("sgdr.physics.laws:CONTACTS")}

Names chosen from a registry are checked against the registry itself (`choice`, imported
lazily so that config modules import nothing heavy), so a newly registered variant is
accepted without touching the checks.
"""

from __future__ import annotations

import importlib
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any


class ConfigError(ValueError):
    """A config value that cannot work; the message names the key, the value and the rule."""


@dataclass(frozen=True)
class Check:
    """`ok(value)` is True when the value is acceptable; `rule` says what is (for the error)."""

    ok: Callable[[Any], bool]
    rule: str | Callable[[], str]  # text, or a function writing it (looked up only for an error)

    def describe(self) -> str:
        return self.rule() if callable(self.rule) else self.rule

    def problem(self, key: str, value: Any) -> str | None:
        """None when `value` passes, else the error line for config key `key`."""
        try:
            passed = bool(self.ok(value))
        except (TypeError, ValueError):
            passed = False
        return None if passed else f"{key}={_show(value)}: {self.describe()}"


def _show(value: Any) -> str:
    return repr(list(value)) if isinstance(value, (list, tuple)) else repr(value)


def _real(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


# ---------------------------------------------------------------------------- numbers
def finite() -> Check:
    return Check(_real, "must be a finite number")


def positive() -> Check:
    return Check(lambda x: _real(x) and x > 0, "must be > 0")


def non_negative(meaning_of_zero: str = "") -> Check:
    extra = f" ({meaning_of_zero})" if meaning_of_zero else ""
    return Check(lambda x: _real(x) and x >= 0, f"must be >= 0{extra}")


def at_least(lo: int | float, meaning: str = "") -> Check:
    extra = f" ({meaning})" if meaning else ""
    return Check(lambda x: _real(x) and x >= lo, f"must be >= {lo}{extra}")


def between(lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> Check:
    """lo <= x <= hi, with either end open when asked."""

    def ok(x) -> bool:
        return _real(x) and (x > lo if lo_open else x >= lo) and (x < hi if hi_open else x <= hi)

    return Check(ok, f"must lie in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}")


def or_none(check: Check, meaning_of_none: str) -> Check:
    """`check`, or None (null in YAML) with the meaning `meaning_of_none`."""
    return Check(lambda x: x is None or check.ok(x), lambda: f"{check.describe()}, or null ({meaning_of_none})")


# ---------------------------------------------------------------------------- lists
def vector(n: int, empty_ok: bool = False, each: Check | None = None) -> Check:
    """A list of n finite numbers (or empty when `empty_ok`), each passing `each` if given."""
    each = each or finite()

    def ok(x) -> bool:
        if not isinstance(x, (list, tuple)):
            return False
        if len(x) == 0:
            return empty_ok
        return len(x) == n and all(each.ok(v) for v in x)

    what = f"a list of {n} numbers, each {_bare(each)}"
    return Check(ok, f"must be {what}" + (", or [] (empty: the default)" if empty_ok else ""))


def list_of(each: Check, min_len: int = 0) -> Check:
    def ok(x) -> bool:
        return isinstance(x, (list, tuple)) and len(x) >= min_len and all(each.ok(v) for v in x)

    length = f"at least {min_len} " if min_len else ""
    return Check(ok, f"must be a list of {length}values, each {_bare(each)}")


def dict_of(each: Check, keys: Check) -> Check:
    """A mapping whose keys pass `keys` and whose values pass `each`."""

    def ok(x) -> bool:
        return isinstance(x, Mapping) and all(keys.ok(k) and each.ok(v) for k, v in x.items())

    return Check(ok, lambda: f"must be a mapping (keys {keys.describe()}; values {each.describe()})")


def _bare(check: Check) -> str:
    """A check's rule without its leading 'must (be)', to nest it in another rule."""
    return check.describe().removeprefix("must ").removeprefix("be ")


# ---------------------------------------------------------------------------- strings
def choice(registry: str | tuple[str, ...], also: tuple[str, ...] = ()) -> Check:
    """One of a registry's names ("module:NAME", imported when checked) or of a fixed tuple,
    plus the extra values `also`."""

    def names() -> list[str]:
        if isinstance(registry, tuple):
            return sorted(registry) + list(also)
        module, attr = registry.split(":")
        return sorted(getattr(importlib.import_module(module), attr)) + list(also)

    def ok(x) -> bool:
        return (isinstance(x, str) or isinstance(registry, tuple)) and x in names()

    return Check(ok, lambda: f"must be one of {names()}")


_FOLDER_NAME = re.compile(r"^[A-Za-z0-9._+-]+$")


def folder_name(empty_ok: bool = True) -> Check:
    """A single folder name (letters, digits, . _ + -; no slash), or "" when `empty_ok`."""

    def ok(x) -> bool:
        return isinstance(x, str) and ((x == "" and empty_ok) or (bool(_FOLDER_NAME.match(x)) and x not in (".", "..")))

    return Check(ok, "must be one folder name of letters, digits, '.', '_', '+', '-' (no '/')")


def non_empty_text() -> Check:
    return Check(lambda x: isinstance(x, str) and x.strip() != "", "must not be empty")


def any_text(what: str) -> Check:
    """Any string (a path, a label); `what` says what it is, for the record of checks."""
    return Check(lambda x: isinstance(x, str), f"must be text ({what})")


# ---------------------------------------------------------------------------- applying
def section_problems(prefix: str, section: Any, checks: dict[str, Check]) -> list[str]:
    """Error lines of one config section (a dataclass instance) against its `CHECKS`."""
    out = []
    for name, check in checks.items():
        problem = check.problem(f"{prefix}.{name}" if prefix else name, getattr(section, name))
        if problem:
            out.append(problem)
    return out
