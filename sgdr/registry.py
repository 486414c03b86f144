"""The one registry of sgdr's swappable parts: a name from the config -> an implementation.

Every part that a config key chooses by name (spring law, contact, springs variant, adjoint,
gradient mode, anchor sampler, IDW binding form, reconstruction mode, MPM material and
collider, benchmark object, sequence layout, backend, simulate cameras) is a `Registry`
instance next to its implementations:

    CONTACTS = Registry("contact model", "physics.contact", PhysicsInputError)

    @CONTACTS.register("coulomb")
    def contact_coulomb(...): ...

    contact = CONTACTS.get_named(cfg.contact)   # unknown name: error naming the key + choices

A registry is a dict (name -> entry), so `in`, iteration and `.values()` work as usual.
"""

from __future__ import annotations

from collections.abc import Callable


class Registry(dict):
    """name -> entry, with a decorator to register and an error naming the key and the choices."""

    def __init__(self, what: str, setting: str = "", error: type[Exception] = ValueError, entries: dict | None = None):
        """what: what an entry is ("contact model"); setting: the config key that chooses it
        ("physics.contact"); error: the exception raised for an unknown name."""
        super().__init__(entries or {})
        self.what = what
        self.setting = setting
        self.error = error

    def register(self, name: str) -> Callable:
        def deco(fn):
            if name in self:
                raise ValueError(f"{self.what} {name!r} is registered twice")
            self[name] = fn
            return fn

        return deco

    def get_named(self, name: str, setting: str | None = None):
        """The entry called `name`; an unknown name raises `self.error` naming the setting
        (default: the registry's config key) and listing the known names."""
        if name not in self:
            key = setting or self.setting or self.what
            raise self.error(f"{key}={name!r} is not a known {self.what}; choose from {sorted(self)}")
        return self[name]
