"""The forecast's model-discrepancy term: how far the object's centre of mass may stray from what
the spring-mass asset predicts, beyond what its parameter uncertainty allows.

The posterior's draws say which futures the model allows; on data from another simulator (MPM) or
a real capture the model itself is wrong, and its error grows with the horizon. So the predictive
band adds, per frame t, an isotropic Gaussian error of standard deviation (per axis)

    σ(t) = σ_fit(t)                                         fit frames t < n_fit
    σ(t) = sqrt(σ_end² + (γ · size · h_t)²)                 future, h_t = (t - n_fit + 1) / fps seconds

σ_fit(t), the model's own misfit on the fit frames, is measured from the images, not from any
ground truth: for each view, the displacement of the projected centre of the asset's bound
Gaussian centres from frame 0 against the displacement of the observed silhouette's centroid,
in pixels, times the depth over the focal length (scene units); a view sees two of the three axes,
so σ_fit = RMS over the views / sqrt(2). σ_end is its RMS over the last third of the fit frames.
γ (sizes per second, `posterior.discrepancy_growth`) is the one number calibrated on null MPM
sequences (the seven objects, leave-one-object-out in docs/posterior.md; `calibrate_growth`).

With `posterior.discrepancy_offset` the discrepancy also has a mean, measured like for like: per
view the observed silhouette's centroid against the centroid of the point prediction rendered at
that view, mapped to 3D through the views' projections (`silhouette_offsets`, relative to frame 0).
The last fit frame's offset is held over the future (the ball moves by it); σ_end is the offsets'
scatter about it over the last third of the fit frames (`offset_discrepancy`, `with_offsets`).

The 90% predictive region of the centre of mass at frame t is a ball around the draws' median
displacement whose radius is the 90% quantile of the draws' displacements plus the discrepancy
noise (`ball_radius`); the truth lies inside when its own displacement from frame 0 is within it
(displacements, because the truth's particles and the Gaussians' centres differ by a
representation offset at rest).
"""

from __future__ import annotations

import numpy as np


def fit_misfit(seq, centres: np.ndarray, n_fit: int, views=None) -> np.ndarray:
    """[n_fit] σ_fit(t) per axis, scene units (module docstring); centres [T >= n_fit, P, 3] of the
    asset's prediction. Views whose silhouette is empty in some fit frame are skipped."""
    views = range(len(seq.cameras)) if views is None else views
    err = []
    for v in views:
        cam = seq.cameras[v]
        row = []
        for f in range(int(n_fit)):
            mask = seq.image(v, f)[..., 3] > 0.5
            if not mask.any():
                row = None
                break
            rr, cc = np.nonzero(mask)
            seen = np.array([cc.mean() + 0.5, rr.mean() + 0.5])
            uv, z = cam.project(np.asarray(centres[f], float))
            row.append((uv.mean(axis=0), seen, float(np.mean(z))))
        if row is None:
            continue
        p0, m0, _ = row[0]
        focal = np.array([cam.K[0, 0], cam.K[1, 1]])
        err.append([((p - p0) - (m - m0)) * z / focal for p, m, z in row])  # [n_fit, 2] scene units
    if not err:
        return np.zeros(int(n_fit))
    e = np.asarray(err)  # [V, n_fit, 2]
    return np.sqrt(np.mean(np.sum(e**2, axis=-1), axis=0) / 2.0)


def _centroid(alpha: np.ndarray, width: int, height: int) -> np.ndarray | None:
    """The silhouette's (alpha > 0.5) area centroid in the pixel coordinates of a width x height
    camera (an image of another size is scaled to it), or None when it is empty or touches the
    image's border (cut off: its centroid is not the object's)."""
    mask = np.asarray(alpha) > 0.5
    if not mask.any() or mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any():
        return None
    rr, cc = np.nonzero(mask)
    return np.array([(cc.mean() + 0.5) * width / mask.shape[1], (rr.mean() + 0.5) * height / mask.shape[0]])


def _projection_jacobian(cam, x: np.ndarray) -> np.ndarray:
    """[2, 3] d(pixel)/d(world point) of `cam` at x [3]."""
    pc = cam.to_camera(np.asarray(x, float)[None])[0]
    z = pc[2]
    d = np.array([[1.0 / z, 0.0, -pc[0] / z**2], [0.0, 1.0 / z, -pc[1] / z**2]])
    return np.asarray(cam.K, float)[:2, :2] @ d @ np.asarray(cam.R, float)


