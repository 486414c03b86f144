"""Scores of a prediction against the sequence's ground truth (DESIGN.md, "Metrics").

Separate scores for the dynamic reconstruction (fit frames 0..n_fit-1, re-simulated from
frame 0) and the future prediction (frames n_fit..n_frames-1):

- geometry: Chamfer distance (x1e3) and EMD between the predicted Gaussian centres and the
  generator's particles (`Sequence.gt_particles`), when the sequence has them;
- images: PSNR and SSIM of every view's render against the ground-truth RGB.

The physics-free baseline (`sgdr.evaluate.baselines`) continues the *reconstructed* centres of
frames n_fit-2 and n_fit-1 without physics. `baseline_future_cd` is the issue's definition:
the better (on the future frames) of "ballistic" and "held still"; every variant's score,
including the constant-velocity extrapolation, is in `baseline_future_cd_by_variant`.
"""

from __future__ import annotations

import math

import numpy as np

from sgdr.evaluate import chamfer_distance, earth_movers_distances, psnr, ssim
from sgdr.evaluate.baselines import ISSUE_BASELINES, physics_free_predictions


def _mean(xs) -> float:
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.mean(xs)) if xs else float("nan")


def evaluate_prediction(prediction, seq, with_emd: bool = True, seed: int = 0, workers: int = 0) -> dict:
    """All scores as a JSON-able dict (means and per-frame lists).

    prediction: `Prediction` (centres [T, M, 3], images [T, V, H, W, 3] uint8); seq: Sequence.
    workers: processes for the per-frame EMDs (`earth_movers_distances`; 0 = every CPU).
    The EMD is computed once per frame, for the prediction only (the baseline is scored by CD).
    """
    T = prediction.centres.shape[0]
    n_fit = int(seq.n_fit)
    if T < seq.n_frames:
        raise ValueError(f"evaluate: prediction has {T} frames, the sequence {seq.n_frames}")
    per_frame: dict[str, list] = {"cd": [], "emd": [], "psnr": [], "ssim": []}
    has_gt = seq.gt_particles(0) is not None
    gts = [seq.gt_particles(f) for f in range(seq.n_frames)] if has_gt else [None] * seq.n_frames
    if has_gt and with_emd:
        per_frame["emd"] = earth_movers_distances(
            zip(prediction.centres[: seq.n_frames], gts), seed=seed, workers=workers
        )
    else:
        per_frame["emd"] = [None] * seq.n_frames
    for f in range(seq.n_frames):
        gt = gts[f]
        per_frame["cd"].append(chamfer_distance(prediction.centres[f], gt, seed=seed) if gt is not None else None)
        if prediction.images.size:
            ps, ss = [], []
            for v in range(len(seq.cameras)):
                target = seq.image(v, f)[..., :3]
                pred = prediction.images[f, v].astype(np.float64) / 255.0
                ps.append(psnr(pred, target))
                ss.append(ssim(pred, target))
            per_frame["psnr"].append(_mean(ps))
            per_frame["ssim"].append(_mean(ss))
    fit, fut = slice(0, n_fit), slice(n_fit, seq.n_frames)
    out: dict = {}
    for split, sl in (("fit", fit), ("future", fut)):
        for key in ("cd", "emd", "psnr", "ssim"):
            out[f"{split}_{key}"] = _mean(per_frame[key][sl])
    # ---- the physics-free baseline on the future frames
    n_future = seq.n_frames - n_fit
    if has_gt and n_fit >= 2 and n_future > 0:
        cands = physics_free_predictions(
            prediction.centres[n_fit - 2],
            prediction.centres[n_fit - 1],
            n_future,
            1.0 / float(seq.fps),
            np.asarray(seq.gravity, float),
            np.asarray(seq.ground_point, float),
            np.asarray(seq.ground_normal, float),
        )
        base = {
            name: _mean(chamfer_distance(pts, gts[n_fit + k], seed=seed) for k, pts in enumerate(frames))
            for name, frames in cands.items()
        }
        out["baseline_future_cd_by_variant"] = base
        best = min(ISSUE_BASELINES, key=base.get)
        out["baseline_future_cd"] = base[best]
        out["baseline_variant"] = best
    out["per_frame"] = per_frame
    return out
