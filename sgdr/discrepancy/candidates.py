"""The candidate extensions a diagnosis fits, and how one is fitted and judged.

Each candidate (`CANDIDATES`, a registry) names the cause it stands for and the few values it
frees (`Param`s, searched within bounds; every one's 0 or 1 null is the base model). Its `apply`
turns those values into `physics.*` settings (`sgdr.physics.extensions`) and replacements of the
asset's identified values (e.g. a stiffness field). A candidate is fitted from the base fit: the
identified parameters are kept, only its own values are searched (scipy's bounded Brent search,
one value after another; `diagnose.evaluations` rollouts per value) to
minimise the discrepancy D (`diagnose.discrepancy`, `sgdr.discrepancy.measures`: by default the
mean absolute difference between the sequence's images and the asset rendered from the rollout)
summed over the *fitting* views. It is judged on the *held-out* views (every other view; never used for the
fit) by its gain over the base (`sgdr.discrepancy.run`).

The initial velocity is refitted with every candidate that changes the free fall (gravity, drag)
when the diagnosis observes the run's own sequence: the pipeline fitted v0 to its frames before
the hit frame under the base model's free fall, so a weaker gravity fitted alone would be judged
with a v0 that compensated for it. On another sequence (a twin simulated from the asset, whose
v0 it shares) the asset's v0 is kept. The fall is rigid
and closed-form (`sgdr.identify.velocity`), so the v0 that keeps the base's pre-hit trajectory
under the candidate's gravity and drag is a least-squares solve, not a search (`refit_v0`).

Why held-out views: one more free value always lowers the fitting loss a little; what transfers
to views the search never saw is what the data ask for. The threshold `diagnose.min_gain` is the
flexibility guard, calibrated on null data (docs/discrepancy.md).

Interval: per value, the range of the values the search evaluated whose fitting D lies within 5%
of the best one (a profile interval; coarse, from the search's own points).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar

from sgdr.physics import Ground
from sgdr.registry import Registry


@dataclass(frozen=True)
class Param:
    name: str  # the fitted value's name (diagnosis.json "values")
    low: float  # search interval, in object sizes when `relative`
    high: float
    relative: bool = False  # a length: the interval is in units of the object's size
    null: float = 0.0  # the value that gives the base model (where the search starts)


@dataclass
class Context:
    """What a candidate's `apply` may use: the asset's identified values and physics, the object's
    size, its rest anchors, and the free-fall frame times the pipeline fitted v0 on."""

    values: dict  # Asset.values (log10_k [N_A], kappa, friction, restitution, v0 [3], gravity [3])
    physics: object  # the asset's PhysicsConfig
    anchors: np.ndarray  # [N_A, 3] rest anchors
    size: float  # the anchors' bounding-box diagonal, scene units
    free_fall_times: np.ndarray  # [F] seconds of frames 1 .. hit_frame - 1


@dataclass(frozen=True)
class Candidate:
    cause: str  # the cause it stands for (diagnosis.json "cause")
    params: tuple  # Param, ...
    apply: Callable  # (Context, {name: value}, variant) -> (physics settings, value replacements)
    describes: str  # what it changes, for diagnosis.json and the docs
    variants: tuple = (None,)  # discrete choices (e.g. an axis): each screened, the best fitting searched in full
    # the frames it is fitted and judged on: "fit" (every fit frame) or "free_flight" (the fit frames
    # before the recorded hit frame, where it acts alone; sgdr.discrepancy.run)
    window: str = "fit"
    # the candidate this one nests (""): its fitted values of the same names start this one's search
    # (the tilt from the fitted offset: from offset 0 the first tilt sweep stands in for the offset)
    starts_from: str = ""

    def at_null(self, values: dict, size: float) -> bool:
        """Whether every fitted value lies within NULL_TOLERANCE of its search box from its null
        value: the candidate is then the base model, and whatever it gains is the controls' refit
        beside it, not the cause (sgdr.discrepancy.run)."""
        for p in self.params:
            scale = size if p.relative else 1.0
            if abs(float(values[p.name]) - p.null * scale) > NULL_TOLERANCE * (p.high - p.low) * scale:
                return False
        return True


# A fitted value this close to its null value, as a share of its search box, is the null value: 1%
# (ten times the search's own tolerance; a stiffness ratio of 10^0.03, a drag of 0.08 /s, a ground
# offset of 0.003 sizes). On the tiny twin 10^0.5 stiffer, ratios of 1e-5 decades "gained" 0.08 to
# 0.21 over the base from the controls' third sweep beside them (held-out D 1% lower, at the floor).
NULL_TOLERANCE = 0.01


def _fall_basis(c: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(φ, ψ) with x(t) = x0 + v0 φ(t) + g ψ(t) under linear drag c (1/s); c = 0: (t, t²/2)."""
    if c * float(np.max(t, initial=0.0)) < 1e-6:
        return t, 0.5 * t * t
    phi = -np.expm1(-c * t) / c
    return phi, (t - phi) / c


