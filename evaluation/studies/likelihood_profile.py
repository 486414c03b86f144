"""How sharp the rendered likelihood is around a point: the posterior's image loss (`RenderedImages`,
the scale and views the posterior uses) at a centre and with each sampled parameter moved alone.

    python -m evaluation.studies.likelihood_profile posterior.run=outputs/torus_small_s0 preset=small \\
        posterior.sequence=outputs/calibration_small/case_000/twin \\
        +posterior_json=outputs/calibration_small/case_000/posterior/posterior.json +centre=truth

`+centre` is a section of the posterior.json holding one value per sampled parameter (`truth`,
`map`, or `likelihood.reference`); `+steps=name:a,b,...;name:...` overrides the offsets (the
defaults below). Prints one JSON object: the centre, its mean loss per view-frame, and per
parameter the offsets and their losses, each also per fit frame (the mean over the views: how the
basin narrows as the rollout goes on; docs/posterior.md, "SBC at small").
`+at=truth,likelihood.reference,diagnostics.median` instead prints the posterior's own
log-likelihood and loss at each of those sections (`log_likelihood_at`);
`+line=diagnostics.median:truth` (`+fractions=0,0.25,0.5,0.75,1`, the default) on the straight line
between two sections (`log_likelihood_on_line`: a ridge or a valley between them).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

import sgdr.backend
from evaluation.studies.config import split_extra
from sgdr.cli import user_errors
from sgdr.config import compose, validate
from sgdr.posterior.run import rendered_images
from sgdr.posterior.sample import Problem
from sgdr.run_folder import run_asset_and_sequence

STEPS = {
    "log10_k_shift": [-0.2, -0.1, -0.05, -0.02, 0.02, 0.05, 0.1, 0.2],
    "kappa": [-1.0, -0.3, -0.1, 0.1, 0.3, 1.0],
    "friction": [-0.2, -0.05, 0.05, 0.2],
    "restitution": [-0.2, -0.05, 0.05, 0.2],
}


def parse_steps(text: str | None) -> dict:
    """'name:a,b;name:c' -> {name: [a, b], ...}; None: `STEPS`."""
    if not text:
        return dict(STEPS)
    out = {}
    for part in text.split(";"):
        name, _, values = part.partition(":")
        try:
            out[name.strip()] = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise SystemExit(f"error: +steps={text}: expected name:a,b;name:c") from None
    return out


def centre_of(posterior: dict, key: str, names: list[str], where: str) -> np.ndarray:
    """One value per sampled parameter from a posterior.json section (`likelihood.reference` reads
    nested keys)."""
    section = posterior
    for k in key.split("."):
        section = section.get(k) if isinstance(section, dict) else None
    if not isinstance(section, dict) or any(n not in section for n in names):
        raise SystemExit(f"error: {where}: +centre={key} does not hold a value for each of {names}")
    return np.array([float(section[n]) for n in names])


def profile(cfg, centre: np.ndarray, names: list[str], steps: dict) -> dict:
    """The mean loss per view-frame at `centre` and with each parameter of `steps` moved alone."""
    unknown = [n for n in steps if n not in names]
    if unknown:
        raise SystemExit(f"error: +steps: {unknown} not sampled (posterior.parameters: {names})")
    pc = cfg.posterior
    _, asset, _, seq = run_asset_and_sequence(Path(pc.run), pc.sequence, cfg.scene_file, "posterior")
    problem = Problem.from_config(asset, pc)
    images = rendered_images(cfg, Path(pc.run), asset, seq, problem)
    thetas, labels = [centre], [(None, 0.0)]
    for name, offsets in steps.items():
        for d in offsets:
            t = centre.copy()
            t[names.index(name)] += d
            thetas.append(t)
            labels.append((name, d))
    per_frame = np.asarray(images(np.array(thetas)), float).mean(axis=2)  # [S, F]: mean over the views
    losses = per_frame.mean(axis=1)
    out = {
        "centre": dict(zip(names, centre.tolist())),
        "centre_loss": float(losses[0]),
        "centre_per_frame": per_frame[0].tolist(),
        "moved": {},
    }
    for (name, d), loss, frames in zip(labels[1:], losses[1:], per_frame[1:]):
        out["moved"].setdefault(name, []).append({"offset": d, "loss": float(loss), "per_frame": frames.tolist()})
    return out


def _posterior_log_likelihood(cfg, posterior: dict, thetas: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The posterior's own rendered log-likelihood (its recorded noise, discrepancy and temperature)
    at each θ [S, D], and the losses [S, F, V] behind it."""
    from sgdr.posterior.likelihood import RenderedLikelihood

    lk = posterior.get("likelihood") or {}
    if lk.get("kind") != "rendered":
        raise SystemExit(f"error: {where}: +at and +line need a posterior with the rendered likelihood")
    pc = cfg.posterior
    _, asset, _, seq = run_asset_and_sequence(Path(pc.run), pc.sequence, cfg.scene_file, "posterior")
    images = rendered_images(cfg, Path(pc.run), asset, seq, Problem.from_config(asset, pc))
    like = RenderedLikelihood(
        float(lk["noise"]), np.asarray(lk["discrepancy_per_frame"], float), float(lk["temperature"])
    )
    losses = np.asarray(images(thetas), float)  # [S, F, V]
    if losses.shape[1] != like.scale.size:
        raise SystemExit(f"error: {where}: {like.scale.size} frames in its likelihood, {losses.shape[1]} rendered here")
    return like.log_likelihood(losses), losses


