"""The scene of a foreign sequence, read from the official projects' own config files.

Neither official dataset records its scene (frame interval, gravity, ground, hit frame) beside
the images: Spring-Gaus keeps it in YAML configs (`config/mpm_synthetic/<object>.yaml`,
`config/real_capture/<object>.yaml`), PAC-NeRF in Python configs (`configs/<object>.py`). sgdr
reads those files as they are released, so `scene_file=<that file>` gives a sequence its scene.

Spring-Gaus YAML: a `DEFAULT:` key names a base file (a path relative to the official
repository's root, e.g. `config/mpm_synthetic/default.yaml`), looked up relative to the working
directory, the file's folder and each folder above it; the file's keys override the base's,
recursively. Read from it (the official code's meaning in brackets):
- fps = `DATA.FREQ` if given, else 1 / `DATA.DT` (`Spring_Mass.__init__`: dt = 1/FREQ or DT);
- ground = `DATA.BC[0]` = [point, normal] (the normal points from the ground to the object:
  [0, 1, 0] keeps y >= point, [0, 0, -1] keeps z <= point, `Spring_Mass.apply_bc`);
- gravity = `DYNAMIC.G` (else `VELOCITY.G`); hit_frame = `DATA.HIT_FRAME`; n_fit = `DATA.N_FRAME`;
- checked against the data: image size `DATA.W` x `DATA.H`, camera count `DATA.N_CAM`.

PAC-NeRF Python config: `cfg = dict(...)` with an optional `_base_ = '<path>'` relative to the
file (mmcv's `Config.fromfile`). The file imports PAC-NeRF's simulator (`material =
MPMSimulator.elasticity`), so it is parsed, never executed: every keyword whose value is a
literal or arithmetic on literals (`1/24/200`) is read, the others are skipped. Read from it:
fps = 1 / `frame_dt`; gravity = `gravity`; ground = `BC["ground"]`; hit_frame = `hit_frame`;
n_fit = `n_frames`; checked: `W` x `H`, `n_cameras`.

Every function here returns plain dicts; a missing or malformed key raises `SequenceError`
naming the file and the key.
"""

from __future__ import annotations

import ast
import logging
import operator
from pathlib import Path

import numpy as np

from sgdr.data.sequence import fail, read_json
import yaml

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------- Spring-Gaus YAML
def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _base_candidates(path: Path, name: str) -> list[Path]:
    p = Path(name)
    if p.is_absolute():
        return [p]
    return [Path.cwd() / p, path.parent / p, *(anc / p for anc in path.resolve().parents)]


def read_spring_gaus_yaml(path, _seen=()) -> dict:
    """The merged official Spring-Gaus config (DEFAULT: resolved) as a dict."""

    path = Path(path)
    if not path.is_file():
        fail(path, "<file>", "config file is missing")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        fail(path, "<yaml>", f"not valid YAML ({e})")
    if not isinstance(data, dict):
        fail(path, "<root>", "expected a YAML mapping (the official Spring-Gaus config)")
    base_name = data.pop("DEFAULT", None)
    if base_name is None:
        return data
    candidates = _base_candidates(path, str(base_name))
    base = next((c for c in candidates if c.is_file()), None)
    if base is None:
        fail(
            path,
            "DEFAULT",
            f"base config {base_name!r} not found (looked in {', '.join(map(str, candidates[:3]))}, ...)",
        )
    if base.resolve() in _seen:
        fail(path, "DEFAULT", f"{base} includes itself")
    return _merge(read_spring_gaus_yaml(base, (*_seen, path.resolve())), data)


def _get(cfg: dict, dotted: str):
    node = cfg
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _vector(value, file, key: str) -> list[float]:
    a = np.asarray(value, dtype=np.float64) if value is not None else None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        fail(file, key, f"expected 3 numbers, got {value!r}")
    return a.tolist()


