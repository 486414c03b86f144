"""Differentiable Gaussian splatting (Eqs. 1-3) as a Dr.Jit program (stage "render"); the image
losses that compare its output with the targets are `sgdr.loss`."""

from sgdr.render.splat import RenderError, RenderOutput, render

__all__ = ["RenderError", "RenderOutput", "render"]
