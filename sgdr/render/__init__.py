"""Differentiable Gaussian splatting (Eqs. 1-3) and image losses, as Dr.Jit programs."""

from sgdr.loss import dssim, image_loss, l1, mask_loss, ssim
from sgdr.render.splat import RenderError, RenderOutput, render

__all__ = ["RenderError", "RenderOutput", "render", "l1", "ssim", "dssim", "image_loss", "mask_loss"]
