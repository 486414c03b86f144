"""3D Gaussians: the appearance model, PLY import/export and the static fit.

`fit_static` lives in `sgdr.static_fit.fit` (it uses the renderer, which uses this
package, so it is not re-exported here).
"""

from sgdr.gaussians.model import Gaussians, GaussiansError
from sgdr.gaussians.ply import load_ply, save_ply

__all__ = ["Gaussians", "GaussiansError", "load_ply", "save_ply"]
