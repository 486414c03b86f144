"""The identification upper bound ("oracle"): the spring-mass model fitted to the generator's
own particle tracks instead of to images.

Anchors are N_A of the ground-truth particles of frame 0 (farthest-point sampled), so every
anchor has a true track [T, N_A, 3]. The loss is the mean squared distance between simulated
anchors and their tracks over frames 1..n_fit-1, differentiated through the whole rollout
(`grad_mode="full"`); v0 and gravity are the generator's, so only what stage 5 identifies is
fitted: log10 k_i, κ, μ and e. The rollout then continues over the future frames.

What it answers: how well the model class reproduces and predicts a sequence when rendering,
the static fit and v0 are perfect. The future error is scored against the same physics-free
continuations as the pipeline's baseline (`sgdr.evaluate.baselines`), here of the *true* tracks of
the last two fit frames. If the oracle itself is not far ahead of that baseline, no image-based
reconstruction with this model will be: the limit is the model, not the pipeline.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import drjit as dr
import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from sgdr.anchors import sample_anchors
from sgdr.arrays import array3_to_points, points_to_array3, scalar, to_numpy
from sgdr.asset.predict import physical_params
from sgdr.backend import ad
from sgdr.evaluate.baselines import BASELINES, ISSUE_BASELINES, physics_free_predictions
from sgdr.evaluate.geometry import chamfer_distance
from sgdr.identify.adam import make_adam
from sgdr.identify.dynamics import clamp_to_ranges
from sgdr.observe.targets import raised_ground
from sgdr.physics import PhysParams, SimState, build_spring_model, rollout


@dataclass
class OracleResult:
    values: dict  # identified {"log10_k" [N_A], "kappa", "friction", "restitution"}
    losses: list  # [iterations] training loss (mean squared anchor error over the fit frames)
    track_error: np.ndarray  # [T] mean |simulated anchor - its track| per frame, scene units
    cd: np.ndarray  # [T] Chamfer distance x1e3 of simulated anchors vs the tracked particles
    baseline_cd: dict  # {variant: [n_future] CD x1e3} of the physics-free continuations
    baseline_track_error: dict  # {variant: [n_future] mean |prediction - track|}
    anchor_index: np.ndarray  # [N_A] indices of the tracked particles
    n_fit: int
    simulated: np.ndarray  # [T, N_A, 3] the identified model's rollout over every frame
    tracks: np.ndarray  # [T, N_A, 3] the tracked particles (ground truth)
    scan: list = field(default_factory=list)  # `offset_scan` rows, one per log10 k offset
    ensemble: dict = field(default_factory=dict)  # `offset_scan`'s ensemble of the near-best offsets

    def summary(self) -> dict:
        """The headline numbers: fit / future means of the oracle and of the baseline."""
        f = self.n_fit
        base = {name: float(np.mean(v)) for name, v in self.baseline_cd.items()}
        best = min(ISSUE_BASELINES, key=lambda name: base[name])
        return {
            "oracle_fit_track_error": float(np.mean(self.track_error[1:f])),
            "oracle_future_track_error": float(np.mean(self.track_error[f:])),
            "oracle_fit_cd": float(np.mean(self.cd[1:f])),
            "oracle_future_cd": float(np.mean(self.cd[f:])),
            "baseline_future_cd": base[best],
            "baseline_variant": best,
            "baseline_future_cd_by_variant": base,
            "baseline_future_track_error_by_variant": {
                n: float(np.mean(v)) for n, v in self.baseline_track_error.items()
            },
            "log10_k_mean": float(np.mean(self.values["log10_k"])),
            "log10_k_std": float(np.std(self.values["log10_k"])),
            "kappa": float(self.values["kappa"]),
            "friction": float(self.values["friction"]),
            "restitution": float(self.values["restitution"]),
            "final_loss": float(self.losses[-1]) if self.losses else float("nan"),
            **(
                {
                    "ensemble_future_track_error": self.ensemble["future_track_error"],
                    "ensemble_members": len(self.ensemble["offsets"]),
                }
                if self.ensemble
                else {}
            ),
        }


def tracked_anchor_index(particles0: np.ndarray, n_anchors: int, seed: int) -> np.ndarray:
    """[N_A] indices of farthest-point-sampled particles of frame 0 (particles0 [P, 3])."""
    chosen = sample_anchors(particles0, int(n_anchors), "fps", 0.0, int(seed))  # [N_A, 3]
    _, index = cKDTree(particles0).query(chosen, k=1)  # exact: the sampler returns particles
    return np.asarray(index, dtype=np.int64)


def track_optimiser(n_anchors: int, physics_cfg, recon_cfg, log10_k_init: float):
    """Adam over log10 k_i [N_A] (uniform start `log10_k_init`), κ, μ, e (the physics' initial
    values), with the dynamic stage's learning rates (`recon_cfg`)."""
    t = ad()
    return make_adam(
        {
            "log10_k": (t.Float(np.full(n_anchors, float(log10_k_init), np.float32)), recon_cfg.lr_log10_k),
            "kappa": (t.Float(float(physics_cfg.kappa_init)), recon_cfg.lr_kappa),
            "friction": (t.Float(float(physics_cfg.friction_init)), recon_cfg.lr_friction),
            "restitution": (t.Float(float(physics_cfg.restitution_init)), recon_cfg.lr_restitution),
        }
    )


