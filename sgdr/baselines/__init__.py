"""The methods the paper compares Spring-Gaus with, in sgdr's engines (docs/baselines.md): the
PAC-NeRF baseline (`pacnerf`: MLS-MPM with one global E and ν). Each is a `recon.model` choice
whose pipeline rows are in `sgdr.pipeline.baselines_flow`; the maths lives here."""
