"""`report.html`: one self-contained page per run that says whether the result is any good.

Readable without the code and without a server: every image and video is embedded as a data
URI, the styles are inline, there is no script and nothing is fetched. The page opens with the
verdict (`sgdr.report.verdict`: fit quality, the future against the physics-free baselines,
in words), then the warnings, then one `Section` after another.

Adding a section (the posterior, discrepancy and table issues): write a function that returns
a `Section(title, body_html)`, building its body with `image`, `video`, `table`, `paragraph`
(or any HTML fragment whose text is escaped with `esc`), and either append it to the sections
the report stage passes to `write_report` (`run_sections` in `sgdr.pipeline.flow.report_produce`),
or, from a driver that runs on a finished run, add it to the written page with `add_section`
(a section of the same title is replaced; redoing the report stage drops it).
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from sgdr.report import media as report
from sgdr.report.verdict import Verdict, momentum_note, parameter_rows

MAX_EMBED_BYTES = 64 * 2**20  # a larger file is linked instead of embedded (the page stays loadable)
MIME = {".png": "image/png", ".mp4": "video/mp4", ".webm": "video/webm", ".gif": "image/gif"}


@dataclass(frozen=True)
class Section:
    """One titled part of the report; `body` is an HTML fragment (escape text with `esc`)."""

    title: str
    body: str

    @property
    def anchor(self) -> str:
        return re.sub(r"[^a-z0-9]+", "-", self.title.lower()).strip("-")


def esc(text) -> str:
    return html.escape(str(text), quote=True)


def data_uri(path) -> str:
    """The file as a base64 `data:` URI (its MIME type from the suffix)."""
    path = Path(path)
    mime = MIME.get(path.suffix.lower())
    if mime is None:
        raise ValueError(f"report: cannot embed {path}: unknown type {path.suffix!r} (known: {sorted(MIME)})")
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _too_big(path: Path) -> str | None:
    size = path.stat().st_size
    if size <= MAX_EMBED_BYTES:
        return None
    return f"{esc(path.name)} ({size / 2**20:.0f} MB) is too large to embed; it is beside this page"


def image(path, alt: str, caption: str = "") -> str:
    """An embedded PNG with its alt text and an optional caption."""
    path = Path(path)
    if note := _too_big(path):
        return paragraph(note)
    cap = f"<figcaption>{esc(caption)}</figcaption>" if caption else ""
    return f'<figure><img src="{data_uri(path)}" alt="{esc(alt)}">{cap}</figure>'


def video(path, caption: str) -> str:
    """An embedded, looping, muted video with controls, and a link to the file beside the page."""
    path = Path(path)
    if note := _too_big(path):
        return paragraph(note)
    return (
        f'<figure><video src="{data_uri(path)}" controls loop muted autoplay playsinline></video>'
        f'<figcaption>{esc(caption)} (file: <a href="{esc(path.name)}">{esc(path.name)}</a>)</figcaption></figure>'
    )


def table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def paragraph(text: str) -> str:
    return f"<p>{esc(text)}</p>"


STYLE = """
body { font-family: sans-serif; max-width: 1100px; margin: 1.5em auto; padding: 0 1em; color: #222; }
h1 { font-size: 1.5em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 1.6em; }
#verdict { border-left: 8px solid #999; background: #f4f4f4; padding: 0.6em 1em; }
#verdict.good { border-color: #3cb44b; } #verdict.fair { border-color: #f5a623; }
#verdict.poor, #verdict.unknown { border-color: #d0312d; }
#verdict .headline { font-size: 1.25em; font-weight: bold; }
#warnings { background: #fff4e5; border-left: 8px solid #f5a623; padding: 0.4em 1em; }
#warnings.none { background: #eef8ee; border-color: #3cb44b; }
figure { margin: 0.8em 0; } img, video { max-width: 100%; height: auto; } figcaption { color: #555; font-size: 0.9em; }
table { border-collapse: collapse; } td, th { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; }
th { background: #f0f0f0; } nav a { margin-right: 1em; }
"""


NAV_END = "<!--nav-end-->"  # markers where `add_section` inserts into a written page
SECTIONS_END = "<!--sections-end-->"


def _nav_link(s: Section) -> str:
    return f'<a href="#{s.anchor}">{esc(s.title)}</a>'


def _section_html(s: Section) -> str:
    return f'<!--section:{s.anchor}--><section id="{s.anchor}"><h2>{esc(s.title)}</h2>{s.body}</section><!--/section:{s.anchor}-->\n'


def add_section(path, section: Section) -> Path:
    """Add `section` at the end of a report written by `write_report` (and to its contents);
    a section with the same title is replaced in place."""
    path = Path(path)
    page = path.read_text(encoding="utf-8")
    if NAV_END not in page or SECTIONS_END not in page:
        raise ValueError(f"{path}: not a report written by sgdr.report.html.write_report (markers missing)")
    old = re.compile(
        rf"<!--section:{re.escape(section.anchor)}-->.*?<!--/section:{re.escape(section.anchor)}-->\n", re.S
    )
    if old.search(page):
        page = old.sub(lambda _: _section_html(section), page, count=1)
    else:
        page = page.replace(NAV_END, _nav_link(section) + NAV_END, 1)
        page = page.replace(SECTIONS_END, _section_html(section) + SECTIONS_END, 1)
    path.write_text(page, encoding="utf-8")
    return path


def write_report(path, title: str, verdict: Verdict, sections: Sequence[Section], subtitle: str = "") -> Path:
    """Write the self-contained page: title, verdict, warnings, contents, sections."""
    verdict_html = (
        f'<section id="verdict" class="{esc(verdict.fit_quality)}"><h2>Verdict</h2>'
        f'<p class="headline">{esc(verdict.headline)}</p>'
        + "".join(paragraph(s) for s in verdict.sentences)
        + "</section>"
    )
    if verdict.warnings:
        items = "".join(f"<li>{esc(w)}</li>" for w in verdict.warnings)
        warn_html = f'<section id="warnings"><h2>Warnings ({len(verdict.warnings)})</h2><ul>{items}</ul></section>'
    else:
        warn_html = '<section id="warnings" class="none"><h2>Warnings</h2><p>None.</p></section>'
    nav = "<nav>" + "".join(_nav_link(s) for s in sections) + f"{NAV_END}</nav>\n"
    body = "".join(_section_html(s) for s in sections)
    sub = f"<p>{esc(subtitle)}</p>" if subtitle else ""
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{esc(title)}</title><style>{STYLE}</style></head>"
        f"<body><h1>{esc(title)}</h1>{sub}{verdict_html}{warn_html}{nav}{body}{SECTIONS_END}</body></html>\n"
    )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path


def _fmt(x, digits: int = 4) -> str:
    return "—" if x is None else f"{float(x):.{digits}g}"


def scores_table(scores: dict) -> str:
    """The mean scores, fit and future, model and baselines, with the reasons for missing ones."""
    rows = []
    for key, name in (("cd", "Chamfer distance x1e3"), ("emd", "EMD"), ("psnr", "PSNR (dB)"), ("ssim", "SSIM")):
        rows.append((name, _fmt(scores.get(f"fit_{key}")), _fmt(scores.get(f"future_{key}"))))
    for variant, cd in (scores.get("baseline_future_cd_by_variant") or {}).items():
        rows.append((f"baseline '{variant.replace('_', ' ')}': Chamfer distance x1e3", "", _fmt(cd)))
    out = table(("score", "fit frames (model)", "future frames"), rows)
    missing = scores.get("missing") or {}
    if missing:
        out += (
            "<p>Not computed:</p><ul>" + "".join(f"<li>{esc(k)}: {esc(v)}</li>" for k, v in missing.items()) + "</ul>"
        )
    return out


def identification_body(out: Path, dyn: dict) -> str:
    """How sure the identification is: the global search's landscape (plot, the best
    candidates, the spread of their futures) and the field prior's choice on held-out time."""

    body = ""
    search = dyn.get("search") or {}
    if search:
        names = list(search["names"])
        png = report.plot_search(out / "search.png", search)
        body += paragraph(
            f"Global search: {search['n_evaluations']} candidates ({search.get('n_initial_samples', 0)} space-filling, "
            + (f"{search['n_swept']} in coordinate sweeps, " if search.get("n_swept") else "")
            + f"then CMA-ES in {search['n_generations']} generations), "
            f"each scored by its open-loop rollout of all fit frames on all views at n_t = {search['n_substeps']} "
            f"(images downscaled {search['image_scale']}x). Best loss {_fmt(search['best_loss'])} at "
            + ", ".join(f"{n} = {_fmt(v)}" for n, v in search["best"].items())
            + "."
        )
        chosen = search.get("chosen")
        if chosen and search.get("choose") == "medoid" and chosen != search["best"]:
            body += paragraph(
                "The local stage started from the equally good candidate whose predicted future is nearest the "
                "others' (recon.search.choose = medoid): "
                + ", ".join(f"{n} = {_fmt(v)}" for n, v in chosen.items())
                + "."
            )
        body += image(
            png, "search landscape", "Every candidate's loss; red rings: those that fit about as well as the best."
        )
        land = search.get("landscape") or {}
        eq = land.get("equivalent") or []
        rows = [
            [str(r + 1), _fmt(search["losses"][i]), *(_fmt(search["candidates"][i][j]) for j in range(len(names)))]
            for r, i in enumerate(eq)
        ]
        if rows:
            body += table(("rank", "loss", *names), rows)
            body += paragraph(
                f"{len(eq)} candidate(s) fit within the equivalence tolerance of the best; their predicted centres of mass "
                f"part by up to {land.get('future_spread', 0.0):.3g} x the object's size after the fit window"
                + (
                    ": the fit frames do not pin the physics down, and the future is uncertain."
                    if land.get("ambiguous")
                    else "."
                )
            )
    prior = dyn.get("field_prior") or {}
    if prior.get("holdout_losses"):
        rows = [
            [k if k != "inf" else "inf (no field: the global level)", _fmt(v)]
            for k, v in prior["holdout_losses"].items()
        ]
        body += paragraph(
            f"The stiffness field's prior strength, chosen on held-out time: each fitted on the first fit frames and "
            f"scored on the last {prior['holdout_frames']} (open loop). Chosen: {prior['chosen']}."
        )
        body += table(("prior strength λ", "held-out loss"), rows)
    return body


def run_sections(
    out: Path,
    scores: dict,
    dyn: dict,
    velocity: dict,
    refine_losses: Sequence[float],
    anchors,
    recon_cfg,
    physics_cfg,
    n_fit: int,
    videos: Sequence[tuple[Path, str]] = (),
    momentum: dict | None = None,
) -> list[Section]:
    """The base sections of a run's report; writes their plots into `out` (metric_curves.png,
    losses.png, stiffness.png). videos: (file in `out`, caption) already written; momentum: the
    predict stage's momentum audit (`sgdr.asset.predict.audit_momentum`), if made."""

    sections = []
    curves = scores.get("per_frame", {})
    metrics_body = scores_table(scores)
    try:
        png = report.plot_metric_curves(out / "metric_curves.png", curves, n_fit)
        metrics_body += image(
            png, "per-frame scores", "Per frame: the model (black) against the physics-free baselines (dashed)."
        )
    except ValueError as exc:
        metrics_body += paragraph(f"No per-frame curves: {exc}.")
    sections.append(Section("Scores", metrics_body))
    if videos:
        sections.append(Section("Videos", "".join(video(p, cap) for p, cap in videos)))
    loss_curves = {
        "appearance refinement (frame 0)": (refine_losses, "Adam step"),
        "initial velocity v0": (velocity.get("losses") or [], "Adam step"),
        "dynamics (training loss per pass)": (dyn.get("pass_losses") or [], "pass over the fit frames"),
    }
    drawn = {k: v for k, v in loss_curves.items() if len(v[0])}
    body = ""
    if drawn:
        png = report.plot_losses(
            out / "losses.png", {k: v[0] for k, v in drawn.items()}, {k: v[1] for k, v in drawn.items()}
        )
        body = image(png, "loss curves", "Each stage's loss on its own axis.")
    empty = [k for k in loss_curves if k not in drawn]
    if empty:
        body += paragraph("No steps ran for: " + ", ".join(empty) + ".")
    body += paragraph(
        f"Deterministic all-view rollout loss of the fit frames: {_fmt(dyn.get('eval_loss_initial'))} before the "
        f"dynamic passes, {_fmt(dyn.get('eval_loss_final'))} after."
    )
    sections.append(Section("Losses", body))
    if dyn.get("search") or (dyn.get("field_prior") or {}).get("holdout_losses"):
        sections.append(Section("Identification", identification_body(out, dyn)))
    png = report.plot_stiffness(
        out / "stiffness.png", anchors, dyn["log10_k"], (recon_cfg.log10_k_min, recon_cfg.log10_k_max)
    )
    sections.append(Section("Stiffness field", image(png, "stiffness field", "Identified log10 k_i per anchor.")))
    sections.append(
        Section(
            "Identified parameters",
            table(("parameter", "identified", "allowed range"), parameter_rows(dyn, velocity, recon_cfg, physics_cfg))
            + (paragraph(momentum_note(momentum)) if momentum else ""),
        )
    )
    return sections
