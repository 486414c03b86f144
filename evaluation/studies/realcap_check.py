"""How well a reconstruction of a simulated real capture recovered the truth (gt/truth.json).

    python -m evaluation.studies.realcap_check outputs/cap_tiny_s0 /tmp/cap

Prints one JSON object:
- registration: rotation error (degrees), relative scale error, and the translation error as the
  displacement of the object's centroid (the truth's frame-0 particles mapped back to the static
  frame, then through the found registration), over the object's size (its bounding-box diagonal
  at frame 0). The plain t of X_d = s R X_s + t is referred to the static frame's origin, which a
  COLMAP frame puts anywhere, so the centroid is where the translation is measured.
- motion: per frame, the error of the predicted centre-of-mass displacement since frame 0 (the
  mean of the predicted Gaussian centres against the mean of the true particles) over the size;
  its mean over the frames after the hit and over all frames, and the same for "hold still"
  (displacement 0), the physics-free baseline.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def check(run_dir, capture) -> dict:
    run_dir, capture = Path(run_dir), Path(capture)
    truth = json.loads((capture / "gt" / "truth.json").read_text())
    reg = json.loads((run_dir / "static" / "registration.json").read_text())
    T = truth["registration"]
    s, R, t = float(T["s"]), np.asarray(T["R"]), np.asarray(T["t"])
    s_e, R_e, t_e = float(reg["s"]), np.asarray(reg["R"]), np.asarray(reg["t"])
    n = int(truth["n_frames"])
    gt = [np.load(capture / "gt" / f"particles_{f:03d}.npy") for f in range(n)]
    size = float(np.linalg.norm(gt[0].max(0) - gt[0].min(0)))
    X_s = ((gt[0] - t) @ R) / s  # the rest shape in the static frame
    X_e = (s_e * X_s) @ R_e.T + t_e
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R_e.T @ R) - 1) / 2, -1, 1))))
    with np.load(run_dir / "predict" / "trajectory.npz") as z:
        centres = z["centres"]  # [T, M, 3]
    com_pred = centres.mean(1)
    com_gt = np.stack([x.mean(0) for x in gt])
    d_pred, d_gt = com_pred - com_pred[0], com_gt - com_gt[0]
    err = np.linalg.norm(d_pred - d_gt, axis=1) / size
    still = np.linalg.norm(d_gt, axis=1) / size
    hit = int(truth["hit_frame"])
    return {
        "registration": {
            "rotation_deg": angle,
            "scale_rel": s_e / s - 1.0,
            "centroid_rel": float(np.linalg.norm(X_e.mean(0) - gt[0].mean(0)) / size),
            "max_point_rel": float(np.linalg.norm(X_e - gt[0], axis=1).max() / size),
        },
        "motion": {
            "com_error_rel": err.tolist(),
            "mean_com_error_rel": float(err.mean()),
            "mean_com_error_rel_after_hit": float(err[hit:].mean()),
            "still_mean_com_error_rel": float(still.mean()),
            "still_mean_com_error_rel_after_hit": float(still[hit:].mean()),
        },
        "size": size,
    }


if __name__ == "__main__":
    print(json.dumps(check(sys.argv[1], sys.argv[2])))