def track_loss(states, targets, n_fit: int):
    """Mean squared distance of the simulated anchors to their tracks over frames 1..n_fit-1
    (states: the rollout's `SimState`s; targets: the tracks as Dr.Jit Array3f per frame)."""
    loss = 0.0
    for f in range(1, n_fit):
        loss = loss + dr.mean(dr.squared_norm(states[f].x - targets[f]))
    return loss / float(n_fit - 1)


def fit_tracks(
    tracks: np.ndarray,
    ground,
    gravity,
    v0,
    fps: float,
    n_fit: int,
    physics_cfg,
    n_k: int,
    iterations: int,
    recon_cfg,
    log10_k_init: float,
    progress: bool = False,
):
    """Fit log10 k_i, κ, μ, e to anchor tracks and roll the result out over every frame.

    tracks [T, N_A, 3] world, scene units (frame 0 = rest shape); ground: `Ground`; gravity,
    v0 [3]; recon_cfg: `ReconConfig`, whose learning rates and clamps the dynamic stage uses.
    Returns (values, losses [iterations], simulated anchors [T, N_A, 3]).
    """
    n_frames, n_a = tracks.shape[0], tracks.shape[1]
    if not 2 <= n_fit <= n_frames:
        raise ValueError(f"oracle: n_fit={n_fit} must be in [2, {n_frames}] (frames of the tracks)")
    model = build_spring_model(tracks[0], int(n_k), physics_cfg)
    base = PhysParams.init(model, physics_cfg, v0=tuple(map(float, v0)), gravity=tuple(map(float, gravity)))
    opt = track_optimiser(n_a, physics_cfg, recon_cfg, log10_k_init)
    targets = [points_to_array3(tracks[f]) for f in range(n_frames)]
    dt_frame = 1.0 / float(fps)

    def params():
        return replace(
            base, log10_k=opt["log10_k"], kappa=opt["kappa"], friction=opt["friction"], restitution=opt["restitution"]
        )

    steps = range(int(iterations))
    if progress:
        steps = tqdm(steps, desc="oracle fit", leave=False)
    losses = []
    for _ in steps:
        p = params()
        states = rollout(
            model, p, SimState.at_rest(model, p.v0), ground, n_fit, dt_frame, physics_cfg, grad_mode="full"
        )
        loss = track_loss(states, targets, n_fit)
        dr.backward(loss)
        opt.step()
        clamp_to_ranges(opt, recon_cfg)  # the stage's projection: log10 k, μ, e back into their ranges
        losses.append(scalar(loss))
        if progress:
            steps.set_postfix(loss=f"{losses[-1]:.3e}")
    with dr.suspend_grad():
        p = params().detach()
        simulated = _rollout_points(model, p, ground, n_frames, dt_frame, physics_cfg)
        values = {
            "log10_k": to_numpy(opt["log10_k"]),
            "kappa": scalar(opt["kappa"]),
            "friction": scalar(p.friction),
            "restitution": scalar(p.restitution),
        }
    return values, losses, simulated


