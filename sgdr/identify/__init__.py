"""Identification by differentiable rendering (stage "optimise"): the appearance refined at the
skinned positions (`appearance`), the initial velocity from the free-fall frames (`velocity`),
the physical parameters from the whole fit window (`dynamics`); Adam helpers (`adam`) and the
targets, posed Gaussians and renders they share (`common`)."""
