"""The methods the paper compares Spring-Gaus with, in sgdr's engines (docs/baselines.md). Each is a
`recon.model` choice whose pipeline rows are in `sgdr.pipeline.baselines_flow`; the maths lives here.

- `pacnerf`: the PAC-NeRF baseline (MLS-MPM with one global E and ν);
- `dyngaus`: Dynamic 3D Gaussians-style per-frame tracking (Luiten et al.), SIMPLIFIED;
- `deform4d`: 4D Gaussian Splatting-style deformation grids (Wu et al.), SIMPLIFIED;
- `common`: the multi-view image loss and the result type dyngaus and deform4d share; `twin`:
  their twins (a cube of Gaussians moved by a known motion); `config`: the schema.

dyngaus and deform4d reconstruct the fit frames only (Table 2: dynamic reconstruction); they
predict no future.
"""
