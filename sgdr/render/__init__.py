"""Differentiable Gaussian splatting (Eqs. 1-3) and image losses, as Dr.Jit programs."""