def _ground(bc, file, key: str) -> dict:
    try:
        point, normal = bc[0], bc[1]
    except (TypeError, IndexError, KeyError):
        fail(file, key, f"expected [[point], [normal]], got {bc!r}")
    return {"point": _vector(point, file, f"{key} point"), "normal": _vector(normal, file, f"{key} normal")}


def spring_gaus_scene(cfg: dict, file) -> tuple[dict, dict]:
    """(scene, checks) of a merged Spring-Gaus config: scene keys fps, ground, gravity, hit_frame,
    n_fit where present; checks: width, height, n_cameras, obj_name, n_frames_all where present."""
    scene, checks = {}, {}
    freq, dt = _get(cfg, "DATA.FREQ"), _get(cfg, "DATA.DT")
    if freq not in (None, -1):
        if not float(freq) > 0:
            fail(file, "DATA.FREQ", f"must be positive, got {freq}")
        scene["fps"] = float(freq)
    elif dt is not None:
        if not float(dt) > 0:
            fail(file, "DATA.DT", f"must be positive, got {dt}")
        scene["fps"] = 1.0 / float(dt)
    bc = _get(cfg, "DATA.BC")
    if bc is not None:
        if not isinstance(bc, list) or not bc:
            fail(file, "DATA.BC", f"expected a list of [[point], [normal]], got {bc!r}")
        if len(bc) > 1:
            log.warning(
                "%s: DATA.BC has %d planes; the official simulator uses only the first, so does sgdr", file, len(bc)
            )
        scene["ground"] = _ground(bc[0], file, "DATA.BC[0]")
    for key in ("DYNAMIC.G", "VELOCITY.G"):
        if _get(cfg, key) is not None:
            scene["gravity"] = _vector(_get(cfg, key), file, key)
            break
    if _get(cfg, "DATA.HIT_FRAME") is not None:
        scene["hit_frame"] = int(_get(cfg, "DATA.HIT_FRAME"))
    if _get(cfg, "DATA.N_FRAME") is not None:
        scene["n_fit"] = int(_get(cfg, "DATA.N_FRAME"))
    for name, key in (
        ("width", "DATA.W"),
        ("height", "DATA.H"),
        ("n_cameras", "DATA.N_CAM"),
        ("n_frames_all", "DATA.FRAME_ALL"),
        ("width_static", "DATA.W_S"),
        ("height_static", "DATA.H_S"),
    ):
        if _get(cfg, key) is not None:
            checks[name] = int(_get(cfg, key))
    for name, key in (("obj_name", "DATA.OBJ_NAME"), ("seq", "DATA.SEQ"), ("type", "DATA.TYPE")):
        if _get(cfg, key) is not None:
            checks[name] = str(_get(cfg, key))
    if _get(cfg, "DATA.IMG_IS_MASK") is not None:
        checks["img_is_mask"] = bool(_get(cfg, "DATA.IMG_IS_MASK"))
    if _get(cfg, "DATA.REGIST") is not None:
        checks["regist"] = _get(cfg, "DATA.REGIST")
    return scene, checks


# ---------------------------------------------------------------------------- PAC-NeRF Python config
_OPS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.FloorDiv: operator.floordiv,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
}


class _NotLiteral(Exception):
    """An expression that is not a literal (e.g. `MPMSimulator.elasticity`): its keyword is skipped."""