def refit_v0(ctx: Context, gravity_scale: float, air_drag: float) -> np.ndarray:
    """The v0 [3] whose free fall under (gravity_scale, air_drag) best matches, in least squares
    over the pre-hit frames, the base model's free fall with the identified v0 (module docstring);
    the identified v0 when there is no free-fall frame."""
    v0 = np.asarray(ctx.values["v0"], float).reshape(3)
    t = np.asarray(ctx.free_fall_times, float)
    if t.size == 0:
        return v0
    g = np.asarray(ctx.values["gravity"], float).reshape(3)
    phi0, psi0 = _fall_basis(float(ctx.physics.air_drag), t)
    target = phi0[:, None] * v0 + float(ctx.physics.gravity_scale) * psi0[:, None] * g
    phi, psi = _fall_basis(float(air_drag), t)
    rest = target - float(gravity_scale) * psi[:, None] * g
    return (phi @ rest) / float(phi @ phi)


def _free_fall(setting: str):
    def apply(ctx: Context, x: dict, _variant):
        settings = {setting: float(x["value"])}
        scale = settings.get("gravity_scale", float(ctx.physics.gravity_scale))
        drag = settings.get("air_drag", float(ctx.physics.air_drag))
        return settings, {"v0": refit_v0(ctx, scale, drag)}

    return apply


def _ground_offset(ctx: Context, x: dict, _variant):
    return {"ground_offset": float(ctx.physics.ground_offset) + float(x["offset"])}, {}


def _ground_tilt(ctx: Context, x: dict, _variant):
    """A tilt vector (degrees towards the plane's axes a and b, `sgdr.physics.extensions`) and an offset."""
    ta, tb = float(x["tilt_a_deg"]), float(x["tilt_b_deg"])
    return {
        "ground_offset": float(ctx.physics.ground_offset) + float(x["offset"]),
        "ground_tilt_deg": float(np.hypot(ta, tb)),
        "ground_tilt_azimuth_deg": float(np.degrees(np.arctan2(tb, ta))),
    }, {}


def halves(anchors: np.ndarray, axis: int) -> np.ndarray:
    """+1 for the anchors above the median along world `axis`, -1 below (the generator's split)."""
    a = np.asarray(anchors, float)[:, axis]
    return np.where(a > np.median(a), 1.0, -1.0)


def _two_stiffnesses(ctx: Context, x: dict, axis):
    """log10 k_i + r/2 on the upper half along `axis`, - r/2 on the lower: a ratio 10^r between halves."""
    field_ = np.asarray(ctx.values["log10_k"], float) + 0.5 * float(x["log10_ratio"]) * halves(ctx.anchors, axis)
    return {}, {"log10_k": field_}


def _plastic(ctx: Context, x: dict, _variant):
    return {"plastic_yield_strain": float(10.0 ** float(x["log10_yield_strain"]))}, {}


