"""Whether a run's result is any good, in words: the verdict, the warnings and the parameter table
that open `report.html` (`sgdr.report.html`). Pure functions of the run's values (the
evaluate stage's scores, the dynamics and velocity stages' values, the config); no files.

Verdict rules (also in docs/report.md):

- Fit quality, from the mean PSNR of the re-simulated fit frames over all views (`fit_psnr`):
  good >= 28 dB (`FIT_PSNR_GOOD`), fair >= 22 dB (`FIT_PSNR_FAIR`), poor below; unknown when it
  was not computed. The fit Chamfer distance is stated beside it when the sequence has
  ground-truth particles.
- Future, against the physics-free baseline (`baseline_future_cd`: the better of "ballistic"
  and "held still", sgdr.evaluate.baselines): the ratio future CD / baseline CD; "better" when
  < 1, "worse" otherwise. The constant-velocity extrapolation is named when it beats the model.
  Without ground-truth particles (no gt/) the future cannot be scored geometrically: the
  verdict says so and gives the image PSNR of the future frames only ("not scored"); a future
  CD without a baseline (fewer than 2 fit frames) is stated without a comparison.

Warnings:
- identified parameters at the bounds of their allowed range: half or more of the anchors'
  log10 k_i (or their mean) at `recon.log10_k_min` / `recon.log10_k_max`; the coarse start
  chosen at either end of `recon.log10_k_grid` (the best value may lie outside the grid);
  friction at 0 or `recon.friction_max`; restitution at 0 or 1 (only with
  `physics.contact=coulomb`, the contact that uses it);
- the loss not decreasing: the deterministic rollout loss after training
  (`eval_loss_final`) not below the one before (`eval_loss_initial`), or the last dynamic
  pass's training loss above the first's;
- the future prediction worse than any baseline variant (still, constant velocity, ballistic);
- no dynamic pass ran and no global search either (the physical parameters are the initial guesses);
- the global search's landscape (recon.search): candidates that fit about equally well
  (`recon.search.equivalent_tolerance`) predicting centres of mass that part by more than
  `recon.search.spread_warning` x the object's size after the fit window; a best value at the
  end of its search range;
- springs that should conserve momentum (physics.springs=symmetric) pushing the predicted
  centre of mass by more than `recon.momentum_tolerance` (scene units / s; the predict stage's
  momentum audit, `sgdr.asset.momentum`): a bug. The official directed springs never conserve
  momentum; how much they add is stated under the parameters (`momentum_note`), not warned
  about: on the small torus they add 2-3 scene units/s along the ground and 19-27 into it in
  good and bad runs alike, and the ground contact absorbs most of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

FIT_PSNR_GOOD = 28.0  # dB: fit frames at least this close to the input images are "good"
FIT_PSNR_FAIR = 22.0  # dB: "fair" from here up to FIT_PSNR_GOOD, "poor" below
AT_BOUND = 1e-3  # a parameter within this of a bound of its range is "at the bound"
BOUND_SHARE = 0.5  # warn when at least this share of the anchors' log10 k_i sit at a bound


@dataclass
class Verdict:
    fit_quality: str  # "good" | "fair" | "poor" | "unknown"
    future: str  # "better" | "worse" (than the physics-free baseline) | "not scored" (no CD or no baseline)
    headline: str  # one line: the fit quality and the future against the baseline
    sentences: list[str] = field(default_factory=list)  # the verdict in a few plain sentences
    warnings: list[str] = field(default_factory=list)


def _num(x: float) -> str:
    """Three significant digits, trailing zeros kept ("2.00", "0.449", "12.3", "123")."""
    return f"{x:#.3g}".rstrip(".")


def _finite(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def fit_verdict(scores: dict) -> tuple[str, str]:
    """(quality, sentence) of the dynamic reconstruction from fit_psnr (and fit_cd)."""
    psnr = _finite(scores.get("fit_psnr"))
    if psnr is None:
        why = scores.get("missing", {}).get("fit_psnr", "it was not computed")
        return "unknown", f"The fit cannot be judged: there is no image PSNR of the fit frames ({why})."
    quality = "good" if psnr >= FIT_PSNR_GOOD else "fair" if psnr >= FIT_PSNR_FAIR else "poor"
    text = (
        f"The fit is {quality}: re-simulated from frame 0 with the identified physics, the fit frames match the "
        f"input images at {psnr:.1f} dB PSNR (good from {FIT_PSNR_GOOD:g} dB, fair from {FIT_PSNR_FAIR:g} dB)"
    )
    cd = _finite(scores.get("fit_cd"))
    if cd is not None:
        text += f"; the predicted shapes are at Chamfer distance {_num(cd)} (x1e3) from the ground-truth particles"
    return quality, text + "."


def _times(a: float, b: float) -> str:
    """ "2.9x" for a / b >= 1.5, "4.5%" below (a 1.045 ratio is not "1.0x"), the degenerate
    ratios in words."""
    if b > 0:
        r = a / b
        return f"{r:.1f}x" if r >= 1.5 - 1e-9 else f"{100.0 * (r - 1.0):.1f}%"
    return "infinitely" if a > 0 else "0%"


def future_verdict(scores: dict) -> tuple[str, str, list[str]]:
    """("better" | "worse" | "not scored", headline part, sentences) of the future against the
    baselines."""
    cd, base = _finite(scores.get("future_cd")), _finite(scores.get("baseline_future_cd"))
    missing = scores.get("missing", {})
    if cd is not None and base is None:
        why = missing.get("baseline_future_cd", "it was not computed")
        text = (
            f"The future prediction (Chamfer distance {_num(cd)}) has no physics-free baseline to compare with: {why}."
        )
        return "not scored", "future not compared with a baseline", [text]
    if cd is None or base is None:
        why = missing.get("future_cd") or missing.get("baseline_future_cd") or "it was not computed"
        text = f"The future cannot be scored geometrically: {why}."
        psnr = _finite(scores.get("future_psnr"))
        if psnr is not None:
            fit = _finite(scores.get("fit_psnr"))
            text += f" On the future frames the predicted images match the video at {psnr:.1f} dB PSNR"
            text += f" (fit frames: {fit:.1f} dB)." if fit is not None else "."
        return "not scored", "future not scored geometrically", [text]
    variant = str(scores.get("baseline_variant", "")).replace("_", " ")
    against = (
        f"Chamfer distance {_num(cd)} against {_num(base)} for the better of 'ballistic' and 'held still' ({variant})"
    )
    if cd < base:
        verdict, factor = "better", _times(base, cd)
        out = [f"The future prediction beats the physics-free baseline: {against}, {factor} better."]
    else:
        verdict, factor = "worse", _times(cd, base)
        out = [
            f"The future prediction is worse than the physics-free baseline: {against}, {factor} worse. The "
            "identified physics does not predict the future better than not simulating at all."
        ]
    cv = _finite(scores.get("baseline_future_cd_by_variant", {}).get("constant_velocity"))
    if cv is not None and cv < cd:
        out.append(
            f"A constant-velocity extrapolation of the last two fit frames (not part of the baseline's definition) "
            f"does better too: Chamfer distance {_num(cv)}."
        )
    return verdict, f"future {factor} {verdict} than the physics-free baseline", out


def _bound_warnings(dyn: dict, recon_cfg, physics_cfg) -> list[str]:
    out = []
    k = np.asarray(dyn["log10_k"], float).reshape(-1)
    lo, hi = float(recon_cfg.log10_k_min), float(recon_cfg.log10_k_max)
    for name, bound, at in (
        ("lower", lo, k <= lo + AT_BOUND),
        ("upper", hi, k >= hi - AT_BOUND),
    ):
        if at.mean() >= BOUND_SHARE or abs(k.mean() - bound) <= AT_BOUND:
            field_name = "recon.log10_k_min" if name == "lower" else "recon.log10_k_max"
            out.append(
                f"Stiffness at the {name} bound: {100 * at.mean():.0f}% of the anchors' log10 k_i (mean "
                f"{k.mean():.3g}) sit at {field_name} = {bound:g}; the fit wants a stiffness outside the allowed range."
            )
    grid = [float(v) for v in (recon_cfg.log10_k_grid or [])]
    losses = dyn.get("log10_k_grid_losses") or {}
    if len(grid) >= 2 and losses:
        best = float(min(losses, key=losses.get))
        if best <= min(grid) + AT_BOUND or best >= max(grid) - AT_BOUND:
            end = "lowest" if best <= min(grid) + AT_BOUND else "highest"
            out.append(
                f"The coarse stiffness start log10 k = {best:g} is the {end} value of recon.log10_k_grid "
                f"{grid}: the best start may lie outside the grid; extend it."
            )
    mu, mu_max = float(dyn["friction"]), float(recon_cfg.friction_max)
    if mu <= AT_BOUND:
        out.append("Friction at its lower bound 0: the fit wants no friction at all.")
    elif mu >= mu_max - AT_BOUND:
        out.append(f"Friction at its upper bound recon.friction_max = {mu_max:g}.")
    if physics_cfg.contact == "coulomb":
        e = float(dyn["restitution"])
        if e <= AT_BOUND or e >= 1.0 - AT_BOUND:
            out.append(f"Restitution at the bound {round(e):d} of its range [0, 1].")
    return out


def _search_warnings(dyn: dict) -> list[str]:
    """The global search's doubts: equally good candidates predicting different futures, and a
    best value at the edge of its search range."""
    search = dyn.get("search") or {}
    out = []
    land = search.get("landscape") or {}
    if land.get("ambiguous"):
        out.append(
            f"{len(land.get('equivalent') or [])} candidates of the global search fit the fit frames about equally well "
            f"but predict futures whose centres of mass part by {float(land['future_spread']):.2g} x the object's size: "
            "the fit frames do not determine the physics; trust the prediction less (see Identification)."
        )
    for name, lo, hi in zip(search.get("names") or [], search.get("lo") or [], search.get("hi") or []):
        v = float(search["best"][name])
        tol = AT_BOUND * max(1.0, abs(float(hi) - float(lo)))
        if v <= float(lo) + tol or v >= float(hi) - tol:
            side, key = (
                ("lower", f"recon.search.{name}_range")
                if v <= float(lo) + tol
                else ("upper", f"recon.search.{name}_range")
            )
            if name == "log10_k" and side == "upper":
                key += " or the stability bound at n_t (raise physics.n_substeps)"
            out.append(f"The global search's best {name} = {v:.4g} is at the {side} end of its range ({key}).")
    return out


def _loss_warnings(dyn: dict) -> list[str]:
    out = []
    passes = list(dyn.get("pass_losses") or [])
    searched = bool(dyn.get("search"))  # the global stage's best is the start: no pass may be needed
    if not passes and not searched:
        out.append("No dynamic pass ran (recon.iterations = 0): the physical parameters are the initial guesses.")
    a, b = _finite(dyn.get("eval_loss_initial")), _finite(dyn.get("eval_loss_final"))
    kept_start = searched and int(dyn.get("best_pass", 0)) < 0  # no pass beat the start: the start was kept
    if a is None or b is None:
        if passes:
            out.append("The rollout loss before or after training is not a finite number.")
    elif b > a or (b == a and not kept_start):
        out.append(
            f"The loss did not decrease: the all-view rollout loss is {b:.4g} after training against {a:.4g} before."
        )
    if len(passes) >= 2 and passes[-1] > passes[0]:
        out.append(
            f"The training loss rose over the dynamic passes: {passes[0]:.4g} in the first pass, {passes[-1]:.4g} "
            "in the last (it is noisy: random cameras per pass)."
        )
    return out


def baseline_warnings(scores: dict) -> list[str]:
    cd = _finite(scores.get("future_cd"))
    if cd is None:
        return []
    out = []
    for name, b in (scores.get("baseline_future_cd_by_variant") or {}).items():
        b = _finite(b)
        if b is not None and b < cd:
            out.append(
                f"The future prediction (Chamfer distance {_num(cd)}) is worse than the physics-free "
                f"'{name.replace('_', ' ')}' baseline ({_num(b)}), {_times(cd, b)} worse."
            )
    return out


def _momentum_warnings(momentum: dict | None, recon_cfg) -> list[str]:
    """Springs that should conserve momentum but pushed the centre of mass beyond the tolerance.
    (The directed springs never conserve it: `momentum_note` states how much they add.)"""
    if not momentum or momentum.get("springs") == "directed":
        return []
    push = _finite(momentum.get("springs_dv_max"))
    tol = float(recon_cfg.momentum_tolerance)
    if push is None or push <= tol:
        return []
    return [
        f"The predicted motion gains momentum without an external cause: its springs "
        f"(physics.springs={momentum.get('springs')}, which should conserve momentum) push the centre of mass by "
        f"up to {_num(push)} scene units/s (tolerance {_num(tol)}, recon.momentum_tolerance): a bug, please report it."
    ]


def momentum_note(momentum: dict) -> str:
    """What the springs of the predicted rollout add to the momentum on their own, in words."""
    along, normal = momentum.get("springs_dv_max_along_ground"), momentum.get("springs_dv_max_along_normal")
    ground = momentum.get("ground_dv_end_along_ground")
    if momentum.get("springs") != "directed":
        return (
            f"Momentum: the springs (physics.springs={momentum.get('springs')}) add {_num(float(along or 0))} scene "
            "units/s along the ground on their own (they conserve momentum: only gravity and the ground act)."
        )
    return (
        f"Momentum: the directed springs (physics.springs=directed, the official model) do not conserve momentum. "
        f"Over the predicted rollout they push the centre of mass by up to {_num(float(along))} scene units/s along "
        f"the ground and {_num(float(normal))} into or away from it, with nothing external acting; the ground "
        f"contact absorbs most of it (its friction took {_num(float(ground))} along the ground by the last frame). "
        "On a slippery ground, or with edited friction, this push moves the object on its own "
        "(experiments/simulate.py warns); physics.springs=symmetric conserves momentum."
    )


def judge(scores: dict, dyn: dict, recon_cfg, physics_cfg, momentum: dict | None = None) -> Verdict:
    """The verdict and warnings of one run (the rules in the module docstring); momentum: the
    predict stage's momentum audit (`sgdr.asset.predict.audit_momentum`), if made."""
    fit, fit_text = fit_verdict(scores)
    future, future_head, future_text = future_verdict(scores)
    warnings = _bound_warnings(dyn, recon_cfg, physics_cfg) + _loss_warnings(dyn) + baseline_warnings(scores)
    warnings += _momentum_warnings(momentum, recon_cfg) + _search_warnings(dyn)
    return Verdict(fit, future, f"Fit {fit}, {future_head}.", [fit_text, *future_text], warnings)


