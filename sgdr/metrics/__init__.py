"""Evaluation metrics: Chamfer distance, EMD, PSNR, SSIM (as DESIGN.md defines them)."""
