"""Spring-mass simulator (Eqs. 5-17 of the seed paper): model, parameters, state, forces,
contact, semi-implicit Euler, rollouts and their gradients.

- `model`: `SpringModel` (static), `PhysParams` (learnable), `SimState` (evolving), `Ground`,
  `build_spring_model`.
- `laws`: the named variants (spring law, symmetric stiffness, soft vector, contact).
- `simulate`: spring forces, `substep`, `simulate_frame`, `rollout`, stability checks, and how
  the rollout is differentiated (module docstring).
- `batched`: S parameter samples of one asset in one program (`batched_rollout`), forward only.
- `reference`: the float64 NumPy reference, for tests and benchmarks only.
"""

from sgdr.physics.config import PhysicsConfig
from sgdr.physics.model import (
    Ground,
    PhysicsInputError,
    PhysParams,
    SimState,
    SpringModel,
    build_spring_model,
    with_masses,
)
from sgdr.physics.simulate import (
    Rollout,
    SimulationUnstable,
    doubled_substeps,
    effective_stiffness,
    rollout,
    simulate_frame,
    stable_substeps,
    substep,
)

__all__ = [
    "Ground",
    "PhysParams",
    "PhysicsConfig",
    "PhysicsInputError",
    "Rollout",
    "SimState",
    "SimulationUnstable",
    "SpringModel",
    "build_spring_model",
    "doubled_substeps",
    "effective_stiffness",
    "rollout",
    "simulate_frame",
    "stable_substeps",
    "substep",
    "with_masses",
]
