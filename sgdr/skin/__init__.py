"""Skinning (stage "skin"): Gaussians follow the anchors by inverse-distance weighting over
their n_b nearest anchors (Eq. 14), or by the displacement form; built once at rest."""

from sgdr.skin.binding import BINDING_FORMS, IDWBinding, idw_weights

__all__ = ["BINDING_FORMS", "IDWBinding", "idw_weights"]
