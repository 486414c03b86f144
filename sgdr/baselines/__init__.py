"""Baselines of the paper's tables (issue 16), each a `method=` choice run by the same pipeline.

- `dyngaus`: Dynamic 3D Gaussians-style per-frame tracking (Luiten et al.), SIMPLIFIED;
- `deform4d`: 4D Gaussian Splatting-style deformation grids (Wu et al.), SIMPLIFIED;
- `common`: the multi-view image loss and the result type they share; `config`: their schema.

Both reconstruct the fit frames only (Table 2: dynamic reconstruction); they predict no future.
"""
