"""The dynamic stage's global search: CMA-ES over the few global physical parameters.

The rendered rollout loss is rugged in the global stiffness (a bounce or a slide shifts in time
when k changes by a few percent: docs/reconstruction-results.md), so its local gradient does not
point to the best basin. Before any gradient step the stage therefore searches, derivative-free,
the box of the global parameters `recon.search.parameters` (a subset of `GLOBAL_PARAMETERS`):

    θ_g = (log10 k, κ, μ, e)    log10 k: one level for every anchor (the field's mean)

and, where `recon.search.parameters` names them, two regions of different stiffness split by a
plane (`region_field`): log10 k_i = level + (c / 2) tanh(((x_i - x̄)·n / size - b) / w), n the
unit normal at polar angle `region_theta` and azimuth `region_phi`, b = `region_offset` (the
plane's distance from the anchors' centre, in sizes), c = `region_contrast` (decades between the
two sides), w = REGION_WIDTH. A stiffness that differs between regions is then seen by the search
itself, on whole rollouts, instead of being left to per-anchor gradients that mostly point
elsewhere (docs/identification.md: a two-region twin).

with CMA-ES (the `cma` package) in unit coordinates u = (θ_g - lo) / (hi - lo) ∈ [0, 1]^d,
started from the best of `recon.search.initial_samples` scrambled Sobol points over the box
(a first look at every basin; CMA-ES with a small population settles in the basin nearest its
start: on the small torus two runs whose static fits differed in the last bits ended in basins
whose losses differ by 17%).
Each candidate is scored by what the asset is asked to do, predict from frame 0 alone:

    L(θ_g) = mean over fit frames f = 1 .. n_fit-1 and all views v of
             (1-λ) L1(I_f,v, I*_f,v) + λ D-SSIM(I_f,v, I*_f,v),   λ = recon.lambda_dssim

of the open-loop rollout from rest at the n_t the prediction uses (the end of the substep
schedule), rendered on every view, optionally on images downscaled by `recon.search.image_scale`
(k x k block means of the targets, intrinsics / k). One generation, a population of S
candidates, is one batched rollout of S x N_A anchors (`sgdr.physics.batched`) and S x
(n_fit - 1) x n_views forward renders. A candidate whose rollout is unstable at that n_t scores
`UNSTABLE_LOSS`, above any image loss; the stiffness range is capped at the level the stability
bound allows at that n_t, so few candidates are wasted there.

What the search records (`GlobalSearchResult`) is also what the report shows of it: every
candidate's values and loss, the best values, and the spread of the futures that candidates
fitting about equally well predict (`Landscape`): when the fit frames do not pin the parameters
down, several basins fit alike and predict different things, and the report says so.

Deterministic: CMA-ES draws from its own seed (`seed`); the losses are forward renders.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import drjit as dr
import numpy as np

from sgdr.arrays import array3_to_points, to_numpy
from sgdr.backend import ad
from sgdr.gaussians.model import Gaussians
from sgdr.loss import image_loss, image_losses
from sgdr.observe.images import block_mean, downscaled
from sgdr.physics.batched import batched_centres, batched_rollout
from sgdr.physics.laws import CONTACT_PARAMETERS
from sgdr.physics.simulate import doubled_substeps, effective_stiffness, model_host
from sgdr.render.images import posed, render
from sgdr.render.splat import render_batch

log = logging.getLogger(__name__)

REGION_PARAMETERS = ("region_contrast", "region_theta", "region_phi", "region_offset")
GLOBAL_PARAMETERS = ("log10_k", "kappa", "friction", "restitution", *REGION_PARAMETERS)
"""The global parameters the search may vary (recon.search.parameters)."""

REGION_START = {"region_contrast": 0.0, "region_theta": 0.5 * math.pi, "region_phi": 0.0, "region_offset": 0.0}
"""Where the search starts the regions: equal (contrast 0), split by a vertical plane through the centre."""

REGION_WIDTH = 0.05
"""Width of the border between the two regions, in sizes (tanh's scale): sharp against the object,
smooth enough that a small move of the plane changes the rollout a little."""


def region_field(x_rest: np.ndarray, values: dict) -> np.ndarray:
    """[S, N_A] deviation of log10 k from the level for {region_*: [S] values} (module docstring);
    x_rest [N_A, 3] the anchors' rest positions. Parameters left out: contrast 0, the plane through
    the centre with normal +z."""
    x = np.asarray(x_rest, float).reshape(-1, 3)
    size = max(float(np.ptp(x, axis=0).max()), 1e-12)
    rel = (x - x.mean(axis=0)) / size  # [N_A, 3]
    n_samples = max(np.size(v) for v in values.values())

    def get(name: str, default: float) -> np.ndarray:
        return np.broadcast_to(np.asarray(values.get(name, default), float), (n_samples,))

    c, b = get("region_contrast", 0.0), get("region_offset", 0.0)
    theta, phi = get("region_theta", 0.0), get("region_phi", 0.0)
    n = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)  # [S, 3]
    return 0.5 * c[:, None] * np.tanh((n @ rel.T - b[:, None]) / REGION_WIDTH)


UNSTABLE_LOSS = 10.0
"""The score of a candidate whose rollout is unstable: above any image loss (L1 and D-SSIM <= 1)."""
LEVELS = ("mean", "effective")  # recon.search.level: the level's search coordinate


def choose_best(result: GlobalSearchResult) -> dict[str, float]:
    """The candidate with the lowest rollout loss."""
    return dict(result.best)


def choose_medoid(result: GlobalSearchResult) -> dict[str, float]:
    """Of the candidates that fit about as well as the best (`Landscape.equivalent`), the one whose
    predicted future is nearest the others': when the fit frames cannot tell them apart, the
    prediction that errs least against the alternatives they allow (the best one itself when
    they agree, or when it is the only one)."""
    if result.landscape is None:
        return dict(result.best)
    i = result.landscape.medoid
    return {n: float(result.candidates[i, j]) for j, n in enumerate(result.names)}


# What the search hands on as the start of the local stage (recon.search.choose)
CHOICES = {"best": choose_best, "medoid": choose_medoid}


class SearchConfigError(ValueError):
    """A recon.search setting that cannot be used; the message names the key."""


@dataclass(frozen=True)
class SearchSpace:
    """The box the search explores: parameter names and their ranges [lo, hi]."""

    names: tuple[str, ...]
    lo: np.ndarray  # [d]
    hi: np.ndarray  # [d]
    # recon.search.level = "effective": the level's coordinate is the effective level
    # s = log10 k + offset(κ), the offset tabulated over κ's range (`level_offsets`), so that moving κ
    # at a fixed s keeps the stiffness the anchors feel; None: the level itself
    level_kappa: np.ndarray | None = None  # [K] ascending
    level_offset: np.ndarray | None = None  # [K]

    def _offset(self, kappa: np.ndarray) -> np.ndarray:
        return np.interp(kappa, self.level_kappa, self.level_offset)

    def values(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """Unit coordinates [S, d] -> {name: [S] values} (clipped to the box)."""
        u = np.clip(np.atleast_2d(np.asarray(u, float)), 0.0, 1.0)
        x = self.lo + u * (self.hi - self.lo)
        if self.level_kappa is not None:
            i, j = self.names.index("log10_k"), self.names.index("kappa")
            x[:, i] = np.clip(x[:, i] - self._offset(x[:, j]), self.lo[i], self.hi[i])
        return {name: x[:, i] for i, name in enumerate(self.names)}

    def unit(self, values: dict) -> np.ndarray:
        """{name: value} -> unit coordinates [d], clipped to the box."""
        x = np.array([float(values[n]) for n in self.names])
        if self.level_kappa is not None:
            i, j = self.names.index("log10_k"), self.names.index("kappa")
            x[i] = x[i] + float(self._offset(x[j]))
        return np.clip((x - self.lo) / np.maximum(self.hi - self.lo, 1e-30), 0.0, 1.0)


def level_offsets(model, physics_cfg, kappa_lo: float, kappa_hi: float, n: int = 33) -> tuple[np.ndarray, np.ndarray]:
    """(κ [n], offset [n]): log10 of the mean effective stiffness of the anchors at log10 k = 0
    (`effective_stiffness`: the soft vector η(κ) cuts the longer springs as κ grows) at n values of
    κ over [kappa_lo, kappa_hi], less its value at the middle of that range. On a twin of the torus
    the first half of the fit window is nearly flat along a diagonal valley of level and κ (a
    softer soft vector with a lower level), narrow across it: these offsets make that valley the
    κ axis (docs/posterior.md, "The SBC's misses up close")."""
    t = ad()
    kappas = np.linspace(float(kappa_lo), float(kappa_hi), int(n))
    g = []
    for kappa in kappas:
        p = SimpleNamespace(log10_k=np.zeros(model.n_anchors), kappa=t.Float(float(kappa)))
        g.append(math.log10(float(np.mean(effective_stiffness(model, p, physics_cfg)))))
    g = np.asarray(g)
    return kappas, g - float(np.interp(0.5 * (kappas[0] + kappas[-1]), kappas, g))


def stable_level(model, kappa_values, dt_frame: float, n_t: int, physics_cfg) -> float:
    """The highest uniform log10 k whose rollout at n_t substeps per frame keeps the stability
    bound dt <= physics.cfl_factor sqrt(m_i / k_eff,i) for every κ in `kappa_values`."""

    mass = model_host(model)["particle_mass"]
    t = ad()
    worst = 0.0
    for kappa in kappa_values:
        p = SimpleNamespace(log10_k=np.zeros(model.n_anchors), kappa=t.Float(float(kappa)))
        k_eff = effective_stiffness(model, p, physics_cfg)  # at log10 k = 0: k_eff scales with 10^level
        worst = max(worst, float(np.max(k_eff / mass)))
    dt = float(dt_frame) / int(n_t)
    # dt <= c sqrt(m / (10^L k0)) <=> L <= log10(c^2 / (dt^2 max(k0 / m)))
    return math.log10(physics_cfg.cfl_factor**2 / (dt * dt * worst))


def search_space(search_cfg, physics_cfg, model, dt_frame: float, n_t: int, per_anchor: bool = True) -> SearchSpace:
    """The box of `recon.search.parameters` with the `recon.search.<name>_range` ranges; κ only
    where the soft vector acts, e only where the contact has one (physics.contact), the two
    regions only with a per-anchor stiffness (`per_anchor`, recon.stiffness); log10 k capped at
    the stability bound at n_t (`stable_level`; with regions, the stiffer side's level). Raises
    SearchConfigError naming the key."""

    unknown = [n for n in search_cfg.parameters if n not in GLOBAL_PARAMETERS]
    if unknown:
        raise SearchConfigError(f"recon.search.parameters: unknown {unknown}; known: {list(GLOBAL_PARAMETERS)}")
    contact = CONTACT_PARAMETERS.get_named(physics_cfg.contact)
    names, lo, hi = [], [], []
    for name in search_cfg.parameters:
        if name == "kappa" and not physics_cfg.soft_vector:
            continue  # η = 1: κ acts on nothing
        if name in ("friction", "restitution") and name not in contact:
            continue
        if name in REGION_PARAMETERS and not per_anchor:
            continue  # one stiffness for every anchor: no regions
        key = f"{name}_range"
        a, b = (float(v) for v in getattr(search_cfg, key))
        if not (math.isfinite(a) and math.isfinite(b) and a < b):
            raise SearchConfigError(f"recon.search.{key}={[a, b]} must be two finite numbers, low < high")
        names.append(name)
        lo.append(a)
        hi.append(b)
    if "log10_k" in names:
        i = names.index("log10_k")
        kappas = list(search_cfg.kappa_range) if "kappa" in names else [physics_cfg.kappa_init]
        cap = stable_level(model, kappas, dt_frame, n_t, physics_cfg)
        if cap <= lo[i]:
            raise SearchConfigError(
                f"recon.search.log10_k_range={[lo[i], hi[i]]}: every level is unstable at n_t={n_t} substeps per "
                f"frame (the stability bound allows log10 k <= {cap:.3g}); lower the range or raise physics.n_substeps"
            )
        if "region_contrast" in names:  # the stiffer region sits half the contrast above the level
            cap -= 0.5 * max(abs(v) for v in (lo[names.index("region_contrast")], hi[names.index("region_contrast")]))
        hi[i] = min(hi[i], cap)
    level = str(getattr(search_cfg, "level", "mean"))
    if level not in LEVELS:
        raise SearchConfigError(f"recon.search.level={level!r}: must be one of {list(LEVELS)}")
    if level == "effective" and "log10_k" in names and "kappa" in names:
        j = names.index("kappa")
        kappas, offsets = level_offsets(model, physics_cfg, lo[j], hi[j])
        return SearchSpace(tuple(names), np.asarray(lo, float), np.asarray(hi, float), kappas, offsets)
    return SearchSpace(tuple(names), np.asarray(lo, float), np.asarray(hi, float))


@dataclass
class Landscape:
    """What the report shows of the search: how sure the identification is.

    equivalent: indices (into GlobalSearchResult.losses) of the candidates whose loss is within
      recon.search.equivalent_tolerance (relative) of the best, best first, at most top_k;
    future_spread: the largest distance between their predicted centres of mass over the frames
      after the fit window, as a fraction of the object's size (0 with one candidate);
    ambiguous: future_spread > recon.search.spread_warning."""

    equivalent: list[int]
    future_spread: float
    ambiguous: bool
    centres: np.ndarray  # [len(equivalent), T, 3] their predicted centres of mass, all frames
    medoid: int = -1  # index (into GlobalSearchResult.losses) of the equivalent candidate whose future is
    #                   nearest the others' (least summed mean distance of the centres after the fit window)


@dataclass
class GlobalSearchResult:
    """Every scored candidate and the best one (module docstring)."""

    names: tuple[str, ...]
    candidates: np.ndarray  # [n_eval, d] values in evaluation order
    losses: np.ndarray  # [n_eval] rollout losses (UNSTABLE_LOSS where unstable)
    generation: np.ndarray  # [n_eval] int, the CMA-ES generation of each candidate (-1: the space-filling samples)
    best: dict[str, float]  # the best candidate's values
    best_loss: float
    n_substeps: int  # the n_t every candidate was scored at
    image_scale: int
    landscape: Landscape | None = None
    lo: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hi: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # the stages on part of the fit window before the last (recon.search.frame_schedule): per stage
    # the fit frames scored, its evaluations, its best loss (on those frames) and values
    stages: list = field(default_factory=list)
    n_swept: int = 0  # of the candidates, those of the coordinate sweep (recon.search.line_points)

    def to_json(self) -> dict:
        """Plain values for dynamics.json (the report's landscape section reads them)."""
        order = np.argsort(self.losses, kind="stable")
        out = {
            "names": list(self.names),
            "lo": self.lo.tolist(),
            "hi": self.hi.tolist(),
            "best": self.best,
            "best_loss": self.best_loss,
            "n_evaluations": int(self.losses.size),
            "n_generations": int(self.generation.max() + 1) if self.generation.size else 0,
            "n_initial_samples": int(np.sum(self.generation < 0)),
            "n_swept": self.n_swept,
            "n_substeps": self.n_substeps,
            "image_scale": self.image_scale,
            "candidates": self.candidates[order].tolist(),
            "losses": self.losses[order].tolist(),
            "generation": self.generation[order].tolist(),
            "stages": self.stages,
        }
        if self.landscape is not None:
            out["landscape"] = {
                "equivalent": [int(np.flatnonzero(order == i)[0]) for i in self.landscape.equivalent],
                "future_spread": self.landscape.future_spread,
                "ambiguous": bool(self.landscape.ambiguous),
                "medoid": int(np.flatnonzero(order == self.landscape.medoid)[0]),
            }
        return out


class PopulationScorer:
    """L(θ_g) of a population (module docstring): one batched rollout, forward renders.

    model / binding / gaussians: the asset; base: PhysParams holding every field a candidate
    does not set (its log10 k field uniform, or any field: a candidate's level moves the field's
    mean); targets [n_fit][n_views] TensorXf [H, W, 3]; cameras: the sequence's."""

    def __init__(
        self,
        model,
        binding,
        gaussians,
        base,
        ground,
        targets,
        cameras,
        dt_frame: float,
        n_t: int,
        physics_cfg,
        render_cfg,
        lam: float,
        image_scale: int = 1,
        images_per_call: int = 1,
    ):
        k = int(image_scale)
        if int(images_per_call) < 1:
            raise SearchConfigError(f"recon.search.images_per_call={images_per_call} must be a positive integer")
        if k < 1:
            raise SearchConfigError(f"recon.search.image_scale={image_scale} must be a positive integer")
        t = ad()
        self.model, self.binding, self.base, self.ground = model, binding, base, ground
        self.gaussians = gaussians.detach() if hasattr(gaussians, "detach") else gaussians
        self.cameras = [downscaled(c, k) for c in cameras]
        # one atlas needs one image size: views of different sizes are rendered one at a time
        sizes = {(c.width, c.height) for c in self.cameras}
        self.images_per_call = int(images_per_call) if len(sizes) == 1 else 1
        if len(sizes) > 1 and int(images_per_call) > 1:
            log.info("dynamics: global search: the views have %d image sizes; rendering one at a time", len(sizes))
        self.targets = [
            [t.TensorXf(np.ascontiguousarray(block_mean(to_numpy(img, np.float32), k))) for img in frame]
            for frame in targets
        ]
        self.dt, self.n_t, self.physics_cfg, self.render_cfg, self.lam = (
            dt_frame,
            int(n_t),
            physics_cfg,
            render_cfg,
            lam,
        )
        self.base_level = float(np.mean(to_numpy(base.log10_k)))
        self.image_scale = k
        self.x_rest = np.asarray(array3_to_points(model.x_rest), float)
        if self.images_per_call > 1:  # what `_batched` reads: the targets [F, V, H, W, 3], the shared fields
            self.stacked_targets = np.stack([[to_numpy(img, np.float32) for img in f] for f in self.targets[1:]])
            self.fields = {f: np.asarray(v) for f, v in self.gaussians.to_numpy().items() if f != "means"}

    def samples(self, values: dict[str, np.ndarray]) -> dict:
        """Candidate values -> `batched_rollout` samples (a level is a shift of the base field)."""
        out = {}
        for name, v in values.items():
            if name == "log10_k":
                out["dlog10_k"] = np.asarray(v, float) - self.base_level
            elif name not in REGION_PARAMETERS:
                out[name] = np.asarray(v, float)
        regions = {n: v for n, v in values.items() if n in REGION_PARAMETERS}
        if regions:
            out["dlog10_k_anchor"] = region_field(self.x_rest, regions)
        return out

    def rollout(self, values: dict[str, np.ndarray], n_frames: int):
        return batched_rollout(
            self.model, self.base, self.samples(values), self.ground, n_frames, self.dt, self.n_t, self.physics_cfg
        )

    @property
    def n_fit_frames(self) -> int:
        """The fit frames after frame 0 that a candidate is scored on by default."""
        return len(self.targets) - 1

    def __call__(self, values: dict[str, np.ndarray], frames: int | None = None) -> np.ndarray:
        """[S] losses of the candidates {name: [S] values}: the mean of `per_image` (over the first
        `frames` fit frames after frame 0; None: all of them)."""
        per = self.per_image(values, frames=frames)
        losses = per.reshape(per.shape[0], -1).mean(axis=1)
        return np.where(np.isfinite(losses), losses, UNSTABLE_LOSS)

    def per_image(self, values: dict[str, np.ndarray], retry: bool = False, frames: int | None = None) -> np.ndarray:
        """[S, n_fit - 1, n_views] image losses of the candidates, fit frames 1 .. n_fit - 1 (what
        the posterior's rendered likelihood weighs per frame); NaN rows for unstable rollouts.
        frames: only the first this many fit frames after frame 0 are simulated and scored
        ([S, frames, n_views]; None: all).

        retry: a candidate unstable at n_t is re-run with n_t doubled while physics.retry_on_nan
        and physics.max_substeps allow (the single rollout's remedy; the posterior's rollouts do
        the same), instead of scoring as unstable. The search does not retry: it scores what the
        asset can simulate at the prediction's n_t."""
        n = len(self.targets) if frames is None else int(frames) + 1
        if not 2 <= n <= len(self.targets):
            raise ValueError(f"frames={frames}: the scorer holds {len(self.targets) - 1} fit frames after frame 0")
        run = self.rollout(values, n)
        positions, stable = run.positions, np.asarray(run.stable, bool).copy()
        n_sub = self.n_t
        while retry and self.physics_cfg.retry_on_nan and not stable.all():
            n_sub = doubled_substeps(n_sub, self.physics_cfg)
            if not n_sub:
                break
            redo = np.flatnonzero(~stable)
            sub = {k: np.broadcast_to(np.asarray(v, float), stable.shape)[redo] for k, v in values.items()}
            again = batched_rollout(self.model, self.base, self.samples(sub), self.ground, n, self.dt, n_sub,
                                    self.physics_cfg)  # fmt: skip
            positions[redo], stable[redo] = again.positions, again.stable
        out = np.full((positions.shape[0], n - 1, len(self.cameras)), np.nan)
        ok = np.flatnonzero(stable)
        if ok.size:
            out[ok] = (
                self._batched(positions[ok], n - 1)
                if self.images_per_call > 1
                else self._one_at_a_time(SimpleNamespace(positions=positions), ok, n - 1)
            )
        return out

    def _one_at_a_time(self, run, stable, n_frames: int) -> np.ndarray:
        """[K, F, V] losses, one render and one loss per (frame, view), frames 1 .. n_frames."""
        t = ad()
        out = np.zeros((len(stable), n_frames, len(self.cameras)))
        with dr.suspend_grad():
            for i, s in enumerate(stable):
                for f in range(1, n_frames + 1):
                    x = run.positions[s, f].astype(np.float32)
                    g = posed(self.gaussians, self.binding.apply(t.Array3f(*x.T)))
                    for v, cam in enumerate(self.cameras):
                        loss = image_loss(render(g, cam, self.render_cfg).rgb, self.targets[f][v], self.lam)
                        out[i, f - 1, v] = float(np.asarray(to_numpy(loss)).reshape(-1)[0])
        return out

    def _batched(self, positions: np.ndarray, n_frames: int) -> np.ndarray:
        """The same [K, F, V] losses as `_one_at_a_time` (to float rounding) from `render_batch`
        and `image_losses`: about images_per_call images per program (whole frames of all views)."""
        t = ad()
        n_views = len(self.cameras)
        centres = batched_centres(self.binding, positions[:, 1 : n_frames + 1])  # [K, F, M, 3]
        poses = [(k, f) for k in range(centres.shape[0]) for f in range(n_frames)]
        per_call = max(1, self.images_per_call // n_views)
        image_losses_all = []
        with dr.suspend_grad():
            for start in range(0, len(poses), per_call):
                chunk = poses[start : start + per_call]
                tiled = {n: np.concatenate([v] * len(chunk)) for n, v in self.fields.items()}
                g = Gaussians.from_numpy(np.concatenate([centres[k, f] for k, f in chunk]), **tiled)
                pred = render_batch(g, len(chunk), self.cameras, self.render_cfg)
                target = self.stacked_targets[[f for _, f in chunk]].reshape((-1,) + self.stacked_targets.shape[2:])
                image_losses_all.append(
                    to_numpy(image_losses(pred, t.TensorXf(np.ascontiguousarray(target)), self.lam))
                )
        return np.concatenate(image_losses_all).astype(np.float64).reshape(centres.shape[0], n_frames, n_views)


def landscape(scorer: PopulationScorer, result: GlobalSearchResult, search_cfg, n_frames: int, n_fit: int) -> Landscape:
    """The futures of the candidates that fit about as well as the best (`Landscape`)."""
    order = np.argsort(result.losses, kind="stable")
    ok = result.losses[order] <= result.best_loss * (1.0 + float(search_cfg.equivalent_tolerance))
    chosen = [int(i) for i in order[ok][: max(1, int(search_cfg.top_k))]]
    values = {n: result.candidates[chosen, j] for j, n in enumerate(result.names)}
    run = scorer.rollout(values, int(n_frames))
    centres = np.nanmean(run.positions, axis=2)  # [K, T, 3]
    size = float(np.ptp(to_numpy(scorer.model.x_rest).T, axis=0).max())
    future = centres[:, int(n_fit) :]
    spread, medoid = 0.0, chosen[0]
    if len(chosen) > 1 and future.shape[1] > 0:
        d = np.linalg.norm(future[:, None] - future[None, :], axis=-1)  # [K, K, T_future]
        spread = float(np.nanmax(d)) / max(size, 1e-12)
        total = np.nansum(np.nanmean(d, axis=-1), axis=1)  # [K] summed mean distance to the others
        medoid = chosen[int(np.argmin(total))]  # argmin takes the first (the better fit) on a tie
    return Landscape(chosen, spread, spread > float(search_cfg.spread_warning), centres, medoid)


def stage_frames(schedule, n_fit_frames: int) -> list[int]:
    """`recon.search.frame_schedule` (shares of the fit frames after frame 0) -> the number of fit
    frames each stage scores (at least 1, non-decreasing, the last all of them)."""
    shares = [float(x) for x in schedule]
    if not shares or any(not 0.0 < x <= 1.0 for x in shares):
        raise SearchConfigError(f"recon.search.frame_schedule={list(schedule)}: each share must lie in (0, 1]")
    if shares[-1] != 1.0 or any(b < a for a, b in zip(shares, shares[1:])):
        raise SearchConfigError(
            f"recon.search.frame_schedule={list(schedule)}: the shares must not decrease and the last must be 1 "
            "(the whole fit window)"
        )
    return [max(1, min(n_fit_frames, int(round(x * n_fit_frames)))) for x in shares]


def stage_generations(generations: int, n_stages: int) -> list[int]:
    """The generations split evenly among the stages (the later ones get the remainder), each at
    least one."""
    g = max(int(generations), n_stages)
    base, rest = divmod(g, n_stages)
    return [base + (1 if i >= n_stages - rest else 0) for i in range(n_stages)]


def _stage_best(stage: dict, names) -> tuple[dict[str, float], float]:
    """The best-scoring candidate of a search stage (its values, its loss on the stage's frames)."""
    c, loss = np.concatenate(stage["candidates"]), np.concatenate(stage["losses"])
    j = int(np.argmin(loss))
    return {n: float(c[j, k]) for k, n in enumerate(names)}, float(loss[j])


def _record(stage: dict, space: SearchSpace, values: dict, losses: np.ndarray, generation: int) -> None:
    """Add scored candidates to a search stage's record."""
    stage["candidates"].append(np.stack([values[n] for n in space.names], axis=1))
    stage["losses"].append(losses)
    stage["generation"].append(np.full(losses.size, generation))


def distinct_starts(u: np.ndarray, losses: np.ndarray, first: np.ndarray, n: int, distance: float) -> np.ndarray:
    """Up to `n` starts [m, d] in unit coordinates: `first`, then the candidates `u` [S, d] in order of
    their `losses`, each taken when it lies at least `distance` (Euclidean, unit box) from every
    start taken before: the best of each region the earlier window liked, not its best's neighbours."""
    chosen = [np.asarray(first, float)]
    for i in np.argsort(losses, kind="stable"):
        if len(chosen) >= n:
            break
        if np.isfinite(losses[i]) and min(np.linalg.norm(u[i] - c) for c in chosen) >= distance:
            chosen.append(np.asarray(u[i], float))
    return np.stack(chosen)


def halving_phases(generations: int, n_starts: int) -> list[tuple[int, int]]:
    """(generations, starts kept) per phase of a multi-start stage: the generations split evenly
    over 1 + ceil(log2 n) phases, the starts halved (rounded up) after each, to one."""
    n_phases = 1 + int(math.ceil(math.log2(max(1, n_starts))))
    kept, out = n_starts, []
    for g in stage_generations(generations, n_phases):
        out.append((g, kept))
        kept = max(1, (kept + 1) // 2)
    return out


def coordinate_sweep(score, space: SearchSpace, u: np.ndarray, loss: float | None, n_points: int, record=None):
    """From unit coordinates `u` (its loss `loss`, or None: scored with the first line), each
    parameter in turn over `n_points` evenly spread values of its whole range, (i + 1/2) / n, the
    others at the best so far: one batch of `score` ({name: [S]} -> [S] losses) per parameter, the
    best of each moving the point. `record(values, losses)` sees every batch. Returns the best unit
    coordinates and their loss. A window that sees a parameter the previous one did not (the
    bounce's restitution in the later frames) finds its basin here, where CMA-ES, restarted with the
    small step the earlier window left it, closes in slowly (docs/posterior.md, "SBC at small")."""
    u = np.asarray(u, float).copy()
    grid = (np.arange(int(n_points)) + 0.5) / int(n_points)
    for i in range(u.size):
        trial = np.repeat(u[None, :], grid.size, axis=0)
        trial[:, i] = grid
        u, loss = _best_of(score, space, trial, u, loss, record)
    return u, loss


def _best_of(score, space: SearchSpace, trial: np.ndarray, u: np.ndarray, loss: float | None, record=None):
    """The unit points `trial` scored in one batch (`u` first when its loss is None; `record` sees
    the batch): the best of them and its loss where it beats `loss`, else `u` and `loss`."""
    if loss is None:
        trial = np.vstack([u[None, :], trial])
    values = space.values(trial)
    f = np.asarray(score(values), float)
    if record is not None:
        record(values, f)
    j = int(np.argmin(f))
    if loss is None or f[j] < loss:
        return trial[j].copy(), float(f[j])
    return u, loss


def contact_grid(score, space: SearchSpace, u: np.ndarray, loss: float | None, n_points: int, record=None):
    """From unit coordinates `u` (its loss `loss`, or None), friction and restitution together over an
    `n_points` x `n_points` grid of their ranges, (i + 1/2) / n each, the others kept: one batch of
    `score`, its best moving the point if it beats `loss`. The two act jointly through the contact
    (how long the object touches the ground decides how much friction acts): on a twin the truth's
    basin can show only where both are right, which a sweep of one at a time does not reach
    (docs/posterior.md, "The SBC's misses in friction and restitution"). Returns `u` unchanged where
    the space lacks either."""
    u = np.asarray(u, float).copy()
    if "friction" not in space.names or "restitution" not in space.names or n_points <= 0:
        return u, loss
    i, j = space.names.index("friction"), space.names.index("restitution")
    g = (np.arange(int(n_points)) + 0.5) / int(n_points)
    trial = np.repeat(u[None, :], g.size * g.size, axis=0)
    trial[:, i] = np.repeat(g, g.size)
    trial[:, j] = np.tile(g, g.size)
    return _best_of(score, space, trial, u, loss, record)


def global_search(
    scorer: PopulationScorer,
    space: SearchSpace,
    start: dict[str, float],
    search_cfg,
    seed: int,
    progress: bool = False,
) -> GlobalSearchResult:
    """CMA-ES (`cma`) over `space` from `start` (values; clipped into the box), or, with
    recon.search.initial_samples > 0, from the best of that many scrambled Sobol points over the
    whole box (scored first, generation -1); a population of recon.search.popsize candidates per
    generation, recon.search.generations generations; every candidate scored by `scorer`.

    With recon.search.frame_schedule = [s_1, ..., 1] the generations are split among stages that
    score the first s_i of the fit frames (the Sobol points on the first stage's); each later stage
    first scores the previous stage's best on its window and restarts CMA-ES there with the step
    size it had reached. With recon.search.line_points > 0 each stage's CMA-ES starts after a
    `coordinate_sweep` from its start (recorded with that stage's first generation).
    Only the last stage's candidates, scored on the whole window, are comparable with each other
    and with what the posterior evaluates: they are the result's candidates; the earlier stages
    are summarised in `stages`. Returns every such candidate and the best one.

    With recon.search.starts = n > 1 the last window runs n CMA-ES searches side by side (one
    batch): from the previous window's best (swept as above) and from the best of its other
    regions (`distinct_starts`, recon.search.start_distance apart in the unit box), each with the
    step the previous window reached; after each of 1 + ceil(log2 n) phases the worse half stops
    (`halving_phases`). One window's search settles in the basin nearest its start; the whole
    window's basins are narrow and lie behind valleys (docs/posterior.md, "The SBC's fourth draw")."""
    import cma

    d = len(space.names)
    if d == 0:
        raise SearchConfigError("recon.search.parameters: none of them applies to this physics configuration")
    popsize = int(search_cfg.popsize)
    if popsize < 2:
        raise SearchConfigError(f"recon.search.popsize={popsize} must be at least 2")
    n_fit = scorer.n_fit_frames
    frames = stage_frames(getattr(search_cfg, "frame_schedule", [1.0]), n_fit)
    gens = stage_generations(int(search_cfg.generations), len(frames))
    stages = [{"frames": f, "generations": g, "candidates": [], "losses": [], "generation": [], "n_swept": 0}
              for f, g in zip(frames, gens)]  # fmt: skip
    u0, loss0 = space.unit(start), None
    n0 = int(search_cfg.initial_samples)
    n_line = int(getattr(search_cfg, "line_points", 0))
    n_contact = int(getattr(search_cfg, "contact_points", 0))

    def window(stage: dict) -> int | None:
        return None if stage["frames"] == n_fit else stage["frames"]

    def sweep(stage: dict, u: np.ndarray, loss: float | None, generation: int) -> np.ndarray:
        if n_line <= 0 and n_contact <= 0:
            return u

        def record(values: dict, losses: np.ndarray) -> None:
            _record(stage, space, values, losses, generation)
            stage["n_swept"] += losses.size

        def score(v: dict) -> np.ndarray:
            return scorer(v, frames=window(stage))

        if n_line > 0:
            u, loss = coordinate_sweep(score, space, u, loss, n_line, record)
        if n_contact > 0:
            u, loss = contact_grid(score, space, u, loss, n_contact, record)
        log.info("dynamics: global search: sweeps on the first %d fit frames, best %.5f", stage["frames"],
                 loss)  # fmt: skip
        return u

    if n0 > 0:
        # a space-filling first look (scrambled Sobol points over the whole box): CMA-ES with a
        # small population settles in the basin nearest its start; this picks the start among basins
        from scipy.stats import qmc

        first = stages[0]
        u_all = qmc.Sobol(d, scramble=True, seed=int(seed)).random(n0)
        for chunk in range(0, n0, popsize):
            values = space.values(u_all[chunk : chunk + popsize])
            _record(first, space, values, scorer(values, frames=window(first)), -1)
        scored = np.concatenate(first["losses"])
        u0, loss0 = u_all[int(np.argmin(scored))], float(np.min(scored))
        log.info("dynamics: global search: %d space-filling samples, best %.5f", n0, loss0)
    u0 = sweep(stages[0], u0, loss0, 0)
    opts = {
        "bounds": [0.0, 1.0],
        "popsize": popsize,
        "seed": int(seed) + 1,  # cma reads 0 as "seed from the clock"
        "maxiter": int(sum(gens)),
        "verbose": -9,
        "tolfun": 0.0,
        "tolx": 1e-6,
    }
    es = cma.CMAEvolutionStrategy(u0.tolist(), float(search_cfg.sigma0), opts)
    n_starts = int(getattr(search_cfg, "starts", 1))
    multi = n_starts > 1 and len(stages) > 1
    plan = [(stage, g) for stage in (stages[:-1] if multi else stages) for g in range(stage["generations"])]
    steps = range(len(plan))
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="dynamics: global search", leave=False)
    for g in steps:
        stage = plan[g][0]
        if g > 0 and stage is not plan[g - 1][0] and plan[g - 1][0]["losses"]:
            # a new window: its first candidate is the last window's best, and CMA-ES starts again
            # there with the step it had reached (its mean may sit beside the best on a flat stretch)
            u_best = space.unit(_stage_best(plan[g - 1][0], space.names)[0])
            values = space.values(u_best[None, :])
            _record(stage, space, values, scorer(values, frames=window(stage)), g)
            u_best = sweep(stage, u_best, float(stage["losses"][-1][0]), g)
            sigma = max(float(es.sigma), 1e-3)
            es = cma.CMAEvolutionStrategy(u_best.tolist(), sigma, {**opts, "maxiter": len(plan) - g})
        if es.stop():  # converged: on to the next window (or done on the last)
            if stage is stages[-1]:
                break
            continue
        u = np.asarray(es.ask(), float)
        values = space.values(u)
        f = scorer(values, frames=window(stage))
        es.tell(list(u), f.tolist())
        _record(stage, space, values, f, g)
        best = float(np.min(np.concatenate(stage["losses"])))
        shown = "" if len(stages) == 1 else f" (first {stage['frames']} of {n_fit} fit frames)"
        log.info("dynamics: global search generation %d%s: best loss %.5f (this generation %.5f)", g, shown, best,
                 f.min())  # fmt: skip
        if progress:
            steps.set_postfix(best=f"{best:.4f}")
    if multi:
        _multistart_stage(scorer, space, stages[-2], stages[-1], len(plan), es.sigma, sweep, opts, n_starts,
                          float(getattr(search_cfg, "start_distance", 0.2)), progress)  # fmt: skip
    last = stages[-1]  # never empty: a stage's first generation always runs, and a later stage starts
    #                    with the previous one's best
    candidates = np.concatenate(last["candidates"])
    all_losses = np.concatenate(last["losses"])
    i = int(np.argmin(all_losses))
    summary = []
    for stage in stages[:-1]:
        best_values, best_loss = _stage_best(stage, space.names)
        n_eval = int(sum(x.size for x in stage["losses"]))
        summary.append(
            {"frames": stage["frames"], "n_evaluations": n_eval, "best_loss": best_loss, "best": best_values}
        )
    return GlobalSearchResult(
        names=space.names,
        candidates=candidates,
        losses=all_losses,
        generation=np.concatenate(last["generation"]),
        best={n: float(candidates[i, j]) for j, n in enumerate(space.names)},
        best_loss=float(all_losses[i]),
        n_substeps=scorer.n_t,
        image_scale=scorer.image_scale,
        lo=space.lo,
        hi=space.hi,
        stages=summary,
        n_swept=last["n_swept"],
    )


def _multistart_stage(
    scorer,
    space,
    previous: dict,
    stage: dict,
    g0: int,
    sigma: float,
    sweep,
    opts: dict,
    n_starts: int,
    distance: float,
    progress: bool = False,
) -> None:
    """The last window of `global_search` with recon.search.starts = n_starts > 1: the previous
    window's best (scored on this window, then swept) and its best distinct regions
    (`distinct_starts`) scored on this window, then a CMA-ES from each, side by side, the worse half
    stopping after each phase (`halving_phases`); every candidate recorded in `stage`."""
    import cma

    best_values, _ = _stage_best(previous, space.names)
    u_prev = np.stack([space.unit({n: c[k] for k, n in enumerate(space.names)})
                       for c in np.concatenate(previous["candidates"])])  # fmt: skip
    starts = distinct_starts(u_prev, np.concatenate(previous["losses"]), space.unit(best_values), n_starts, distance)
    values = space.values(starts)
    f0 = scorer(values, frames=None)
    _record(stage, space, values, f0, g0)
    u_main = sweep(stage, starts[0], float(f0[0]), g0)
    starts[0] = u_main
    step = max(float(sigma), 1e-3)
    runs = [cma.CMAEvolutionStrategy(u.tolist(), step, {**opts, "seed": int(opts["seed"]) + i, "maxiter": stage["generations"]})
            for i, u in enumerate(starts)]  # fmt: skip
    best = [float(v) for v in f0]
    best[0] = min(best[0], float(np.min(np.concatenate(stage["losses"]))))
    log.info("dynamics: global search: %d starts on the whole window, losses %s", len(starts),
             " ".join(f"{v:.5f}" for v in f0))  # fmt: skip
    active = list(range(len(runs)))
    g = g0
    for n_gen, n_keep in halving_phases(stage["generations"], len(runs)):
        active = sorted(active, key=lambda i: best[i])[:n_keep]
        for _ in range(n_gen):
            live = [i for i in active if not runs[i].stop()]
            if not live:
                break
            asked = [np.asarray(runs[i].ask(), float) for i in live]
            u = np.concatenate(asked)
            values = space.values(u)
            f = scorer(values, frames=None)
            _record(stage, space, values, f, g)
            for k, i in enumerate(live):
                fi = f[k * len(asked[k]) : (k + 1) * len(asked[k])]
                runs[i].tell(list(asked[k]), fi.tolist())
                best[i] = min(best[i], float(fi.min()))
            log.info("dynamics: global search generation %d (%d starts): best loss %.5f, per start %s", g, len(live),
                     min(best), " ".join(f"{best[i]:.5f}" for i in live))  # fmt: skip
            g += 1
