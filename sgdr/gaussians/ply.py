"""PLY import/export of Gaussians in the standard 3DGS layout (binary little endian).

Vertex properties, all float32, in this order (what 3DGS writes for SH degree 0 and what
common splat viewers read):

    x, y, z            centre μ, world, scene units
    nx, ny, nz         unused normals (zeros)
    f_dc_0..2          degree-0 SH coefficient: (rgb - 0.5) / C0, C0 = 0.28209479177387814
    opacity            opacity logit (opacity = sigmoid)
    scale_0..2         log standard deviations
    rot_0..3           quaternion (w, x, y, z), not necessarily normalised

`load_ply` reads any binary-little-endian or ASCII PLY holding these properties by name
(extra properties such as f_rest_* are ignored).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sgdr.gaussians.model import Gaussians, logit, sigmoid

SH_C0 = 0.28209479177387814
PROPERTIES = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    + [f"scale_{i}" for i in range(3)]
    + [f"rot_{i}" for i in range(4)]
)
_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


class PlyError(ValueError):
    """A PLY file that cannot be read as Gaussians; the message names the file and the field."""


def save_ply(path, gaussians: Gaussians) -> Path:
    """Write `gaussians` to `path` (parents created). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    d = gaussians.to_numpy()
    m = len(d["opacity_logits"])
    rgb = sigmoid(d["color_logits"])
    cols = np.concatenate(
        [
            d["means"],
            np.zeros((m, 3)),
            (rgb - 0.5) / SH_C0,
            d["opacity_logits"][:, None],
            d["log_scales"],
            d["rotations"],
        ],
        axis=1,
    ).astype("<f4")
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {m}"]
    header += [f"property float {p}" for p in PROPERTIES] + ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(cols).tobytes())
    return path


def load_ply(path) -> Gaussians:
    """Read Gaussians from a 3DGS-layout PLY (see the module docstring)."""
    path = Path(path)
    data = _read_vertices(path)
    missing = [p for p in PROPERTIES if p not in data and not p.startswith("n")]
    if missing:
        raise PlyError(f"{path}: vertex element lacks properties {missing}")

    def stack(names):
        return np.stack([np.asarray(data[n], dtype=np.float64) for n in names], axis=1)

    rgb = stack(["f_dc_0", "f_dc_1", "f_dc_2"]) * SH_C0 + 0.5
    return Gaussians.from_numpy(
        means=stack(["x", "y", "z"]),
        log_scales=stack([f"scale_{i}" for i in range(3)]),
        rotations=stack([f"rot_{i}" for i in range(4)]),
        color_logits=logit(rgb),
        opacity_logits=np.asarray(data["opacity"], dtype=np.float64),
    )


def _read_vertices(path: Path) -> dict[str, np.ndarray]:
    raw = path.read_bytes()
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise PlyError(f"{path}: not a PLY file (no 'ply' magic or 'end_header')")
    body_start = raw.index(b"\n", end) + 1
    lines = raw[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements, current = None, [], None
    for line in lines:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            current = {"name": tok[1], "count": int(tok[2]), "props": []}
            elements.append(current)
        elif tok[0] == "property":
            if current is None:
                raise PlyError(f"{path}: property before any element")
            if tok[1] == "list":
                raise PlyError(f"{path}: list property {tok[-1]!r} in element {current['name']!r} is not supported")
            if tok[1] not in _PLY_TYPES:
                raise PlyError(f"{path}: unknown property type {tok[1]!r} for {tok[2]!r}")
            current["props"].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("binary_little_endian", "ascii"):
        raise PlyError(f"{path}: format {fmt!r} not supported (binary_little_endian or ascii)")
    if not elements or elements[0]["name"] != "vertex":
        raise PlyError(f"{path}: the first element must be 'vertex'")
    v = elements[0]
    if fmt == "ascii":
        rows = raw[body_start:].decode("ascii").split("\n")[: v["count"]]
        table = np.array([r.split() for r in rows], dtype=np.float64).reshape(v["count"], len(v["props"]))
        return {name: table[:, i] for i, (name, _) in enumerate(v["props"])}
    dtype = np.dtype([(name, "<" + t) for name, t in v["props"]])
    need = dtype.itemsize * v["count"]
    if len(raw) - body_start < need:
        raise PlyError(f"{path}: truncated vertex data ({len(raw) - body_start} of {need} bytes)")
    arr = np.frombuffer(raw, dtype=dtype, count=v["count"], offset=body_start)
    return {name: arr[name] for name in dtype.names}
