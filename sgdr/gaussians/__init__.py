"""3D Gaussians: the appearance model, PLY import/export and the static fit."""