def _rebound(ctx: Context, x: dict, _variant):
    if ctx.physics.contact != "project":  # the coulomb law learns its own restitution: nothing to add
        return {}, {}
    return {"contact_restitution": float(x["value"])}, {}


CANDIDATES = Registry("diagnosis candidate", "diagnose.candidates", ValueError)
CANDIDATES["air_drag"] = Candidate(
    "air_drag",
    (Param("value", 0.0, 8.0),),
    _free_fall("air_drag"),
    "physics.air_drag (1/s), v0 refitted",
    window="free_flight",
)
CANDIDATES["gravity"] = Candidate(
    "gravity",
    (Param("value", 0.6, 1.4, null=1.0),),
    _free_fall("gravity_scale"),
    "physics.gravity_scale, v0 refitted",
    window="free_flight",
)
CANDIDATES["ground_plane"] = Candidate(
    "ground_plane",
    (Param("offset", -0.15, 0.15, relative=True),),
    _ground_offset,
    "physics.ground_offset (scene units)",
)
CANDIDATES["ground_tilt"] = Candidate(
    "ground_plane",
    (Param("tilt_a_deg", -12.0, 12.0), Param("tilt_b_deg", -12.0, 12.0), Param("offset", -0.15, 0.15, relative=True)),
    _ground_tilt,
    "physics.ground_tilt_deg / ground_tilt_azimuth_deg from a tilt vector, and physics.ground_offset",
    starts_from="ground_plane",
)
CANDIDATES["contact"] = Candidate(
    "contact",
    (Param("value", 0.0, 0.9),),
    _rebound,
    "physics.contact_restitution (the project contact's lost rebound; nothing under coulomb contact)",
)
CANDIDATES["plasticity"] = Candidate(
    "plasticity",
    (Param("log10_yield_strain", -2.5, -0.1, null=-0.1),),
    _plastic,
    "physics.plastic_yield_strain = 10^value (rest lengths yield beyond that strain; 0.8 is all but elastic)",
)
CANDIDATES["heterogeneous_stiffness"] = Candidate(
    "heterogeneous_stiffness",
    (Param("log10_ratio", -1.5, 1.5),),
    _two_stiffnesses,
    "the identified log10 k field + r/2 above the median of a world axis and - r/2 below (ratio 10^r)",
    variants=(0, 1, 2),
)


def _shift_stiffness(ctx: Context, x: dict, _variant):
    return {}, {"log10_k": np.asarray(ctx.values["log10_k"], float) + float(x["log10_k_shift"])}


def _replace_value(name: str):
    def apply(ctx: Context, x: dict, _variant):
        return {}, {name: float(x["value"])}

    return apply


def _restitution(ctx: Context, x: dict, _variant):
    if ctx.physics.contact != "coulomb":  # only the coulomb law reads e
        return {}, {}
    return {}, {"restitution": float(x["value"])}


# Refits of the base model's own parameters (cause "none"): what flexibility inside the base model
# class buys. `diagnose.rebase` fits them before the candidates, so that a candidate's gain is
# measured over a base that is as good as its own parameters allow on the measure: a base fit
# that is merely off (e.g. a stiffness the pipeline's loss placed elsewhere) would otherwise let
# every free extension buy a large gain (docs/discrepancy.md, the MPM nulls).
CONTROLS = Registry("base refit", "diagnose.rebase", ValueError)
CONTROLS["stiffness"] = Candidate(
    "none",
    (Param("log10_k_shift", -1.0, 1.0),),
    _shift_stiffness,
    "a global shift of the identified log10 k field (decades)",
)
# (one value each, searched over its whole box: the search start `null` is not used)
CONTROLS["friction"] = Candidate(
    "none", (Param("value", 0.0, 1.0),), _replace_value("friction"), "the ground friction μ"
)
CONTROLS["restitution"] = Candidate("none", (Param("value", 0.0, 1.0),), _restitution, "e of the coulomb contact")