def silhouette_offsets(seq, rendered_alpha: np.ndarray, coms: np.ndarray, min_views: int = 2) -> np.ndarray:
    """[F, 3] where the observed object stands relative to the asset's prediction, frames 0..F-1,
    in scene units, from the images alone: per view, the observed silhouette's centroid minus the
    rendered prediction's (rendered_alpha [F, V, h, w], the prediction's opacity in view v of
    `seq.cameras`), mapped to 3D through each view's projection at the prediction's centre of mass
    coms [F, 3] (least squares over the views that see both silhouettes). Like for like (a
    silhouette against a silhouette), so a prediction that matches the images has none; relative
    to frame 0 (the rest state both start from). A view whose silhouette (either) is empty or cut
    off by the image's border does not count; a frame fewer than `min_views` views see is NaN."""
    alpha = np.asarray(rendered_alpha)
    n_frames, n_views = alpha.shape[:2]
    out = np.full((n_frames, 3), np.nan)
    for f in range(n_frames):
        rows, rhs = [], []
        for v in range(n_views):
            cam = seq.cameras[v]
            seen = _centroid(seq.image(v, f)[..., 3], cam.width, cam.height)
            pred = _centroid(alpha[f, v], cam.width, cam.height)
            if seen is None or pred is None:
                continue
            rows.append(_projection_jacobian(cam, coms[f]))
            rhs.append(seen - pred)
        if len(rows) >= int(min_views):
            out[f] = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)[0]
    if np.isfinite(out[0]).all():
        out -= out[0]
    return out


