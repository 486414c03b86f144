"""The benchmark generator: MLS-MPM simulation, procedural objects, Mitsuba ground truth.

- `config`: `SynthConfig` (group key `synth`) and `EffectsConfig` (injected effects).
- `objects`: the seven procedural objects (SDF -> watertight trimesh, volume particles, colours).
- `mpm`: MLS-MPM in Dr.Jit (`MPMModel` / `MPMParams` / `MPMState`, `substep`, `simulate`).
- `linalg`: 3x3 symmetric eigen-decomposition in Dr.Jit (for the plastic return mapping).
- `render_gt`: particles -> marching-cubes surface -> Mitsuba path tracing, RGBA on black.
- `generate`: `generate_sequence(cfg, out_dir, seed)`, one complete sgdr sequence with `gt/`.
"""