def _rollout_points(model, params, ground, n_frames: int, dt_frame: float, cfg) -> np.ndarray:
    """Anchor positions [n_frames, N_A, 3] of a rollout from rest, without gradients."""
    with dr.suspend_grad():
        states = rollout(model, params, SimState.at_rest(model, params.v0), ground, n_frames, dt_frame, cfg)
        return np.stack([array3_to_points(s.x) for s in states])


def offset_scan(
    tracks: np.ndarray,
    ground,
    gravity,
    v0,
    fps: float,
    n_fit: int,
    physics_cfg,
    n_k: int,
    values: dict,
    offsets,
    ensemble_tol: float = 1.25,
) -> tuple:
    """Roll the identified model out with its whole log10 k field shifted by each offset: how
    much the fit frames pin down the future. Returns (rows, ensemble): rows [{"offset",
    "fit_track_error", "future_track_error", "final_centre" [3]}]; ensemble: the mean rollout
    of the offsets whose fit error is within `ensemble_tol` x the best, scored the same way
    ({"offsets", "fit_track_error", "future_track_error", "spread_last"}; {} without offsets)."""
    offsets = [float(o) for o in offsets]
    if not offsets:
        return [], {}
    model = build_spring_model(tracks[0], int(n_k), physics_cfg)
    rows, runs = [], []
    for offset in offsets:
        shifted = {**values, "log10_k": np.asarray(values["log10_k"]) + offset, "v0": v0, "gravity": gravity}
        sim = _rollout_points(
            model, physical_params(model, physics_cfg, shifted), ground, tracks.shape[0], 1.0 / float(fps), physics_cfg
        )
        error = np.linalg.norm(sim - tracks, axis=2).mean(axis=1)
        rows.append(
            {
                "offset": offset,
                "fit_track_error": float(error[1:n_fit].mean()),
                "future_track_error": float(error[n_fit:].mean()),
                "final_centre": sim[-1].mean(axis=0).tolist(),
            }
        )
        runs.append(sim)
    fit = np.array([r["fit_track_error"] for r in rows])
    keep = np.flatnonzero(fit <= float(ensemble_tol) * fit.min())
    mean = np.mean([runs[i] for i in keep], axis=0)
    error = np.linalg.norm(mean - tracks, axis=2).mean(axis=1)
    spread = np.mean([np.linalg.norm(runs[i][-1] - mean[-1], axis=1).mean() for i in keep])
    ensemble = {
        "offsets": [offsets[i] for i in keep],
        "fit_track_error": float(error[1:n_fit].mean()),
        "future_track_error": float(error[n_fit:].mean()),
        "spread_last": float(spread),
    }
    return rows, ensemble


def score_tracks(simulated: np.ndarray, tracks: np.ndarray, n_fit: int, fps: float, gravity, ground) -> tuple:
    """Per-frame track error and CD of `simulated` vs `tracks` (both [T, N_A, 3]), and of the
    physics-free continuations of the true tracks of frames n_fit-2, n_fit-1 on the future.
    Returns (track_error [T], cd [T], baseline_cd {variant: [n_future]}, baseline_error {...})."""
    n_frames = tracks.shape[0]
    error = np.linalg.norm(simulated - tracks, axis=2).mean(axis=1)
    cd = np.array([chamfer_distance(simulated[f], tracks[f]) for f in range(n_frames)])
    future = physics_free_predictions(
        tracks[n_fit - 2],
        tracks[n_fit - 1],
        n_frames - n_fit,
        1.0 / float(fps),
        np.asarray(gravity, float),
        ground.point,
        ground.normal,
    )
    baseline_cd, baseline_error = {}, {}
    for name in BASELINES:
        preds = future[name]
        baseline_cd[name] = np.array([chamfer_distance(preds[k], tracks[n_fit + k]) for k in range(len(preds))])
        baseline_error[name] = np.array(
            [np.linalg.norm(preds[k] - tracks[n_fit + k], axis=1).mean() for k in range(len(preds))]
        )
    return error, cd, baseline_cd, baseline_error