def offset_discrepancy(offsets: np.ndarray) -> tuple[np.ndarray, float]:
    """(the discrepancy's mean over the future [3]: the offset at the last fit frame the images
    measured, its per-axis standard deviation σ_end: the offsets' scatter about it over the last
    third of the fit frames) from silhouette_offsets [n_fit, 3]; zeros when no frame was measured."""
    d = np.asarray(offsets, float)
    ok = np.isfinite(d).all(axis=1)
    if not ok.any():
        return np.zeros(3), 0.0
    d = d[ok]
    end = d[-1]
    tail = d[-max(1, d.shape[0] // 3) :]
    return end, float(np.sqrt(np.mean(np.sum((tail - end) ** 2, axis=1)) / 3.0))


def with_offsets(draws: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(draws [S, T, 3] moved by the discrepancy's mean: offsets [n_fit, 3] over the fit frames, the
    last fit frame's after them; σ_fit [n_fit]: the offsets' scatter, every fit frame; the mean
    offset after the fit frames [3]) (offset_discrepancy)."""
    draws = np.asarray(draws, float)
    offsets = np.asarray(offsets, float)
    n_fit = offsets.shape[0]
    end, sigma_end = offset_discrepancy(offsets)
    shift = np.repeat(end[None], draws.shape[1], axis=0)
    shift[:n_fit] = np.where(np.isfinite(offsets), offsets, end[None])[: draws.shape[1]]
    return draws + shift[None], np.full(n_fit, sigma_end), end


def sigma_over_time(sigma_fit: np.ndarray, n_frames: int, fps: float, size: float, growth: float) -> np.ndarray:
    """[n_frames] σ(t) (module docstring)."""
    sigma_fit = np.asarray(sigma_fit, float)
    n_fit = sigma_fit.size
    tail = sigma_fit[-max(1, n_fit // 3) :]
    end = float(np.sqrt(np.mean(tail**2)))
    h = (np.arange(int(n_frames)) - n_fit + 1) / float(fps)
    out = np.sqrt(end**2 + (float(growth) * float(size) * h) ** 2)
    out[:n_fit] = sigma_fit[: min(n_fit, int(n_frames))]
    return out


def ball_radius(draws: np.ndarray, centre: np.ndarray, sigma: np.ndarray, level: float = 0.9, n_noise: int = 64,
                seed: int = 0) -> np.ndarray:  # fmt: skip
    """[T] radius around centre [T, 3] holding `level` of the predictive: draws [S, T, 3] (the
    posterior draws' centre-of-mass displacements) plus N(0, σ(t)² I) (seeded)."""
    return mixture_radius([(draws, sigma)], centre, level, n_noise, seed)


def mixture_radius(members: list, centre: np.ndarray, level: float = 0.9, n_noise: int = 64,
                   seed: int = 0) -> np.ndarray:  # fmt: skip
    """[T] radius around centre [T, 3] holding `level` of an equal-weight mixture of predictives,
    members [(draws [S_i, T, 3], σ_i [T])], each its draws plus N(0, σ_i(t)² I) (seeded); a member
    with fewer draws repeats its noise more often, so every member weighs the same."""
    rng = np.random.default_rng(seed)
    n_max = max(np.asarray(d).shape[0] for d, _ in members)
    dist = []
    for draws, sigma in members:
        draws = np.asarray(draws, float)
        n = int(np.ceil(int(n_noise) * n_max / draws.shape[0]))
        noise = rng.standard_normal((draws.shape[0], n, draws.shape[1], 3)) * np.asarray(sigma)[None, None, :, None]
        d = np.linalg.norm(draws[:, None] + noise - np.asarray(centre)[None, None], axis=-1)  # [S, n, T]
        dist.append(d.reshape(-1, d.shape[-1])[: int(n_noise) * n_max])
    return np.quantile(np.concatenate(dist), float(level), axis=0)


def ensemble_ball(cases: list, growth: float = 0.0, level: float = 0.9, seed: int = 0) -> dict:
    """The `level` ball of several runs of one sequence (reconstructions at other seeds: the
    identification's run-to-run spread), each case as `coverage`'s: the equal-weight mixture of
    their predictives (their draws, their own σ(t) with `growth`), centred on the median of all
    draws. Returns {centre [T, 3], radius [T], member_centres [R, T, 3]} and, when every case has
    the truth, truth_inside [T] (bool) and the shares over the fit and the future frames."""
    if not cases:
        raise ValueError("an ensemble needs at least one run")
    n_fit = len(cases[0]["sigma_fit"])
    if any(len(c["sigma_fit"]) != n_fit for c in cases):
        raise ValueError("the runs of an ensemble must share the sequence's fit frames")
    t = min(np.asarray(c["draws"]).shape[1] for c in cases)
    members = [(np.asarray(c["draws"], float)[:, :t], sigma_over_time(c["sigma_fit"], t, c["fps"], c["size"], growth))
               for c in cases]  # fmt: skip
    centre = np.median(np.concatenate([d for d, _ in members]), axis=0)
    out = {
        "centre": centre,
        "radius": mixture_radius(members, centre, level, seed=seed),
        "member_centres": np.stack([np.median(d, axis=0) for d, _ in members]),
    }
    truths = [c.get("truth") for c in cases]
    if all(x is not None and len(x) for x in truths):
        tt = min(len(x) for x in truths)
        truth = np.asarray(truths[0], float)[:tt]
        hit = inside(truth, centre[:tt], out["radius"][:tt])
        out["truth_inside"] = hit
        out["truth_inside_fit"] = float(hit[1:n_fit].mean()) if n_fit > 1 else None
        out["truth_inside_future"] = float(hit[n_fit:].mean()) if tt > n_fit else None
    return out


def inside(truth: np.ndarray, centre: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """[T] bool: the truth's displacement [T, 3] within the ball."""
    return np.linalg.norm(np.asarray(truth) - np.asarray(centre), axis=-1) <= np.asarray(radius) + 1e-12


def coverage(case: dict, growth: float, level: float = 0.9, seed: int = 0) -> float:
    """Share of the future frames whose true centre of mass lies in the `level` ball of one case
    ({draws [S, T, 3], centre [T, 3], truth [T, 3], sigma_fit [n_fit], fps, size}), or of an
    ensemble of runs ({members: [such cases]}, `ensemble_ball`)."""
    if "members" in case:
        return float(ensemble_ball(case["members"], growth, level, seed)["truth_inside_future"])
    n_fit = len(case["sigma_fit"])
    truth = np.asarray(case["truth"], float)
    t = truth.shape[0]
    sigma = sigma_over_time(case["sigma_fit"], t, case["fps"], case["size"], growth)
    r = ball_radius(np.asarray(case["draws"])[:, :t], np.asarray(case["centre"])[:t], sigma, level, seed=seed)
    return float(inside(truth, np.asarray(case["centre"])[:t], r)[n_fit:].mean())


def calibrate_growth(cases: list, level: float = 0.9, hi: float = 50.0, seed: int = 0) -> float:
    """The smallest γ >= 0 whose pooled future coverage over `cases` (each as `coverage`'s,
    weighted by its future frames) reaches `level` (bisection; `hi` when none below it does)."""

    def future_frames(c) -> int:
        c = c["members"][0] if "members" in c else c
        return len(c["truth"]) - len(c["sigma_fit"])

    def pooled(growth: float) -> float:
        n = [future_frames(c) for c in cases]
        return float(np.average([coverage(c, growth, level, seed) for c in cases], weights=n))

    if pooled(0.0) >= level:
        return 0.0
    lo, up = 0.0, float(hi)
    if pooled(up) < level:
        return up
    for _ in range(30):
        mid = 0.5 * (lo + up)
        lo, up = (lo, mid) if pooled(mid) >= level else (mid, up)
    return up
