"""Scores of a prediction against the sequence's ground truth (DESIGN.md, "Metrics").

Separate scores for the dynamic reconstruction (fit frames 0..n_fit-1, re-simulated from
frame 0) and the future prediction (frames n_fit..n_frames-1):

- geometry: Chamfer distance (x1e3) and EMD between the predicted Gaussian centres and the
  generator's particles (`Sequence.gt_particles`), when the sequence has them;
- images: PSNR and SSIM of every view's render against the ground-truth RGB.

The physics-free baseline (`sgdr.evaluate.baselines`) continues the *reconstructed* centres of
frames n_fit-2 and n_fit-1 without physics. `baseline_future_cd` is the issue's definition:
the better (on the future frames) of "ballistic" and "held still"; every variant's score,
including the constant-velocity extrapolation, is in `baseline_future_cd_by_variant`, and its
per-frame CDs in `per_frame["baseline_cd"][variant]` (None on the fit frames).

The result is strict JSON: a score that cannot be computed is None, never NaN, and
`missing[<key>]` says why (e.g. a sequence without ground-truth particles has no CD).

A method that reconstructs the fit frames only (the Table 2 baselines `dyngaus`, `deform4d`)
is scored with `fit_only` = the reason: its prediction holds the fit frames, the per-frame lists
are None on the future frames, and every future score (the physics-free baseline's included, as
it continues the reconstruction into frames the method does not claim) is None with that reason.
"""

from __future__ import annotations

import math

import numpy as np

from sgdr.evaluate import chamfer_distance, earth_movers_distances, psnr, ssim
from sgdr.evaluate.baselines import BASELINES, ISSUE_BASELINES, physics_free_predictions

NO_GT = "the sequence has no ground-truth particles (gt/)"


def _mean(xs) -> float | None:
    """Mean of the finite entries, None when there are none."""
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.mean(xs)) if xs else None


def evaluate_prediction(
    prediction, seq, with_emd: bool = True, seed: int = 0, workers: int = 0, fit_only: str = ""
) -> dict:
    """All scores as a strict-JSON dict (means, per-frame lists, `missing` reasons).

    prediction: `Prediction` (centres [T, M, 3], images [T, V, H, W, 4] uint8 RGBA); seq: Sequence.
    workers: processes for the per-frame EMDs (`earth_movers_distances`; 0 = every CPU).
    The EMD is computed once per frame, for the prediction only (the baseline is scored by CD).
    fit_only: "" scores every frame; else the reason why only the fit frames are scored (T >= n_fit).
    """
    T = prediction.centres.shape[0]
    n_fit = int(seq.n_fit)
    n_scored = n_fit if fit_only else seq.n_frames
    if T < n_scored:
        raise ValueError(f"evaluate: prediction has {T} frames, expected {n_scored}")
    per_frame: dict[str, list] = {"cd": [], "emd": [], "psnr": [], "ssim": []}
    missing: dict[str, str] = {}
    has_gt = seq.gt_particles(0) is not None
    gts = [seq.gt_particles(f) for f in range(n_scored)] if has_gt else [None] * n_scored
    if has_gt and with_emd:
        per_frame["emd"] = earth_movers_distances(zip(prediction.centres[:n_scored], gts), seed=seed, workers=workers)
    else:
        per_frame["emd"] = [None] * n_scored
    for f in range(n_scored):
        gt = gts[f]
        per_frame["cd"].append(chamfer_distance(prediction.centres[f], gt, seed=seed) if gt is not None else None)
        if prediction.images.size:
            ps, ss = [], []
            for v in range(len(seq.cameras)):
                target = seq.image(v, f)[..., :3]
                pred = prediction.images[f, v, ..., :3].astype(np.float64) / 255.0
                ps.append(psnr(pred, target))
                ss.append(ssim(pred, target))
            per_frame["psnr"].append(_mean(ps))
            per_frame["ssim"].append(_mean(ss))
    why = {
        "cd": None if has_gt else NO_GT,
        "emd": NO_GT if not has_gt else (None if with_emd else "recon.eval_emd is false"),
        "psnr": None if prediction.images.size else "the prediction has no rendered images",
    }
    why["ssim"] = why["psnr"]
    for values in per_frame.values():  # None on the frames not scored (fit_only); an empty list stays empty
        if values:
            values.extend([None] * (seq.n_frames - len(values)))
    fit, fut = slice(0, n_fit), slice(n_fit, seq.n_frames)
    out: dict = {}
    for split, sl in (("fit", fit), ("future", fut)):
        for key in ("cd", "emd", "psnr", "ssim"):
            name = f"{split}_{key}"
            out[name] = _mean(per_frame[key][sl])
            if out[name] is None:
                no_future = split == "future" and sl.start >= sl.stop
                if split == "future" and fit_only and not no_future:
                    missing[name] = fit_only
                else:
                    missing[name] = why[key] or ("the sequence has no future frames" if no_future else "not finite")
    # ---- the physics-free baseline on the future frames
    n_future = seq.n_frames - n_fit
    per_frame["baseline_cd"] = {name: [None] * seq.n_frames for name in BASELINES}
    if has_gt and n_fit >= 2 and n_future > 0 and not fit_only:
        cands = physics_free_predictions(
            prediction.centres[n_fit - 2],
            prediction.centres[n_fit - 1],
            n_future,
            1.0 / float(seq.fps),
            np.asarray(seq.gravity, float),
            np.asarray(seq.ground_point, float),
            np.asarray(seq.ground_normal, float),
        )
        for name, frames in cands.items():
            for k, pts in enumerate(frames):
                per_frame["baseline_cd"][name][n_fit + k] = chamfer_distance(pts, gts[n_fit + k], seed=seed)
        base = {name: _mean(per_frame["baseline_cd"][name][fut]) for name in cands}
        out["baseline_future_cd_by_variant"] = base
        best = min(ISSUE_BASELINES, key=lambda n: math.inf if base[n] is None else base[n])
        out["baseline_future_cd"] = base[best]
        out["baseline_variant"] = best
    else:
        reason = NO_GT if not has_gt else ("fewer than 2 fit frames" if n_fit < 2 else "no future frames")
        reason = fit_only if fit_only and n_future > 0 else reason
        out["baseline_future_cd_by_variant"] = {name: None for name in BASELINES}
        out["baseline_future_cd"] = None
        out["baseline_variant"] = None
        missing["baseline_future_cd"] = reason
    out["per_frame"] = per_frame
    out["missing"] = missing
    return out


def strict_json(obj, missing: dict | None = None, path: str = ""):
    """A copy of `obj` that `json.dumps(..., allow_nan=False)` accepts: NumPy scalars and arrays
    as Python numbers and lists, tuples as lists, and every non-finite float as None, recorded
    in `missing[<dotted path>]` (when given) unless a reason is already there."""
    if isinstance(obj, dict):
        return {k: strict_json(v, missing, f"{path}.{k}" if path else str(k)) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [strict_json(v, missing, f"{path}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        if math.isfinite(obj):
            return float(obj)
        if missing is not None:
            missing.setdefault(path, f"not finite ({float(obj)})")
        return None
    return obj
