"""The asset: what a finished reconstruction is and what it predicts.

- `store`: `Asset` and its folder (`save_asset`, `load_asset`).
- `predict`: `physical_params` (the simulator's parameters from identified values) and `predict`
  (the rollout and renders of every frame from frame 0).
- `momentum`: the springs' own impulse over a rollout (nothing external acting).
- `whatif`: the asset simulated under edited conditions (`simulate_asset`, `experiments/simulate.py`).
- `config`: `SimulateConfig` (group key `recon.simulate`).
"""
