"""The static fit (stage "static fit"): 3D Gaussians fitted to the first frame of every view
(`fit.fit_static`, config `static_fit`: `config.StaticFitConfig`). The Gaussian representation
itself and its PLY files are `sgdr.gaussians`."""