def parameter_rows(dyn: dict, velocity: dict, recon_cfg, physics_cfg) -> list[tuple[str, str, str]]:
    """(parameter, identified value, allowed range) for every identified quantity."""
    k = np.asarray(dyn["log10_k"], float).reshape(-1)
    lo, hi = float(recon_cfg.log10_k_min), float(recon_cfg.log10_k_max)
    start = f"start {physics_cfg.log10_k_init:g} (physics.log10_k_init)"
    if recon_cfg.log10_k_grid:
        start = f"start chosen from recon.log10_k_grid {list(recon_cfg.log10_k_grid)}"
    rows = [
        (
            "log10 k_i, spring stiffness per anchor",
            f"mean {k.mean():.3f}, std {k.std():.3f}, min {k.min():.3f}, max {k.max():.3f} ({k.size} anchors)",
            f"[{lo:g}, {hi:g}] (recon.log10_k_min, recon.log10_k_max); {start}",
        ),
        ("κ, soft-vector coefficient", f"{float(dyn['kappa']):.4g}", "unbounded"),
        (
            "μ, friction" + (" (per substep)" if physics_cfg.contact == "project" else " (Coulomb coefficient)"),
            f"{float(dyn['friction']):.4g}",
            f"[0, {float(recon_cfg.friction_max):g}] (recon.friction_max)",
        ),
    ]
    if physics_cfg.contact == "coulomb":
        rows.append(("e, restitution", f"{float(dyn['restitution']):.4g}", "[0, 1]"))
    else:
        rows.append(("e, restitution", "not used", f"physics.contact = {physics_cfg.contact} has no restitution"))
    v0 = np.asarray(velocity["v0"], float)
    frames = velocity.get("frames") or []
    rows.append(
        (
            "v0, initial velocity (scene units/s)",
            "(" + ", ".join(f"{x:.3f}" for x in v0) + f"), |v0| = {np.linalg.norm(v0):.3f}",
            "unbounded; fitted on frames " + (f"{min(frames)}..{max(frames)}" if frames else "(none)"),
        )
    )
    rows.append(
        (
            "n_t, substeps per frame",
            f"{int(dyn['n_substeps'])}",
            f"physics.n_substeps = {physics_cfg.n_substeps} x recon.substep_growth {list(recon_cfg.substep_growth)}",
        )
    )
    return rows