def log_likelihood_at(cfg, posterior: dict, keys: list[str], where: str) -> dict:
    """The posterior's own log-likelihood and mean loss per view-frame at each section `keys` of its
    posterior.json (e.g. `truth`, `likelihood.reference`, `diagnostics.median`): whether a twin's
    truth fits its images better than where the posterior sits (a design search that missed the
    truth's basin) or worse (a posterior too narrow around the right place)."""
    names = list(posterior["names"])
    thetas = np.stack([centre_of(posterior, k, names, where) for k in keys])
    ll, losses = _posterior_log_likelihood(cfg, posterior, thetas, where)
    return {
        "n_view_frames": int(losses[0].size),
        "at": {k: {"log_likelihood": float(v), "loss": float(np.mean(x))} for k, v, x in zip(keys, ll, losses)},
    }


def log_likelihood_on_line(cfg, posterior: dict, ends: tuple[str, str], fractions: list[float], where: str) -> dict:
    """The posterior's own log-likelihood on the straight line between two sections of its
    posterior.json (e.g. `diagnostics.median` and `truth`), at `fractions` of the way: whether the
    two are joined by a ridge the likelihood keeps high (a posterior that should reach the truth and
    does not: its surrogate never saw that stretch) or parted by a valley (another basin)."""
    names = list(posterior["names"])
    a, b = (centre_of(posterior, k, names, where) for k in ends)
    t = np.asarray(fractions, float)
    ll, losses = _posterior_log_likelihood(cfg, posterior, a[None] + t[:, None] * (b - a)[None], where)
    return {
        "line": list(ends),
        "n_view_frames": int(losses[0].size),
        "points": [
            {"fraction": float(f), "log_likelihood": float(v), "loss": float(np.mean(x))}
            for f, v, x in zip(t, ll, losses)
        ],
    }


def parse_line(text: str, fractions: str | None) -> tuple[tuple[str, str], list[float]]:
    """'+line=A:B' (two posterior.json sections) and '+fractions=0,0.5,1' -> ((A, B), [fractions])."""
    a, sep, b = str(text).partition(":")
    if not sep or not a.strip() or not b.strip():
        raise SystemExit(f"error: +line={text}: expected two sections, e.g. +line=diagnostics.median:truth")
    try:
        ts = [float(x) for x in str(fractions or "0,0.25,0.5,0.75,1").split(",") if x.strip()]
    except ValueError:
        raise SystemExit(f"error: +fractions={fractions}: expected numbers, e.g. 0,0.5,1") from None
    if not ts:
        raise SystemExit("error: +fractions: none given")
    return (a.strip(), b.strip()), ts


def main(argv: list[str]) -> None:
    extra, overrides = split_extra(argv)
    with user_errors():
        cfg = OmegaConf.to_object(compose(overrides))
        validate(cfg)
        if "posterior_json" not in extra:
            raise SystemExit("error: +posterior_json=<a posterior.json> is needed (its section +centre is the centre)")
        where = extra["posterior_json"]
        posterior = json.loads(Path(where).read_text())
        names = list(posterior["names"])
        sgdr.backend.init(cfg.backend, cfg.threads or None)
        if "line" in extra:
            ends, fractions = parse_line(extra["line"], extra.get("fractions"))
            print(json.dumps(log_likelihood_on_line(cfg, posterior, ends, fractions, where)))
            return
        if "at" in extra:
            print(json.dumps(log_likelihood_at(cfg, posterior, str(extra["at"]).split(","), where)))
            return
        centre = centre_of(posterior, extra.get("centre", "truth"), names, where)
        print(json.dumps(profile(cfg, centre, names, parse_steps(extra.get("steps")))))


if __name__ == "__main__":
    main(sys.argv[1:])
