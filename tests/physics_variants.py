"""Every registered simulator variant, read from the registries themselves: a newly registered
spring law, springs variant, symmetric stiffness, contact or adjoint is picked up by the twin,
adjoint and invariant tests without anyone editing a list (and fails them until its NumPy reference
in sgdr/physics/reference.py exists)."""

import itertools

from sgdr.physics.config import PhysicsConfig
from sgdr.physics.laws import CONTACTS, SPRING_LAWS, SPRING_REACTION, SYMMETRIC_STIFFNESS
from sgdr.physics.simulate import ADJOINTS, SPRINGS

LAWS = sorted(SPRING_LAWS)
SPRINGS_VARIANTS = sorted(SPRINGS)
CONTACT_MODELS = sorted(CONTACTS)
ADJOINT_NAMES = sorted(ADJOINTS)
SOFT_VECTOR_FORMS = [True, False]  # physics.soft_vector_normalised: official | paper as printed


def spring_variants():
    """(springs, symmetric_stiffness): every stiffness combination rule for the variants whose
    springs push back on both ends, the default one elsewhere (it is unused there)."""
    default = PhysicsConfig().symmetric_stiffness
    out = []
    for springs in SPRINGS_VARIANTS:
        rules = sorted(SYMMETRIC_STIFFNESS) if SPRING_REACTION.get_named(springs) else [default]
        out += [(springs, rule) for rule in rules]
    return out


def all_variants():
    """(law, springs, symmetric_stiffness, contact, normalised) for every combination."""
    return [
        (law, springs, rule, contact, normalised)
        for law, (springs, rule), contact, normalised in itertools.product(
            LAWS, spring_variants(), CONTACT_MODELS, SOFT_VECTOR_FORMS
        )
    ]


def variant_ids() -> list[str]:
    """Readable test ids for `all_variants()`, in the same order."""
    return [
        "-".join(p if isinstance(p, str) else ("normalised" if p else "printed") for p in v) for v in all_variants()
    ]