@dataclass
class Fit:
    values: dict  # {param: fitted value}
    variant: object  # the discrete choice kept (None when the candidate has none)
    interval: dict  # {param: (low, high)} profile interval
    settings: dict  # the physics settings at the fit
    d_fit: float  # fitting-views D at the fit
    d_held_out: float  # held-out-views D at the fit
    d_future: float | None  # D over the future frames (all views), when the sequence has them
    evaluated: list = field(default_factory=list)  # [(variant, {param: value}, fitting D)] in search order
    # D over the held-out time (the fit window's last frames, all views: the open-loop rollout of
    # frames no fit saw), when the diagnosis holds them out (diagnose.held_out_time)
    d_time: float | None = None


class Evaluator:
    """D of the asset's rollouts with given physics settings and value replacements, on fitting /
    held-out views, the held-out time (`obs_time`: the fit window's last frames, all views; None
    when not held out) and future frames; positions are cached per (settings, replacements).
    score: (observation, positions [T, N_A, 3]) -> D [V, F] (`sgdr.discrepancy.measures`)."""

    def __init__(self, asset, rollout, obs_fit, obs_held, obs_future, score, obs_time=None):
        self.asset, self.rollout = asset, rollout
        self.values = dict(asset.values)  # the base's values and physics settings (`rebase` replaces them)
        self.settings: dict = {}
        self.obs_fit, self.obs_held, self.obs_future = obs_fit, obs_held, obs_future
        self.obs_time = obs_time
        self.score = score
        self.model, _ = asset.build()
        self.ground = Ground(asset.ground_point, asset.ground_normal)
        frames = [o.frames for o in (obs_fit, obs_held, obs_future, obs_time) if o is not None]
        self.n_frames = int(max(int(np.max(f)) for f in frames)) + 1
        self.cache: dict = {}
        self.scores: dict = {}

    @staticmethod
    def _key(settings: dict, values: dict | None) -> tuple:
        return (
            tuple(sorted(settings.items())),
            tuple((k, np.asarray(v, float).round(12).tobytes()) for k, v in sorted((values or {}).items())),
        )

    def positions(self, settings: dict, values: dict | None = None, n_frames: int | None = None) -> np.ndarray | None:
        """Anchor positions [T, N_A, 3] of the rollout with `settings` and `values`, None when it is
        unstable; n_frames: at least that many frames (default: up to the last observed one). The
        fitting and held-out views see the fit frames only, so a search's rollouts stop there and
        the future frames are simulated only for the fits that are judged on them (a rollout's
        first frames do not depend on how long it runs: the same positions, unless the longer one
        needed more substeps to stay stable to its end; one unstable early is unstable longer)."""
        values = values or {}
        key = self._key(settings, values)
        n = self.n_frames if n_frames is None else min(int(n_frames), self.n_frames)
        done = self.cache.get(key)  # (frames simulated, positions or None: unstable within them)
        if done is None or (done[0] < n and done[1] is not None):
            cfg = replace(self.asset.physics, **{**self.settings, **settings})
            pos, stable = self.rollout(
                self.model,
                {**self.values, **values},
                {"log10_k_shift": np.zeros(1)},
                self.ground,
                n,
                1.0 / self.asset.fps,
                self.asset.n_substeps,
                cfg,
            )
            self.cache[key] = (n, pos[0] if stable[0] else None)
        return self.cache[key][1]

    def rebase(self, values: dict, settings: dict | None = None) -> None:
        """Replace base values and physics settings (what every later rollout starts from); the
        cached rollouts, keyed by what differs from the base, no longer hold."""
        self.values = {**self.values, **values}
        self.settings = {**self.settings, **(settings or {})}
        self.cache.clear()
        self.scores.clear()

    def reset(self, values: dict, settings: dict) -> None:
        """Back to a saved base (`values`, `settings`)."""
        self.values, self.settings = dict(values), dict(settings)
        self.cache.clear()
        self.scores.clear()

    def per_view_frame(self, settings: dict, obs, values: dict | None = None) -> np.ndarray | None:
        """D [V, F] of one rollout, None when it is unstable (cached per rollout and observation:
        a rendered measure costs as much as the rollout)."""
        pos = self.positions(settings, values, int(np.max(obs.frames)) + 1)
        if pos is None:
            return None
        key = (self._key(settings, values), id(obs))
        if key not in self.scores:
            self.scores[key] = np.asarray(self.score(obs, pos), float)
        return self.scores[key]

    def d(self, settings: dict, obs, values: dict | None = None) -> float:
        d = self.per_view_frame(settings, obs, values)
        return float("inf") if d is None else float(np.sum(d))

    def d_or_none(self, settings: dict, obs, values: dict | None = None) -> float | None:
        """`d` on an optional observation (the future frames, the held-out time): None without it."""
        return None if obs is None else self.d(settings, obs, values)


