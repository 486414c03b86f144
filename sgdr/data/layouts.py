"""`load_sequence`: which layout a sequence folder has, and the reader for it.

Layouts (a `sgdr.registry.Registry`, name -> (marker file, reader)):
- `sgdr`: `sequence.json` (`sgdr.data.sequence`, sgdr's own format)
- `spring_gaus`: `camera.json` (`sgdr.data.foreign`)
- `pac_nerf`: `all_data.json` (`sgdr.data.foreign`)
- `spring_gaus_real`: `dynamic/sequences/` (`sgdr.data.real_capture`)

This module sits above `sequence` and `foreign` (foreign builds on sequence's helpers; neither
imports this one), so the two readers do not import each other.
"""

from __future__ import annotations

from pathlib import Path

from sgdr.data import foreign, real_capture
from sgdr.data.sequence import SEQUENCE_FILE, Sequence, SequenceError, read_sgdr
from sgdr.registry import Registry


def _read_sgdr(root: Path, scene_file=None, **scene) -> Sequence:
    if scene_file or any(v is not None for v in scene.values()):
        raise SequenceError(
            f"{root}: sgdr's layout records its scene in sequence.json; scene_file and scene values apply only to "
            "the foreign layouts (edit sequence.json instead)"
        )
    return read_sgdr(root)


LAYOUTS = Registry(
    "sequence layout",
    "sequence",
    SequenceError,
    {
        "sgdr": (SEQUENCE_FILE, _read_sgdr),
        "spring_gaus": (foreign.SPRING_GAUS_FILE, foreign.read_spring_gaus),
        "pac_nerf": (foreign.PAC_NERF_FILE, foreign.read_pac_nerf),
        "spring_gaus_real": (real_capture.MARKER, real_capture.read_real_capture),
    },
)
_LAYOUT_TITLES = {
    "sgdr": "sgdr",
    "spring_gaus": "Spring-Gaus",
    "pac_nerf": "PAC-NeRF",
    "spring_gaus_real": "Spring-Gaus real capture",
}


def detect_layout(root: Path) -> str:
    """The name of the first layout whose marker (a file, or a folder) is in `root` (in `LAYOUTS` order)."""
    for name, (marker, _) in LAYOUTS.items():
        if (Path(root) / marker).exists():
            return name
    expected = ", ".join(f"{marker} ({_LAYOUT_TITLES[name]})" for name, (marker, _) in LAYOUTS.items())
    raise SequenceError(f"{root}: no sequence found: expected {expected}")


def load_sequence(path, scene_file=None, **scene) -> Sequence:
    """Read a sequence folder, auto-detecting the sgdr / Spring-Gaus / PAC-NeRF / real-capture layout.

    scene_file: for the foreign layouts, which do not record their scene, a file giving it: sgdr's
      `sgdr_scene.json` form, the official Spring-Gaus YAML or PAC-NeRF Python config (default:
      the folder's `sgdr_scene.json`; see `sgdr.data.foreign`).
    scene: values that override it (fps, n_fit, hit_frame, ground {point, normal}, gravity; None
      ignored). Both are refused for sgdr's own layout, which records its scene.
    """
    root = Path(path)
    if not root.is_dir():
        raise SequenceError(f"{root}: sequence folder does not exist")
    _, reader = LAYOUTS.get_named(detect_layout(root))
    return reader(root, scene_file=scene_file or None, **scene)