def oracle_study(
    seq, n_anchors: int, n_k: int, physics_cfg, recon_cfg, oracle_cfg, seed: int = 0, progress: bool = False
) -> OracleResult:
    """Fit the model to the sequence's ground-truth particle tracks (gt/particles_*.npy and
    gt/params.json's v0, MPM cell) and score fit and future. `seq`: a `Sequence` with gt;
    `recon_cfg`: the dynamic stage's learning rates and clamps; `oracle_cfg`: `OracleConfig`."""
    gt = seq.gt_params()
    if gt is None:
        raise ValueError(f"{seq.root}: the oracle needs ground truth (gt/particles_*.npy, gt/params.json)")
    if "v0" not in gt:
        raise ValueError(f"{seq.gt_dir / 'params.json'}: field 'v0' is missing")
    particles = [seq.gt_particles(f) for f in range(seq.n_frames)]
    index = tracked_anchor_index(particles[0], n_anchors, seed)
    tracks = np.stack([p[index] for p in particles]).astype(np.float64)  # [T, N_A, 3]
    margin = float(oracle_cfg.contact_margin)
    if margin < 0:  # the MPM collider acts on grid nodes up to half a cell above the plane
        margin = 0.5 * float(gt.get("mpm", {}).get("dx", 0.0))
    ground = raised_ground(seq, margin)
    values, losses, simulated = fit_tracks(
        tracks,
        ground,
        seq.gravity,
        gt["v0"],
        seq.fps,
        seq.n_fit,
        physics_cfg,
        n_k,
        int(oracle_cfg.iterations),
        recon_cfg,
        float(oracle_cfg.log10_k_init),
        progress=progress,
    )
    error, cd, baseline_cd, baseline_error = score_tracks(simulated, tracks, seq.n_fit, seq.fps, seq.gravity, ground)
    scan, ensemble = offset_scan(
        tracks,
        ground,
        seq.gravity,
        gt["v0"],
        seq.fps,
        seq.n_fit,
        physics_cfg,
        n_k,
        values,
        oracle_cfg.k_offsets,
        oracle_cfg.ensemble_tol,
    )
    return OracleResult(
        values=values,
        losses=losses,
        track_error=error,
        cd=cd,
        baseline_cd=baseline_cd,
        baseline_track_error=baseline_error,
        anchor_index=index,
        n_fit=int(seq.n_fit),
        simulated=simulated,
        tracks=tracks,
        scan=scan,
        ensemble=ensemble,
    )


def plot_oracle(result: OracleResult, path, title: str = "") -> None:
    """Per-frame track error of the oracle rollout and of the physics-free continuations."""
    import matplotlib  # here, not at the top: the Agg backend is chosen only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_loss) = plt.subplots(1, 2, figsize=(10, 3.6))
    frames = np.arange(len(result.track_error))
    ax.plot(frames, result.track_error, "k-o", ms=3, label="oracle spring-mass")
    future = np.arange(result.n_fit, len(result.track_error))
    for name, err in result.baseline_track_error.items():
        ax.plot(future, err, "--", label=f"baseline: {name}")
    ax.axvline(result.n_fit - 0.5, color="grey", lw=0.8)
    ax.set_xlabel("frame (fit | future)")
    ax.set_ylabel("mean anchor error, scene units")
    ax.legend(fontsize=8)
    ax_loss.semilogy(result.losses)
    ax_loss.set_xlabel("oracle iteration")
    ax_loss.set_ylabel("fit loss")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