def _search(objective, bounds: list, x0: np.ndarray, evaluations: int) -> np.ndarray:
    """The minimiser of `objective` within `bounds`: a bounded Brent search of at most
    `evaluations` rollouts per value, one value after another from x0 (one coordinate sweep:
    each value of a multi-value candidate gets its own budget, which Powell's line searches
    spent on the first direction)."""

    x = np.asarray(x0, float).copy()
    for i, (lo, hi) in enumerate(bounds):

        def along(v, i=i):
            y = x.copy()
            y[i] = v
            return objective(y)

        res = minimize_scalar(
            along, bounds=(lo, hi), method="bounded", options={"maxiter": int(evaluations), "xatol": 1e-3 * (hi - lo)}
        )
        x[i] = float(res.x)
    return np.clip(x, [b[0] for b in bounds], [b[1] for b in bounds])


def fit_candidate(ev: Evaluator, cand: Candidate, ctx: Context, evaluations: int, start: dict | None = None) -> Fit:
    """The candidate's values that minimise D on the fitting views; the search starts at the null
    values, or at `start`'s for the names it holds (clipped into the bounds)."""
    names = [p.name for p in cand.params]
    bounds = [
        (p.low * (ctx.size if p.relative else 1.0), p.high * (ctx.size if p.relative else 1.0)) for p in cand.params
    ]
    x0 = np.array([float((start or {}).get(p.name, p.null)) for p in cand.params], float)
    x0 = np.clip(x0, [b[0] for b in bounds], [b[1] for b in bounds])
    evaluated: list = []

    def objective(x, variant):
        values = dict(zip(names, (float(v) for v in x)))
        settings, repl = cand.apply(ctx, values, variant)
        d = ev.d(settings, ev.obs_fit, repl)
        evaluated.append((variant, values, d))
        return d

    # several variants: each screened with half the budget, the best one searched in full
    variants = list(cand.variants)
    if len(variants) > 1:
        screen = max(4, int(evaluations) // 2)
        scores = [objective(_search(lambda x, v=v: objective(x, v), bounds, x0, screen), v) for v in variants]
        variants = [variants[int(np.argmin(scores))]]
    variant = variants[0]
    x = _search(lambda x: objective(x, variant), bounds, x0, evaluations)
    objective(x, variant)
    variant, values, d_best = min((e for e in evaluated if e[0] == variant), key=lambda e: e[2])
    near = [vals for var, vals, d in evaluated if var == variant and d <= 1.05 * d_best]
    interval = {n: (float(min(v[n] for v in near)), float(max(v[n] for v in near))) for n in names}
    settings, repl = cand.apply(ctx, values, variant)
    return Fit(
        values=values,
        variant=variant,
        interval=interval,
        settings=settings,
        d_fit=ev.d(settings, ev.obs_fit, repl),
        d_held_out=ev.d(settings, ev.obs_held, repl),
        d_future=None if ev.obs_future is None else ev.d(settings, ev.obs_future, repl),
        evaluated=evaluated,
        d_time=None if ev.obs_time is None else ev.d(settings, ev.obs_time, repl),
    )