def _literal(node):
    """Value of a literal / arithmetic-on-literals expression, else _NotLiteral (never executes)."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, (ast.List, ast.Tuple)):
        return [_literal(e) for e in node.elts]
    if isinstance(node, ast.Dict):
        return {_literal(k): _literal(v) for k, v in zip(node.keys, node.values)}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        return {kw.arg: _literal(kw.value) for kw in node.keywords}
    if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        return _OPS[type(node.op)](_literal(node.left), _literal(node.right))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
        return _OPS[type(node.op)](_literal(node.operand))
    raise _NotLiteral(ast.dump(node)[:60])


def read_pac_nerf_py(path, _seen=()) -> dict:
    """The literal keywords of an official PAC-NeRF config (`cfg = dict(...)`, `_base_` merged)."""
    path = Path(path)
    if not path.is_file():
        fail(path, "<file>", "config file is missing")
    try:
        tree = ast.parse(path.read_text(), filename=str(path))
    except SyntaxError as e:
        fail(path, "<python>", f"not valid Python ({e})")
    base_name, cfg = None, None
    for stmt in tree.body:
        if not (isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Name)):
            continue
        target = stmt.targets[0].id
        if target == "_base_":
            try:
                base_name = str(_literal(stmt.value))
            except _NotLiteral:
                fail(path, "_base_", "must be a string literal")
        elif target == "cfg":
            items = (
                [(kw.arg, kw.value) for kw in stmt.value.keywords]
                if isinstance(stmt.value, ast.Call)
                else list(zip((_literal(k) for k in stmt.value.keys), stmt.value.values))
                if isinstance(stmt.value, ast.Dict)
                else None
            )
            if items is None:
                fail(path, "cfg", "expected cfg = dict(...) or a dict literal")
            cfg = {}
            for key, value in items:
                try:
                    cfg[key] = _literal(value)
                except _NotLiteral:
                    log.debug("%s: cfg[%r] is not a literal; skipped", path, key)
    if cfg is None:
        fail(path, "cfg", "no `cfg = dict(...)` assignment (the official PAC-NeRF config form)")
    if base_name is None:
        return cfg
    base = (path.parent / base_name).resolve()
    if not base.is_file():
        fail(path, "_base_", f"base config {base_name!r} not found at {base}")
    if base in _seen:
        fail(path, "_base_", f"{base} includes itself")
    return _merge(read_pac_nerf_py(base, (*_seen, path.resolve())), cfg)


def pac_nerf_scene(cfg: dict, file) -> tuple[dict, dict]:
    """(scene, checks) of a merged PAC-NeRF config (see the module docstring)."""
    scene, checks = {}, {}
    if cfg.get("frame_dt") is not None:
        dt = float(cfg["frame_dt"])
        if not dt > 0:
            fail(file, "frame_dt", f"must be positive, got {dt}")
        scene["fps"] = 1.0 / dt
    if cfg.get("gravity") is not None:
        scene["gravity"] = _vector(cfg["gravity"], file, "gravity")
    bc = cfg.get("BC")
    if bc is not None:
        if not isinstance(bc, dict):
            fail(file, "BC", f"expected a dict of colliders, got {bc!r}")
        others = sorted(k for k in bc if k != "ground")
        if others:
            log.warning("%s: BC colliders %s are not modelled by sgdr; only the ground is", file, others)
        if "ground" in bc:
            scene["ground"] = _ground(bc["ground"], file, "BC['ground']")
    if cfg.get("hit_frame") is not None:
        scene["hit_frame"] = int(cfg["hit_frame"])
    if cfg.get("n_frames") is not None:
        scene["n_fit"] = int(cfg["n_frames"])
    for name, key in (("width", "W"), ("height", "H"), ("n_cameras", "n_cameras")):
        if cfg.get(key) is not None:
            checks[name] = int(cfg[key])
    return scene, checks


def read_scene_file(path) -> tuple[dict, dict, str]:
    """(scene, checks, kind) of a scene file by its extension: `.json` sgdr's `sgdr_scene.json`
    form (scene keys at the top), `.yaml`/`.yml` a Spring-Gaus config, `.py` a PAC-NeRF config."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        data = read_json(path)
        if not isinstance(data, dict):
            fail(path, "<root>", "expected a JSON object")
        return data, {}, "sgdr"
    if suffix in (".yaml", ".yml"):
        return (*spring_gaus_scene(read_spring_gaus_yaml(path), path), "spring_gaus")
    if suffix == ".py":
        return (*pac_nerf_scene(read_pac_nerf_py(path), path), "pac_nerf")
    fail(
        path, "scene_file", "expected sgdr_scene.json (.json), a Spring-Gaus config (.yaml) or a PAC-NeRF config (.py)"
    )
